//! retrocomp: a fieldbus gateway that computes the volumetric error of a legacy CNC machine and feeds
//! the correction back to its controller. See README.md for the pipeline and the conventions.

pub mod bus;
pub mod cli;
pub mod diagnose;
pub mod models;
pub mod recording;
pub mod units;
