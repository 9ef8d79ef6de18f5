//! Model fitting from measurements (Spaan Ch3, Ch5; Ni 1996): linear least squares, C¹ piecewise
//! quadratics with stepwise knot selection, thermal regression with sensor-subset selection
//! (Mallows' Cp, BIC), a ball-screw lead wave beside a smooth part, and Spaan's efficiency δ on
//! held-out data.

mod efficiency;
pub mod lead;
mod lsq;
mod piecewise;
pub mod regression;
pub mod to_model;
pub mod workflow;

pub use efficiency::{Efficiency, efficiency};
pub use lsq::LsqError;
pub use piecewise::{PiecewiseError, PiecewiseQuadratic, fit_stepwise};

pub(crate) use lsq::lstsq;
