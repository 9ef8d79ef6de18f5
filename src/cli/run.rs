//! `retrocomp run --config FIELD.toml`: the gateway in the field. Loads the field config and the
//! machine model, starts the configured sources (CAN/CANopen, Modbus TCP/RTU, serial lines), and runs the cycle with its
//! sinks until SIGINT/SIGTERM. Status on the configured loopback address (`retrocomp status`).

use std::path::PathBuf;

use retrocomp_gateway::config::{CheckedField, check_field};
use retrocomp_gateway::run::{require_sink, run_until_signal};
use retrocomp_gateway::sources::spawn_sources;
use retrocomp_gateway::supervise::exit_on_panic;

/// The field file and model every command that runs the box takes (`run`, `dnc`).
#[derive(Debug, clap::Args)]
pub(crate) struct FieldArgs {
    /// Field configuration TOML (see deploy/field/; `dnc` needs its `[dnc]` section).
    #[arg(long)]
    pub(crate) config: PathBuf,
    /// Machine model TOML; overrides `[model] path` of the field config.
    #[arg(long)]
    pub(crate) model: Option<PathBuf>,
}

impl FieldArgs {
    /// Field file and model checked together, offline (the same checks as `check-config`).
    pub(crate) fn check(&self) -> anyhow::Result<CheckedField> {
        Ok(check_field(&self.config, self.model.as_deref())?)
    }
}

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(flatten)]
    pub field: FieldArgs,
    /// Run without any sink (compute and report only).
    #[arg(long)]
    pub dry_run: bool,
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    super::term::init_tracing("info");
    exit_on_panic();
    let checked = args.field.check()?;
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
        let mut cfg = cfg;
        if args.dry_run {
            cfg.sink = Default::default();
        }
        let summary = run_until_signal(cfg, Box::new(model), feed, epoch).await?;
        eprintln!(
            "stopped after {} cycles; {} writes ok, {} failed; compute p50 {:.1} µs p99 {:.1} µs",
            summary.cycles,
            summary.writes_ok,
            summary.writes_failed,
            summary.compute_us_p50,
            summary.compute_us_p99
        );
        Ok(())
    })
}
