//! `retrocomp demo`: the product's main job on a machine with no hardware. hil-sim (a separate
//! binary, see [`sim_process`]) plays an old mill with hidden geometric, thermal and cutting-force
//! physics; the gateway (this crate, in-process) reads its encoders and temperatures through a
//! socketcand hub on loopback and writes origin shifts into its PLC window over Modbus TCP. Three
//! runs of the same program: no compensation, the geometric-only model, the full model (geometry +
//! thermal + cutting-force load, the force read as weighing lines on a serial pty). Error = actual −
//! nominal, µm, at the tool tip; correction = −error.
//!
//! The three runs go in parallel (each with its own hub, sim and gateway) so the demo takes one
//! program's wall time; they are independent processes and sockets, with the same seed.

pub mod field;
pub mod metrics;
pub mod plot;
pub mod sim_process;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;

use crate::bus::can::hub::Hub;
use crate::gateway::config::FieldConfig;
use crate::gateway::model_adapter::MachineModelAdapter;
use crate::gateway::sources::spawn_sources;
use crate::models::MachineModel;
use metrics::{DemoStats, ErrorTrace, RunStats};

/// The geometric-only model (also hil-sim's hidden truth geometry).
pub const GEOMETRIC_MODEL: &str = include_str!("../../../deploy/demo/mill-geometric.toml");
/// Geometry + thermal + load terms of the simulated mill.
pub const FULL_MODEL: &str = include_str!("../../../deploy/demo/mill-full.toml");

/// Which model the gateway runs with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Uncompensated,
    Geometric,
    Full,
}

impl Mode {
    pub const ALL: [Mode; 3] = [Mode::Uncompensated, Mode::Geometric, Mode::Full];

    pub fn key(self) -> &'static str {
        match self {
            Mode::Uncompensated => "uncompensated",
            Mode::Geometric => "geometric",
            Mode::Full => "full",
        }
    }
}

#[derive(Clone, Debug)]
pub struct DemoOptions {
    pub out: PathBuf,
    pub seed: u64,
    /// Length of the accelerated warm-up (X strokes with the spindle on), simulated s.
    pub warmup_s: f64,
    pub hil_sim: PathBuf,
}

/// One finished run.
pub struct RunResult {
    pub mode: Mode,
    pub stats: RunStats,
    pub trace: ErrorTrace,
    pub gateway_cycles: u64,
    pub writes_ok: u64,
}

pub struct DemoResult {
    pub stats: DemoStats,
    pub runs: Vec<RunResult>,
    pub wall_s: f64,
}

/// Run the three modes and write recordings, configs and plots under `opts.out`.
pub async fn run_demo(opts: &DemoOptions) -> anyhow::Result<DemoResult> {
    let t0 = Instant::now();
    let models = opts.out.join("models");
    std::fs::create_dir_all(&models).with_context(|| format!("creating {}", models.display()))?;
    let geo_path = models.join("mill-geometric.toml");
    std::fs::write(&geo_path, GEOMETRIC_MODEL)?;
    std::fs::write(models.join("mill-full.toml"), FULL_MODEL)?;
    let geo_path = std::fs::canonicalize(&geo_path)?;
    let runs = futures_join3(
        one_run(opts, Mode::Uncompensated, &geo_path),
        one_run(opts, Mode::Geometric, &geo_path),
        one_run(opts, Mode::Full, &geo_path),
    )
    .await;
    let runs: Vec<RunResult> = runs.into_iter().collect::<anyhow::Result<_>>()?;
    let stats = DemoStats {
        uncompensated: runs[0].stats,
        geometric: runs[1].stats,
        full: runs[2].stats,
    };
    plot::write_plots(&opts.out, &runs)?;
    std::fs::write(
        opts.out.join("summary.json"),
        serde_json::to_string_pretty(&stats)? + "\n",
    )?;
    Ok(DemoResult {
        stats,
        runs,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

async fn futures_join3<T>(
    a: impl std::future::Future<Output = T>,
    b: impl std::future::Future<Output = T>,
    c: impl std::future::Future<Output = T>,
) -> [T; 3] {
    let (a, b, c) = tokio::join!(a, b, c);
    [a, b, c]
}

fn model_for(mode: Mode) -> anyhow::Result<Option<MachineModel>> {
    let text = match mode {
        Mode::Uncompensated => return Ok(None),
        Mode::Geometric => GEOMETRIC_MODEL,
        Mode::Full => FULL_MODEL,
    };
    MachineModel::from_toml_str(text, &format!("deploy/demo ({})", mode.key()))
        .map(Some)
        .map_err(|e| anyhow::anyhow!("demo model ({}): {e}", mode.key()))
}

async fn one_run(opts: &DemoOptions, mode: Mode, truth: &Path) -> anyhow::Result<RunResult> {
    let dir = std::path::absolute(opts.out.join(mode.key()))?;
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let hub = Hub::start_loopback()
        .await
        .context("starting the socketcand hub")?;
    let sim_cfg = dir.join("sim.toml");
    std::fs::write(
        &sim_cfg,
        sim_process::sim_config(
            opts.seed,
            truth,
            hub.local_addr().port(),
            opts.warmup_s,
            &dir.join("weighing-pty"),
        ),
    )?;
    let mut sim = sim_process::start(&opts.hil_sim, &sim_cfg, &dir).await?;
    let model = model_for(mode)?;
    let (mut cycles, mut writes_ok) = (0, 0);
    let status = if let Some(model) = model {
        let text = field::field_toml(
            &format!("demo-{}", mode.key()),
            hub.local_addr(),
            sim.modbus,
            &sim.weighing_pty,
        );
        let field_path = dir.join("field.toml");
        std::fs::write(&field_path, &text)?;
        let cfg = FieldConfig::parse(&text, &field_path)?;
        let epoch = Instant::now();
        let rx = spawn_sources(&cfg, epoch).await?;
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let gw = tokio::spawn(crate::gateway::run::run(
            cfg,
            Box::new(MachineModelAdapter::new(model)),
            rx,
            epoch,
            async move {
                let _ = stop_rx.await;
            },
            None,
        ));
        let status = sim.child.wait().await;
        let _ = stop_tx.send(());
        let summary = gw
            .await
            .context("gateway task")?
            .with_context(|| format!("gateway ({})", mode.key()))?;
        cycles = summary.cycles;
        writes_ok = summary.writes_ok;
        status
    } else {
        sim.child.wait().await
    }?;
    let log = sim.log.await.unwrap_or_default();
    anyhow::ensure!(
        status.success(),
        "hil-sim ({}) failed: {status}\n{log}",
        mode.key()
    );
    let rec = dir.join("recording.csv");
    let text = std::fs::read_to_string(&rec).with_context(|| format!("{}", rec.display()))?;
    let trace = metrics::parse_recording(&text, &rec.display().to_string())?;
    let stats = metrics::stats(&trace, 0.0)?;
    drop(hub);
    Ok(RunResult {
        mode,
        stats,
        trace,
        gateway_cycles: cycles,
        writes_ok,
    })
}
