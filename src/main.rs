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
    /// Run the gateway: sources → model → safety → origin-shift / quadrature sinks.
    Run(cli::run::Args),
    /// Show a running gateway's per-axis corrections, term breakdown and sensor health.
    Status(cli::status::Args),
}

fn main() -> std::process::ExitCode {
    let result = match Cli::parse().command {
        Command::CheckConfig(a) => cli::check_config::run(&a),
        Command::Eval(a) => cli::eval::run(&a),
        Command::Run(a) => cli::run::run(&a),
        Command::Status(a) => cli::status::run(&a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
