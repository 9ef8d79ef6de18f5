//! retrocomp: a fieldbus gateway that computes the volumetric error of a legacy CNC machine and feeds
//! the correction back to its controller. See README.md for the pipeline and the conventions.

pub mod analysis;
pub mod approach;
pub mod bus;
pub mod config_issue;
pub mod decimal;
pub mod demo;
pub mod diagnose;
pub mod error;
pub mod fault;
pub mod gateway;
pub mod guard;
pub mod listen;
pub mod models;
pub mod origin_shift;
pub mod quadrature;
pub mod realtime;
pub mod recording;
pub mod sink;
pub mod status;
pub mod telemetry;
pub mod units;
