//! `retrocomp run --config FIELD.toml`: the gateway in the field. Loads the field config and the
//! machine model, starts the configured sources (CAN/CANopen, Modbus TCP/RTU, serial lines), and runs the cycle with its
//! sinks until SIGINT/SIGTERM. Status on the configured loopback address (`retrocomp status`).

use std::path::PathBuf;

use retrocomp_gateway::config::field_check::check_field;
use retrocomp_gateway::engine::{AxisErrors, ErrorModel, MachineState};
use retrocomp_gateway::run::{require_sink, run as run_gateway};
use retrocomp_gateway::sources::spawn_sources;
use retrocomp_gateway::supervise::{exit_on_panic, spawn_watchdog};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Field configuration TOML (see deploy/field/).
    #[arg(long)]
    pub config: PathBuf,
    /// Machine model TOML; overrides `[model] path` of the field config.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Run without any sink (compute and report only).
    #[arg(long)]
    pub dry_run: bool,
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    super::term::init_tracing("info");
    exit_on_panic();
    // Field file and model checked together, offline (the same checks as `check-config`).
    let checked = check_field(&args.config, args.model.as_deref())?;
    let cfg = checked.cfg;
    if !args.dry_run {
        require_sink(&cfg)?;
    }
    let model = checked.model;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let epoch = std::time::Instant::now();
        let feed = spawn_sources(&cfg, epoch).await?;
        let _watchdog = spawn_watchdog(feed.cycles.clone())?;
        let mut cfg = cfg;
        if args.dry_run {
            cfg.sink = Default::default();
        }
        let shutdown = async {
            let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending().await } } => {}
            }
            tracing::info!("stopping");
        };
        let model: Box<dyn ErrorModel + Send> = match hang_hook() {
            Some(after) => Box::new(HangAfter { inner: model, after }),
            None => Box::new(model),
        };
        let summary = run_gateway(cfg, model, feed, epoch, shutdown, None).await?;
        eprintln!(
            "stopped after {} cycles; {} writes ok, {} failed; compute p50 {:.1} µs p99 {:.1} µs",
            summary.cycles, summary.writes_ok, summary.writes_failed, summary.compute_us_p50, summary.compute_us_p99
        );
        Ok(())
    })
}

/// Test hook for the watchdog tests: `RETROCOMP_TEST_HANG_CYCLE_AFTER=N` makes the model evaluation
/// block forever at its N-th call, i.e. the cycle hangs the way a stuck computation would.
const HANG_HOOK: &str = "RETROCOMP_TEST_HANG_CYCLE_AFTER";

fn hang_hook() -> Option<u64> {
    std::env::var(HANG_HOOK).ok()?.parse().ok()
}

struct HangAfter<M> {
    inner: M,
    after: u64,
}

impl<M: ErrorModel> ErrorModel for HangAfter<M> {
    fn required_channels(&self) -> Vec<retrocomp_bus::ChannelId> {
        self.inner.required_channels()
    }

    fn identity(&self) -> Option<retrocomp_gateway::northbound::prometheus::ModelIdentity> {
        self.inner.identity()
    }

    fn axis_errors(&mut self, state: &MachineState, out: &mut AxisErrors) -> Result<(), String> {
        if self.after == 0 {
            tracing::warn!("{HANG_HOOK}: the cycle now blocks forever (test hook)");
            loop {
                std::thread::park();
            }
        }
        self.after -= 1;
        self.inner.axis_errors(state, out)
    }
}
