//! Command-line front ends. Each subcommand lives in its own module with a clap `Args` struct and a
//! `run` function; `src/main.rs` only lists them.

pub mod check_config;
pub mod circle;
pub mod demo;
pub mod diagnose;
pub mod eval;
pub mod export;
pub mod fit;
pub mod fleet;
pub mod hub;
pub mod identify;
pub mod import;
pub mod iso230_2;
pub mod nc;
pub mod run;
pub mod ship;
pub mod status;
pub mod util;
