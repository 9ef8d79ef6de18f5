//! hil-sim: the virtual legacy CNC.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "hil-sim",
    about = "Hardware-in-the-loop simulator of a legacy CNC"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Write concealed-effect cases (recording CSV + truth manifest JSON per case) for `retrocomp diagnose`.
    GenCases {
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Number of cases (30 % nulls; every effect id appears every 20 cases).
        #[arg(long, default_value_t = 100)]
        count: usize,
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().cmd {
        Cmd::GenCases { seed, count, out } => {
            let files = hil_sim::cases::write_cases(seed, count, &out)?;
            println!("wrote {} cases to {}", files.len(), out.display());
        }
    }
    Ok(())
}
