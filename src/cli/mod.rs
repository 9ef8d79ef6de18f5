//! Command-line front ends. Each subcommand lives in its own module with a clap `Args` struct and a
//! `run` function; `src/main.rs` only lists them.

pub mod check_config;
pub mod eval;
pub mod run;
pub mod status;
