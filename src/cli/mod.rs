//! Command-line front ends. Each subcommand lives in its own module with a clap `Args` struct and a
//! `run` function; `src/main.rs` only lists them.

pub(crate) mod check_config;
pub(crate) mod circle;
pub(crate) mod demo;
pub(crate) mod demo_report;
pub(crate) mod diagnose;
pub(crate) mod diagnose_report;
pub(crate) mod dnc;
pub(crate) mod eval;
pub(crate) mod export;
pub(crate) mod fit;
pub(crate) mod fit_report;
pub(crate) mod fleet;
pub(crate) mod fleet_worker;
pub(crate) mod hub;
pub(crate) mod identify;
pub(crate) mod import;
pub(crate) mod iso230_2;
pub(crate) mod nc;
pub(crate) mod report_args;
pub(crate) mod run;
pub(crate) mod ship;
pub(crate) mod status;
pub(crate) mod term;
pub(crate) mod util;
