//! `retrocomp nc IN.nc (--model MACHINE.toml | --plane-model PLANE.toml) [--diameter-x] [--split-mm S]
//! [--out OUT.nc] [--json] [--svg OUT]`
//!
//! `--model` takes the machine model (docs/model.md; evaluated exactly, temperatures and loads at
//! their references). `--plane-model` takes a two-axis Z–X table model (tables are CSV files, paths
//! relative to the TOML file):
//! ```toml
//! terms = "geometric"        # or "positional"
//! szx_urad = -382.35         # squareness Szx, µrad
//! [dzz]                      # δzz(z); likewise [dxz], [dxx], [dzx]
//! file = "table_6_1.csv"
//! position = "target_z_mm"
//! forward = "dzz_f_mm"
//! reverse = "dzz_r_mm"
//! to_um = 1000.0             # table printed in mm
//! ```

use std::path::{Path, PathBuf};

use crate::analysis::laser_import::parse_table_columns;
use crate::analysis::nc::model_errors::ModelErrors;
use crate::analysis::nc::parser::parse_program;
use crate::analysis::nc::rewrite::{RewriteConfig, rewrite};
use crate::analysis::plane_model::{PlaneTerms, ZxPlaneModel};
use crate::analysis::report::{Series, xy_svg};
use crate::analysis::table::BidirectionalTable;
use crate::models::MachineModel;
use anyhow::Context;
use serde::Deserialize;

use super::util::{emit, read, write};

#[derive(Debug, clap::Args)]
pub struct Args {
    pub program: PathBuf,
    /// Machine model TOML (the error function to compensate).
    #[arg(
        long,
        required_unless_present = "plane_model",
        conflicts_with = "plane_model"
    )]
    pub model: Option<PathBuf>,
    /// Two-axis Z–X table model (see docs/toolkit.md).
    #[arg(long)]
    pub plane_model: Option<PathBuf>,
    /// Use the model's first-order closed form instead of the exact 4×4 evaluation.
    #[arg(long)]
    pub first_order: bool,
    /// X words are diameters (lathe, cylindrical grinder).
    #[arg(long)]
    pub diameter_x: bool,
    /// Split G1/G2/G3 moves into pieces of at most this length, mm.
    #[arg(long)]
    pub split_mm: Option<f64>,
    /// Refuse corrections larger than this, µm.
    #[arg(long, default_value_t = 500.0)]
    pub max_correction_um: f64,
    /// `;` starts a comment (LinuxCNC) instead of ending a block (Fanuc/ISO).
    #[arg(long)]
    pub semicolon_comment: bool,
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[arg(long)]
    pub json: bool,
    #[arg(long)]
    pub svg: Option<PathBuf>,
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

fn load_table(base: &Path, s: &TableSpec) -> anyhow::Result<BidirectionalTable> {
    let path = base.join(&s.file);
    let text = read(&path)?;
    Ok(parse_table_columns(
        &path.display().to_string(),
        &text,
        &s.position,
        &s.forward,
        &s.reverse,
        s.to_um,
    )?)
}

pub fn load_plane_model(path: &Path) -> anyhow::Result<ZxPlaneModel> {
    let spec: ModelSpec = toml::from_str(&read(path)?)
        .with_context(|| format!("{}: invalid plane model", path.display()))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let terms = match spec.terms.as_str() {
        "geometric" => PlaneTerms::Geometric,
        "positional" => PlaneTerms::Positional,
        t => anyhow::bail!(
            "{}: key `terms`: expected \"geometric\" or \"positional\", found \"{t}\"",
            path.display()
        ),
    };
    Ok(ZxPlaneModel {
        dzz: load_table(base, &spec.dzz)?,
        dxz: load_table(base, &spec.dxz)?,
        dxx: load_table(base, &spec.dxx)?,
        dzx: load_table(base, &spec.dzx)?,
        szx_urad: spec.szx_urad,
        terms,
    })
}

pub fn run(a: &Args) -> anyhow::Result<()> {
    let text = read(&a.program)?;
    let blocks = parse_program(
        &a.program.display().to_string(),
        &text,
        !a.semicolon_comment,
    )?;
    let cfg = RewriteConfig {
        diameter_x: a.diameter_x,
        split_step_mm: a.split_mm,
        max_correction_um: a.max_correction_um,
        ..Default::default()
    };
    let (out, stats) = match (&a.model, &a.plane_model) {
        (Some(m), _) => {
            let model = MachineModel::from_toml_path(m)?;
            rewrite(&blocks, &ModelErrors::new(&model, !a.first_order), &cfg)
        }
        (None, Some(p)) => rewrite(&blocks, &load_plane_model(p)?, &cfg),
        (None, None) => anyhow::bail!("give --model or --plane-model"),
    }
    .with_context(|| format!("{}", a.program.display()))?;
    if a.json {
        let v = serde_json::json!({ "program": a.program.display().to_string(), "stats": stats, "output": out });
        println!("{}", serde_json::to_string_pretty(&v)?);
        if let Some(p) = &a.out {
            write(p, &out)?;
        }
    } else {
        emit(a.out.as_deref(), &out)?;
        if a.out.is_some() {
            println!(
                "{} blocks in, {} moves compensated, {} points written, {} moves outside the model kept as programmed, max |correction| {:.2} µm",
                stats.blocks_in,
                stats.moves_compensated,
                stats.points_emitted,
                stats.moves_outside_domain,
                stats.max_abs_correction_um
            );
        }
    }
    if let Some(p) = &a.svg {
        // Correction per output motion point: commanded − nominal is not kept, so plot the words.
        let blocks_out = parse_program("output", &out, true)?;
        let pts = |l: char| -> Vec<(f64, f64)> {
            blocks_out
                .iter()
                .filter(|b| !b.has_g(4.0))
                .filter_map(|b| b.get(l))
                .enumerate()
                .map(|(i, w)| (i as f64, w.value))
                .collect()
        };
        let series = [
            Series::markers("X words", pts('X')),
            Series::markers("Z words", pts('Z')),
        ];
        write(
            p,
            &xy_svg(
                "rewritten program: axis words per motion point",
                "motion point #",
                "mm",
                &series,
            )?,
        )?;
    }
    Ok(())
}
