//! The `retrocomp` command line: one subcommand per module in `src/cli/`.

use clap::{Parser, Subcommand};
use retrocomp::cli;

#[derive(Parser)]
#[command(
    name = "retrocomp",
    version,
    about = "Volumetric error compensation gateway for legacy CNC machines"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Load a machine model and print a summary, or every problem with file, line and key.
    CheckConfig(cli::check_config::Args),
    /// Evaluate a machine model along a path CSV; writes the errors and every term as CSV.
    Eval(cli::eval::Args),
    /// Find where simulation and recording disagree, name the missing physics, fit it (DESIGN §5).
    Diagnose(cli::diagnose::DiagnoseArgs),
    /// Run diagnose over `hil-sim gen-cases` output and score it against the truth manifests.
    DiagnoseBench(cli::diagnose::BenchArgs),
}

fn main() -> std::process::ExitCode {
    let result = match Cli::parse().command {
        Command::CheckConfig(a) => cli::check_config::run(&a),
        Command::Eval(a) => cli::eval::run(&a),
        Command::Diagnose(a) => cli::diagnose::run_diagnose(&a),
        Command::DiagnoseBench(a) => cli::diagnose::run_bench(&a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
