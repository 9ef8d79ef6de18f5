//! retrocomp's analysis crate. Offline tools of the compensation engineer: ISO 230-2 positioning analysis, laser-data import,
//! circular (ballbar) test analysis, model fitting, controller-table export and NC-program rewriting.
//!
//! Conventions used throughout this module tree (docs/model.md, Conventions):
//! - positions in mm (`_mm`), errors in µm (`_um`), angles in µrad (`_urad`);
//! - **error = actual − nominal** (ISO 230-2); **correction = −error**;
//! - "forward" / "up" (`+`) = approach in the positive axis direction, "reverse" / "down" (`-`) the
//!   other way (ISO 230-2 ↑ / ↓).
//!
//! Every importer reports file, line and column of each bad row and never drops one silently
//! ([`import_error::ImportErrors`]).
//!
//! Every numeric conversion that could truncate, wrap or lose a sign is a `try_from`, or an `as`
//! after a clamp or check with its reason beside it (these lints are errors in CI).
#![warn(
    unreachable_pub,
    unnameable_types,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]
#![cfg_attr(
    test,
    allow(
        clippy::float_cmp,
        reason = "tests assert values that are exact in binary or parsed from the same decimal text"
    )
)]

pub mod chart;
pub mod chart_geometry;
pub mod circular;
pub mod diagnose;
pub mod export;
pub mod fit;
pub mod html;
pub mod identify;
mod import_error;
pub mod iso230_2;
pub mod iso230_2_figure;
pub mod laser_import;
pub mod nc;
pub mod numeric;
pub mod plane_model;
pub mod polar;
pub mod report;
pub mod table;

pub use import_error::{ImportError, ImportErrors};
