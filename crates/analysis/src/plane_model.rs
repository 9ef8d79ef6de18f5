//! Two-axis Z–X error model of a cylindrical grinder / lathe (Asad Ullah 2013, Ch5), from
//! bidirectional one-axis tables; used to rewrite NC programs before the full machine model exists
//! and to reproduce the thesis' Table 6.3.
//!
//! Terms (error = actual − nominal, µm; x is the radial X position in mm, z the Z position):
//! - positional only: `ez = δzz(z)`, `ex = δxx(x)`;
//! - geometric (the thesis equations with its negligible εyz products dropped, as its own Table 6.3
//!   values show, digest §4): `ez = δzz(z) + δzx(x) − Szx·x`, `ex = δxx(x) + δxz(z)`.
//!
//! Squareness `Szx` is in µrad; the thesis' −0.065 mm at 170 mm is −382.35 µrad (negative = the
//! angle is below 90°). Each table is read in the approach direction of the axis it depends on.
//! Outside the measured travel the model has no value (`None`), so the rewriter leaves such points
//! (overshoot moves) as programmed.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::import_error::ImportErrors;
use crate::laser_import::parse_table_columns;
use crate::nc::ErrorFunction;
use crate::table::{BidirectionalTable, Direction};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneTerms {
    Positional,
    Geometric,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ZxPlaneModel {
    /// δzz(z): positioning error of Z.
    pub dzz: BidirectionalTable,
    /// δxz(z): straightness of Z in X.
    pub dxz: BidirectionalTable,
    /// δxx(x): positioning error of X (radial).
    pub dxx: BidirectionalTable,
    /// δzx(x): straightness of X in Z.
    pub dzx: BidirectionalTable,
    pub szx_urad: f64,
    pub terms: PlaneTerms,
}

const DOMAIN_TOL_MM: f64 = 1e-9;

fn inside(t: &BidirectionalTable, p: f64) -> bool {
    p >= t.positions_mm[0] - DOMAIN_TOL_MM && p <= t.positions_mm[t.len() - 1] + DOMAIN_TOL_MM
}

impl ErrorFunction for ZxPlaneModel {
    fn error_um(&self, pos_mm: [f64; 3], dirs: [Direction; 3]) -> Option<[f64; 3]> {
        let (x, z) = (pos_mm[0], pos_mm[2]);
        if !(inside(&self.dzz, z) && inside(&self.dxx, x)) {
            return None;
        }
        let (dx, dz) = (dirs[0], dirs[2]);
        let (ez, ex) = match self.terms {
            PlaneTerms::Positional => (self.dzz.error_um(z, dz), self.dxx.error_um(x, dx)),
            PlaneTerms::Geometric => (
                // µrad × mm = nm → /1000 for µm.
                self.dzz.error_um(z, dz) + self.dzx.error_um(x, dx) - self.szx_urad * x / 1000.0,
                self.dxx.error_um(x, dx) + self.dxz.error_um(z, dz),
            ),
        };
        Some([ex, 0.0, ez])
    }

    fn axes(&self) -> [bool; 3] {
        [true, false, true]
    }
}

// The plane model file (TOML naming four table CSVs; format in `retrocomp nc`'s help).

/// Why a plane model file (and the table files it names) could not be loaded. Display and
/// `source()` chain as `retrocomp nc` prints them: `cannot read FILE: <io error>`,
/// `FILE: invalid plane model: <TOML error>`, the located table errors.
#[derive(Debug, thiserror::Error)]
pub enum PlaneModelError {
    #[error("cannot read {}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: invalid plane model", path.display())]
    Toml {
        path: PathBuf,
        #[source]
        source: toml::de::Error,
    },
    #[error("{}: key `terms`: expected \"geometric\" or \"positional\", found \"{found}\"", path.display())]
    Terms { path: PathBuf, found: String },
    #[error(transparent)]
    Table(#[from] ImportErrors),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TableSpec {
    file: PathBuf,
    position: String,
    forward: String,
    reverse: String,
    #[serde(default = "one")]
    to_um: f64,
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelSpec {
    terms: String,
    szx_urad: f64,
    dzz: TableSpec,
    dxz: TableSpec,
    dxx: TableSpec,
    dzx: TableSpec,
}

fn load_table(
    base: &Path,
    s: &TableSpec,
    read_file: &mut dyn FnMut(&Path) -> std::io::Result<String>,
) -> Result<BidirectionalTable, PlaneModelError> {
    let path = base.join(&s.file);
    let text = read_file(&path).map_err(|source| PlaneModelError::Read {
        path: path.clone(),
        source,
    })?;
    Ok(parse_table_columns(
        &path.display().to_string(),
        &text,
        &s.position,
        &s.forward,
        &s.reverse,
        s.to_um,
    )?)
}

/// Loads the Z–X plane model from `path` and the table files it names (relative to its folder).
pub fn load_plane_model(path: &Path) -> Result<ZxPlaneModel, PlaneModelError> {
    let text = std::fs::read_to_string(path).map_err(|source| PlaneModelError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_plane_model(path, &text, &mut |p| std::fs::read_to_string(p))
}

/// The plane model from its TOML text (`path` names it in messages and is the base of the table
/// files' names); each table file's text comes from `read_file` (the file system for
/// `load_plane_model`, memory for the fuzz target), so both go through the same parsing.
pub fn parse_plane_model(
    path: &Path,
    toml_text: &str,
    read_file: &mut dyn FnMut(&Path) -> std::io::Result<String>,
) -> Result<ZxPlaneModel, PlaneModelError> {
    let spec: ModelSpec = toml::from_str(toml_text).map_err(|source| PlaneModelError::Toml {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path.parent().unwrap_or(Path::new("."));
    let terms = match spec.terms.as_str() {
        "geometric" => PlaneTerms::Geometric,
        "positional" => PlaneTerms::Positional,
        t => {
            return Err(PlaneModelError::Terms {
                path: path.to_path_buf(),
                found: t.to_string(),
            });
        }
    };
    Ok(ZxPlaneModel {
        dzz: load_table(base, &spec.dzz, read_file)?,
        dxz: load_table(base, &spec.dxz, read_file)?,
        dxx: load_table(base, &spec.dxx, read_file)?,
        dzx: load_table(base, &spec.dzx, read_file)?,
        szx_urad: spec.szx_urad,
        terms,
    })
}
