//! `faulty_box`: `retrocomp run` with one fault injected, for the supervision tests
//! (`tests/real_peers/bus_supervision.rs`). It loads and checks the field file and model, starts the
//! configured sources and runs the gateway through the same library call as `retrocomp run`
//! (`run::run_until_signal`: systemd watchdog, SIGINT/SIGTERM), and injects what a real failure
//! would look like, so the product binary carries no test hook:
//!
//! - `--fault source-panic`: a source task panics at the first sample (the process must exit 70);
//! - `--fault source-return`: a source task ends at the first sample (the run must stop, status 1);
//! - `--fault hang-after:N`: the model evaluation blocks forever at its N-th call (the cycle hangs;
//!   the watchdog must stop pinging).
//!
//! Test-only: part of hil-sim, never of the `retrocomp` package.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use retrocomp_bus::Sample;
use retrocomp_gateway::config::check_field;
use retrocomp_gateway::engine::{AxisErrors, ErrorModel, MachineState};
use retrocomp_gateway::run::run_until_signal;
use retrocomp_gateway::sources::spawn_sources;
use retrocomp_gateway::supervise::{TaskDeaths, exit_on_panic};
use retrocomp_model::error::Chain;
use tokio::sync::mpsc;

#[derive(Debug, Parser)]
struct Args {
    /// Field configuration TOML.
    #[arg(long)]
    config: PathBuf,
    /// The fault: `source-panic`, `source-return` or `hang-after:N`.
    #[arg(long)]
    fault: Fault,
}

#[derive(Clone, Copy, Debug)]
enum Fault {
    SourcePanic,
    SourceReturn,
    HangAfter(u64),
}

impl std::str::FromStr for Fault {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "source-panic" => Ok(Fault::SourcePanic),
            "source-return" => Ok(Fault::SourceReturn),
            _ => s
                .strip_prefix("hang-after:")
                .and_then(|n| n.parse().ok())
                .map(Fault::HangAfter)
                .ok_or_else(|| format!("unknown fault {s:?}")),
        }
    }
}

/// The model, blocking forever at its `after`-th evaluation (a stuck computation).
struct HangAfter<M> {
    inner: M,
    after: u64,
}

impl<M: ErrorModel> ErrorModel for HangAfter<M> {
    fn required_channels(&self) -> Vec<std::sync::Arc<str>> {
        self.inner.required_channels()
    }

    fn identity(&self) -> Option<retrocomp_gateway::status::ModelIdentity> {
        self.inner.identity()
    }

    fn axis_errors(
        &mut self,
        state: &MachineState,
        out: &mut AxisErrors,
    ) -> Result<(), retrocomp_gateway::engine::ModelError> {
        if self.after == 0 {
            tracing::warn!("faulty_box: the cycle now blocks forever (injected hang)");
            loop {
                std::thread::park();
            }
        }
        self.after -= 1;
        self.inner.axis_errors(state, out)
    }
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    exit_on_panic();
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", Chain(&*e));
            ExitCode::FAILURE
        }
    }
}

fn run(args: &Args) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let checked = check_field(&args.config, None)?;
    let (cfg, model) = (checked.cfg, checked.model);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let epoch = std::time::Instant::now();
        let mut feed = spawn_sources(&cfg, epoch).await?;
        let model: Box<dyn ErrorModel + Send> = match args.fault {
            Fault::HangAfter(after) => Box::new(HangAfter {
                inner: model,
                after,
            }),
            Fault::SourcePanic | Fault::SourceReturn => {
                // A task between the sources and the cycle, supervised like a source's: it fails
                // as asked at the first sample.
                let (notice, deaths) = TaskDeaths::new();
                let (tx, rx) = mpsc::channel::<Sample>(16_384);
                let mut real = std::mem::replace(&mut feed.samples, rx);
                feed.deaths = deaths;
                let fault = args.fault;
                tokio::spawn(async move {
                    // Holding the cycle's sample channel open: the run must stop on the
                    // report, not on a closed channel.
                    let _samples = tx;
                    if real.recv().await.is_none() {
                        return;
                    }
                    if let Fault::SourcePanic = fault {
                        panic!("faulty_box: source `can` panics (injected)");
                    }
                    notice.report("can", "faulty_box: the task returned (injected)");
                    std::future::pending::<()>().await;
                });
                Box::new(model)
            }
        };
        let summary = run_until_signal(cfg, model, feed, epoch).await?;
        eprintln!("stopped after {} cycles", summary.cycles);
        Ok(())
    })
}
