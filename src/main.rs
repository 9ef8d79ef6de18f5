//! retrocomp command line. Each subcommand's logic lives in `src/cli/<name>.rs`.

mod cli;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "retrocomp",
    version,
    about = "Volumetric error compensation gateway for legacy CNC machines"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// ISO 230-2:2014 positioning evaluation of one axis from laser runs.
    #[command(name = "iso230-2")]
    Iso230_2(cli::iso230_2::Args),
    /// Import laser runs or controller tables into a bidirectional error table.
    Import(cli::import::Args),
    /// Export an error table as a Fanuc pitch tape, LinuxCNC comp file or ISG CSV.
    Export(cli::export::Args),
    /// Rewrite an NC program with compensation.
    Nc(cli::nc::Args),
    /// Circular (ballbar) test: ISO 230-4 G/F and error diagnosis.
    Circle(cli::circle::Args),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Iso230_2(a) => cli::iso230_2::run(a),
        Command::Import(a) => cli::import::run(a),
        Command::Export(a) => cli::export::run(a),
        Command::Nc(a) => cli::nc::run(a),
        Command::Circle(a) => cli::circle::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
