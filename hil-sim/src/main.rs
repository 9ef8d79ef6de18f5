//! hil-sim: the virtual legacy CNC. A small clap enum + dispatch; each command's logic lives in the
//! library (`hil_sim::cli`, `hil_sim::io`, `hil_sim::cases`).

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "hil-sim",
    version,
    about = "Virtual legacy CNC: hidden physics, field buses, recordings"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a config to the end as fast as possible; write recording.csv + manifest.json.
    Run(hil_sim::cli::RunArgs),
    /// Run with the field buses up (Modbus TCP/RTU, CAN, weighing lines), real time or fast.
    Serve(hil_sim::cli::ServeArgs),
    /// Write concealed-effect cases (recording CSV + truth manifest JSON per case) for `retrocomp diagnose`.
    GenCases(hil_sim::cli::GenCasesArgs),
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().cmd {
        Cmd::Run(a) => hil_sim::cli::run(&a),
        Cmd::Serve(a) => hil_sim::cli::serve(&a),
        Cmd::GenCases(a) => hil_sim::cli::gen_cases(&a),
    }
}
