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

use crate::analysis::nc::ErrorFunction;
use crate::analysis::table::{BidirectionalTable, Direction};

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
