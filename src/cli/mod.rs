//! Subcommand implementations of the `retrocomp` binary (one module per command).

pub mod diagnose;
