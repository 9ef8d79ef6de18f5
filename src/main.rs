//! The `retrocomp` command line.

use clap::{Parser, Subcommand};
use retrocomp::cli;

#[derive(Parser)]
#[command(
    name = "retrocomp",
    about = "Volumetric error compensation gateway for legacy CNC machines"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Find where simulation and recording disagree, name the missing physics, fit it (DESIGN §5).
    Diagnose(cli::diagnose::DiagnoseArgs),
    /// Run diagnose over `hil-sim gen-cases` output and score it against the truth manifests.
    DiagnoseBench(cli::diagnose::BenchArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().cmd {
        Cmd::Diagnose(a) => cli::diagnose::run_diagnose(&a),
        Cmd::DiagnoseBench(a) => cli::diagnose::run_bench(&a),
    }
}
