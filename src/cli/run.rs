//! `retrocomp run --config FIELD.toml`: the gateway in the field. Loads the field config and the
//! machine model, starts the configured sources (CAN/CANopen today), and runs the cycle with its
//! sinks until SIGINT/SIGTERM. Status on the configured loopback address (`retrocomp status`).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};
use tokio::sync::mpsc;

use crate::bus::Sample;
use crate::bus::can::backend;
use crate::bus::canopen::source::{self as canopen, CanopenSource};
use crate::gateway::config::FieldConfig;
use crate::gateway::model_adapter::MachineModelAdapter;
use crate::gateway::run::{require_sink, run as run_gateway};
use crate::models::MachineModel;

#[derive(Debug, clap::Args)]
pub struct Args {
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

pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    init_tracing();
    let cfg = FieldConfig::load(&args.config)?;
    if !args.dry_run {
        require_sink(&cfg)?;
    }
    let model_path = match (&args.model, &cfg.model) {
        (Some(p), _) => p.clone(),
        (None, Some(m)) => args
            .config
            .parent()
            .unwrap_or(std::path::Path::new("."))
            .join(&m.path),
        (None, None) => bail!(
            "{}: no [model] path and no --model given",
            args.config.display()
        ),
    };
    let model = MachineModel::from_toml_path(&model_path).map_err(|e| anyhow::anyhow!("{e}"))?;
    if cfg.modbus.is_some() || cfg.serial.is_some() {
        bail!(
            "{}: [modbus] / [serial] sources are configured but src/bus has no Modbus poller or serial \
             source wired yet; remove them or use CAN sources",
            args.config.display()
        );
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let (tx, rx) = mpsc::channel::<Sample>(16_384);
        let epoch = std::time::Instant::now();
        if let (Some(can), Some(co)) = (cfg.can.clone(), cfg.canopen.clone()) {
            let mut bus = backend::open(&can, None).await.with_context(|| format!("opening CAN backend {can:?}"))?;
            let (btx, mut brx) = mpsc::channel::<Vec<Sample>>(1024);
            tokio::spawn(async move {
                let mut src = CanopenSource::new(co);
                let clock = move || epoch.elapsed().as_secs_f64();
                if let Err(e) = canopen::run(&mut bus, &mut src, clock, Duration::from_millis(10), btx).await {
                    tracing::error!(%e, "CAN source stopped");
                }
            });
            tokio::spawn(async move {
                while let Some(batch) = brx.recv().await {
                    for s in batch {
                        if tx.send(s).await.is_err() {
                            return;
                        }
                    }
                }
            });
        }
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
        let summary = run_gateway(cfg, Box::new(MachineModelAdapter::new(model)), rx, shutdown, None).await?;
        eprintln!(
            "stopped after {} cycles; {} writes ok, {} failed; compute p50 {:.1} µs p99 {:.1} µs",
            summary.cycles, summary.writes_ok, summary.writes_failed, summary.compute_us_p50, summary.compute_us_p99
        );
        Ok(())
    })
}
