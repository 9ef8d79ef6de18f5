//! NC-program rewriting for offline compensation (Spaan Ch7, Asad Ullah Ch6): the program is
//! parsed into blocks ([`parser`]), interpreted with its modal state (G0–G3, G4, G90/G91, diameter
//! programming of lathe X, M30/M2), and every motion end point is replaced by
//! `commanded = nominal − error(nominal, approach direction)` ([`rewrite`]).
//!
//! The error comes from any [`ErrorFunction`] (a table model, the machine model, …), evaluated in
//! machine coordinates: program + work offset (G54–G59.3, given to the rewriter or set in the
//! program by G10 L2; G54 not given = zero). Cutter compensation, tool length offsets, G92 shifts
//! and canned cycles must be expanded first and are refused, not silently misread.

mod model_errors;
mod motion;
pub mod parser;
pub mod rewrite;

pub use model_errors::ModelErrors;

use crate::table::Direction;

/// Axis index in `[f64; 3]` vectors: X = 0, Y = 1, Z = 2.
pub const AXES: [char; 3] = ['X', 'Y', 'Z'];

/// An error model as the rewriter sees it.
pub trait ErrorFunction {
    /// Error (actual − nominal, µm) of the tool relative to the workpiece along X, Y, Z, at the
    /// nominal position `pos_mm` (X as a radius on a lathe), with each axis approached in `dirs`.
    /// `None` outside the model's domain (the rewriter then leaves the point as programmed).
    fn error_um(&self, pos_mm: [f64; 3], dirs: [Direction; 3]) -> Option<[f64; 3]>;

    /// The axes the error depends on and corrects (X, Y, Z). A move is only compensated when all
    /// of them have known positions; the other axes are never given corrections.
    fn axes(&self) -> [bool; 3] {
        [true; 3]
    }
}
