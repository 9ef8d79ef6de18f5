//! `retrocomp demo`: the product's main job on a machine with no hardware. hil-sim (a separate
//! binary, see `sim_process`) plays an old mill with hidden geometric, thermal and cutting-force
//! physics; the gateway (this crate, in-process) reads its encoders and temperatures through a
//! socketcand hub on loopback and writes origin shifts into its PLC window over Modbus TCP. Four
//! runs of the same program: no compensation, the geometric-only truth model, the full truth model
//! (geometry + thermal + cutting-force load, the force read as weighing lines on a serial pty), and
//! the model FITTED from the simulator's own measurement runs (`campaign`, `fitted`): what a
//! compensation engineer would get without knowing the truth. Error = actual − nominal, µm, at the
//! tool tip; correction = −error.
//!
//! The measurement runs come first (offline, seconds); then the four runs go in parallel (each
//! with its own hub, sim and gateway) so the demo takes one program's wall time; they are
//! independent processes and sockets, with the same seed.

pub(crate) mod campaign;
pub(crate) mod error;
pub(crate) mod field;
pub(crate) mod fitted;
pub(crate) mod metrics;
pub(crate) mod plot;
pub(crate) mod readings;
pub(crate) mod sim_process;

use std::path::{Path, PathBuf};
use std::time::Instant;

use error::Context as _;

pub use error::DemoError;
pub use metrics::{AxisStats, DemoStats, ErrorTrace, GatewayRun, GatewayRuns, Phase, RunStats};
pub use plot::DemoFigure;
use retrocomp_bus::can::Hub;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_gateway::sources::spawn_sources;
use retrocomp_model::MachineModel;
use retrocomp_model::recording::Recording;
pub use sim_process::locate_hil_sim;

/// The geometric-only model (also hil-sim's hidden truth geometry).
pub const GEOMETRIC_MODEL: &str = include_str!("../../deploy/demo/mill-geometric.toml");
/// Geometry + thermal + load terms of the simulated mill.
pub const FULL_MODEL: &str = include_str!("../../deploy/demo/mill-full.toml");
/// The machine without error terms (chain, travels, tool): the start of the fitted model.
pub const BASE_MODEL: &str = include_str!("../../deploy/demo/mill-base.toml");

/// Which model the gateway runs with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Uncompensated,
    Geometric,
    Full,
    /// The model fitted from the measurement campaign.
    Fitted,
}

impl Mode {
    pub const ALL: [Mode; 4] = [
        Mode::Uncompensated,
        Mode::Geometric,
        Mode::Full,
        Mode::Fitted,
    ];

    pub fn key(self) -> &'static str {
        match self {
            Mode::Uncompensated => "uncompensated",
            Mode::Geometric => "geometric",
            Mode::Full => "full",
            Mode::Fitted => "fitted",
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
    /// `host:port` of an MQTT broker: each compensated run publishes Sparkplug B there (group
    /// `retrocomp-demo`, edge node `mill-<run>`; the live gateway of `--serve` is `mill-live`, one
    /// Sparkplug session across its passes), through the same publisher as `run`.
    pub mqtt: Option<String>,
    /// `SCHED_FIFO` priority for the real-time parts of each run: hil-sim's threads (the machine),
    /// the socketcand hub (the bus), the gateway's cycle, sink and readers. None: normal scheduler.
    pub realtime_priority: Option<u8>,
}

/// One finished run.
#[derive(Debug)]
pub struct RunResult {
    pub mode: Mode,
    pub stats: RunStats,
    pub trace: ErrorTrace,
    pub gateway_cycles: u64,
    pub writes_ok: u64,
    /// How the gateway kept up (zeros for the uncompensated run, which has none).
    pub gateway: GatewayRun,
}

#[derive(Debug)]
pub struct DemoResult {
    pub stats: DemoStats,
    pub runs: Vec<RunResult>,
    /// What the fit of the measurement runs produced (one line per component / signal).
    pub fit_report: Vec<String>,
    /// Wall time of the measurement runs and the fit, s.
    pub campaign_s: f64,
    pub wall_s: f64,
    /// The figures written into the output folder (error per axis, volumetric).
    pub figures: Vec<DemoFigure>,
}

/// Measure, fit, then run the four modes; write recordings, configs, models and plots under
/// `opts.out`.
pub async fn run_demo(opts: &DemoOptions) -> Result<DemoResult, DemoError> {
    let t0 = Instant::now();
    let models = opts.out.join("models");
    std::fs::create_dir_all(&models).with_context(|| format!("creating {}", models.display()))?;
    let geo_path = models.join("mill-geometric.toml");
    std::fs::write(&geo_path, GEOMETRIC_MODEL)?;
    std::fs::write(models.join("mill-full.toml"), FULL_MODEL)?;
    let geo_path = std::fs::canonicalize(&geo_path)?;
    let (fitted_model, fit) = measure_and_fit(opts, &geo_path).await?;
    std::fs::write(models.join("mill-fitted.toml"), &fit.toml)?;
    std::fs::write(models.join("fit-report.txt"), fit.report.join("\n") + "\n")?;
    let campaign_s = t0.elapsed().as_secs_f64();
    let (a, b, c, d) = tokio::join!(
        one_run(opts, Mode::Uncompensated, &geo_path, None, None),
        one_run(
            opts,
            Mode::Geometric,
            &geo_path,
            Some(truth_model(Mode::Geometric)?),
            None
        ),
        one_run(
            opts,
            Mode::Full,
            &geo_path,
            Some(truth_model(Mode::Full)?),
            None
        ),
        one_run(opts, Mode::Fitted, &geo_path, Some(fitted_model), None),
    );
    let runs = vec![a?, b?, c?, d?];
    let stats = DemoStats {
        uncompensated: runs[0].stats,
        geometric: runs[1].stats,
        full: runs[2].stats,
        fitted: runs[3].stats,
        gateway: GatewayRuns {
            geometric: runs[1].gateway,
            full: runs[2].gateway,
            fitted: runs[3].gateway,
        },
    };
    let figures = plot::write_plots(&opts.out, &runs)?;
    std::fs::write(
        opts.out.join("summary.json"),
        serde_json::to_string_pretty(&stats)? + "\n",
    )?;
    Ok(DemoResult {
        stats,
        runs,
        fit_report: fit.report,
        campaign_s,
        wall_s: t0.elapsed().as_secs_f64(),
        figures,
    })
}

/// The measurement campaign on hil-sim (the demo's hidden machine, `truth` = its geometry) and the
/// fit; everything under `OUT/campaign`.
async fn measure_and_fit(
    opts: &DemoOptions,
    truth: &Path,
) -> Result<(MachineModel, fitted::FitOutcome), DemoError> {
    let dir = std::path::absolute(opts.out.join("campaign"))?;
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    // The demo's machine; the buses are dropped, so the port and pty are placeholders.
    let sim = sim_process::sim_config(opts.seed, truth, 0, 0.0, &dir.join("unused-pty"));
    let plans = campaign::demo_plans();
    let mut jobs = Vec::new();
    for p in &plans {
        let name = format!("geometry-{}", p.axis.lower());
        jobs.push((
            name,
            campaign::measurement_config(&sim, &p.gcode(), 0.1, "geometry")?,
        ));
    }
    jobs.push((
        "context".to_string(),
        campaign::measurement_config(&sim, &campaign::context_gcode(), 0.05, "context")?,
    ));
    let mut set = tokio::task::JoinSet::new();
    for (name, text) in &jobs {
        let run_dir = dir.join(name);
        std::fs::create_dir_all(&run_dir)?;
        let cfg = run_dir.join("sim.toml");
        std::fs::write(&cfg, text)?;
        let bin = opts.hil_sim.clone();
        set.spawn(async move { campaign::run_measurement(&bin, &cfg, &run_dir).await });
    }
    while let Some(r) = set.join_next().await {
        r.context("measurement task")??;
    }
    let read = |name: &str| -> Result<(Recording, String), DemoError> {
        let p = dir.join(name).join("recording.csv");
        Ok((Recording::read_path(&p)?, p.display().to_string()))
    };
    let geo: Vec<(Recording, String)> = plans
        .iter()
        .map(|p| read(&format!("geometry-{}", p.axis.lower())))
        .collect::<Result<_, DemoError>>()?;
    let (ctx, ctx_name) = read("context")?;
    let base = MachineModel::from_toml_str(BASE_MODEL, "deploy/demo/mill-base.toml")
        .map_err(|e| DemoError::Failed(format!("{e}")))?;
    let geometry: Vec<(&campaign::AxisPlan, &Recording, &str)> = plans
        .iter()
        .zip(&geo)
        .map(|(p, (r, n))| (p, r, n.as_str()))
        .collect();
    let (model, fit) = fitted::fit_model(base.spec(), &geometry, (&ctx, &ctx_name))?;
    for (name, text) in &fit.readings_csv {
        std::fs::write(dir.join(name), text)?;
    }
    Ok((model, fit))
}

fn truth_model(mode: Mode) -> Result<MachineModel, DemoError> {
    let text = match mode {
        Mode::Geometric => GEOMETRIC_MODEL,
        _ => FULL_MODEL,
    };
    MachineModel::from_toml_str(text, &format!("deploy/demo ({})", mode.key()))
        .map_err(|e| DemoError::Failed(format!("demo model ({}): {e}", mode.key())))
}

/// Where a live run serves its page: the address to bind (instead of the demo's ephemeral
/// loopback port) and who to tell the bound address.
struct Live {
    listen: String,
    bound: tokio::sync::oneshot::Sender<std::net::SocketAddr>,
    /// The OPC UA server's loopback port, the same on every pass (clients keep their endpoint),
    /// held by this listener until the gateway binds it: hil-sim's server and every connection
    /// the run opens take ephemeral ports from the same range, so a port merely chosen earlier
    /// could be taken by the time the OPC UA server binds it.
    opcua: std::net::TcpListener,
    opcua_port: u16,
}

/// Passes of the program one live simulator runs (≈ 40 s each, so about an hour) before the live
/// gateway and its machine are started afresh.
pub const LIVE_PASSES: usize = 90;

/// `retrocomp demo --serve`: after the four runs, ONE full-model gateway runs against ONE hil-sim
/// that repeats the warm-up and the part program [`LIVE_PASSES`] times
/// (`sim_process::repeated`): the page's history spans the passes, the fault log shows only real
/// faults, OPC UA subscriptions and the Sparkplug session stay up between passes. Its live page and
/// `/metrics` on `listen`, its OPC UA server on a loopback port chosen once (kept when the machine
/// is started afresh after the last pass); `on_bound` gets the page's address and the OPC UA
/// endpoint (`opc.tcp://…/`) once the gateway is up. Returns only on error (the caller stops it
/// with Ctrl-C).
pub async fn serve_live(
    opts: &DemoOptions,
    listen: &str,
    on_bound: impl FnOnce(std::net::SocketAddr, String),
) -> Result<(), DemoError> {
    // A free port on the first pass, the same one on every later pass.
    let mut opcua_port = 0;
    let models = opts.out.join("models");
    std::fs::create_dir_all(&models)?;
    let geo_path = models.join("mill-geometric.toml");
    std::fs::write(&geo_path, GEOMETRIC_MODEL)?;
    let geo_path = std::fs::canonicalize(&geo_path)?;
    let mut on_bound = Some(on_bound);
    loop {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let opcua = reserve_port(opcua_port).await?;
        opcua_port = opcua.local_addr()?.port();
        let live = Live {
            listen: listen.to_string(),
            bound: tx,
            opcua,
            opcua_port,
        };
        let run = one_run(
            opts,
            Mode::Full,
            &geo_path,
            Some(truth_model(Mode::Full)?),
            Some(live),
        );
        tokio::pin!(run);
        let mut rx = Some(rx);
        loop {
            tokio::select! {
                r = &mut run => { r?; break; }
                Ok(addr) = async { rx.as_mut().expect("polled once").await }, if rx.is_some() => {
                    rx = None;
                    if let Some(f) = on_bound.take() {
                        f(addr, format!("opc.tcp://127.0.0.1:{opcua_port}/"));
                    }
                }
            }
        }
    }
}

/// A loopback listener on `port` (0: any free one). A later pass asks again for the port the
/// previous pass's OPC UA server held, which that server's stop may release a moment late.
async fn reserve_port(port: u16) -> Result<std::net::TcpListener, DemoError> {
    let mut tries = 0;
    loop {
        match std::net::TcpListener::bind((std::net::Ipv4Addr::LOCALHOST, port)) {
            Ok(l) => return Ok(l),
            Err(e) if port != 0 && tries < 50 => {
                tracing::debug!(port, %e, "the OPC UA port is not free yet");
                tries += 1;
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            }
            Err(e) => return Err(e).with_context(|| format!("reserving OPC UA port {port}")),
        }
    }
}

async fn one_run(
    opts: &DemoOptions,
    mode: Mode,
    truth: &Path,
    model: Option<MachineModel>,
    live: Option<Live>,
) -> Result<RunResult, DemoError> {
    let sub = if live.is_some() { "live" } else { mode.key() };
    let dir = std::path::absolute(opts.out.join(sub))?;
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let hub = Hub::start_on_thread(([127, 0, 0, 1], 0).into(), opts.realtime_priority)
        .context("starting the socketcand hub")?;
    let sim_cfg = dir.join("sim.toml");
    let sim_text = sim_process::sim_config(
        opts.seed,
        truth,
        hub.local_addr().port(),
        opts.warmup_s,
        &dir.join("weighing-pty"),
    );
    let sim_text = match live {
        Some(_) => sim_process::repeated(&sim_text, LIVE_PASSES),
        None => sim_text,
    };
    std::fs::write(
        &sim_cfg,
        sim_process::with_realtime_priority(&sim_text, opts.realtime_priority),
    )?;
    let mut sim = sim_process::start(&opts.hil_sim, &sim_cfg, &dir).await?;
    let (mut cycles, mut writes_ok) = (0, 0);
    let mut gateway = GatewayRun::default();
    let status = if let Some(model) = model {
        let (text, live) = field_text(opts, mode, hub.local_addr(), &sim, live);
        let field_path = dir.join("field.toml");
        std::fs::write(&field_path, &text)?;
        let mut cfg = FieldConfig::parse(&text, &field_path)?;
        if let Some(broker) = &opts.mqtt {
            cfg.telemetry = Some(retrocomp_gateway::northbound::telemetry::demo_section(
                broker, sub,
            ));
        }
        let epoch = Instant::now();
        let rx = spawn_sources(&cfg, epoch).await?;
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        // The OPC UA port is released just before the gateway binds it.
        let bound = live.map(|(bound, opcua)| {
            drop(opcua);
            bound
        });
        let mut gw = tokio::spawn(retrocomp_gateway::run::run(
            cfg,
            Box::new(MachineModelAdapter::new(model)),
            rx,
            epoch,
            async move {
                let _ = stop_rx.await;
            },
            bound,
        ));
        let status =
            match sim_process::until_exit_or_gateway_end(sim.child.wait(), &mut gw, sub).await {
                Ok(status) => status,
                Err(e) => {
                    let _ = sim.child.kill().await;
                    return Err(e);
                }
            };
        let _ = stop_tx.send(());
        let summary = gw
            .await
            .context("gateway task")?
            .with_context(|| format!("gateway ({})", mode.key()))?;
        cycles = summary.cycles;
        writes_ok = summary.writes_ok;
        gateway = gateway_run(&summary);
        status
    } else {
        sim.child.wait().await
    }?;
    let log = sim.log.await.unwrap_or_default();
    // Kept beside the recording: fault edges, the PLC watchdog and the real-time lag of the sim.
    std::fs::write(dir.join("hil-sim.log"), &log)?;
    if !status.success() {
        return Err(DemoError::Failed(format!(
            "hil-sim ({}) failed: {status}\n{log}",
            mode.key()
        )));
    }
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
        gateway,
    })
}

/// The gateway's field config for one run: the hub, the sim's Modbus server and weighing pty;
/// for a live run also its page's address and OPC UA section, with who to tell the bound address.
fn field_text(
    opts: &DemoOptions,
    mode: Mode,
    hub: std::net::SocketAddr,
    sim: &sim_process::Sim,
    live: Option<Live>,
) -> (
    String,
    Option<(
        tokio::sync::oneshot::Sender<std::net::SocketAddr>,
        std::net::TcpListener,
    )>,
) {
    let text = field::field_toml(
        &format!("demo-{}", mode.key()),
        hub,
        sim.modbus,
        &sim.weighing_pty,
    );
    let text = field::with_realtime_priority(&text, opts.realtime_priority);
    // The live gateway (`--serve`): the page on the asked address and, for the plant, an
    // OPC UA server on the port `serve_live` holds (printed beside the page's address).
    match live {
        Some(l) => {
            let listen = format!("status_listen = \"{}\"", l.listen);
            let text = text.replacen("status_listen = \"127.0.0.1:0\"", &listen, 1);
            // The demo machine's identity (OPC 40501-1 requires one): plainly a simulation.
            let opcua = format!(
                "\n[opcua]\nlisten = \"127.0.0.1:{}\"\n[opcua.identification]\n\
                 manufacturer = \"retrocomp demo (simulated mill)\"\nserial_number = \"demo-{}\"\n\
                 product_instance_uri = \"urn:retrocomp:demo:{}\"\n",
                l.opcua_port,
                mode.key(),
                mode.key()
            );
            (text + &opcua, Some((l.bound, l.opcua)))
        }
        None => (text, None),
    }
}

/// The gateway's availability and timing figures of one run, as the demo reports them.
fn gateway_run(summary: &retrocomp_gateway::run::RunSummary) -> GatewayRun {
    GatewayRun {
        not_compensating_s: summary.not_compensating_s,
        not_compensating_episodes: summary.not_compensating_episodes,
        partial_s: summary.partial_s,
        partial_episodes: summary.partial_episodes,
        late_cycles: summary.late_cycles,
        max_late_ms: summary.max_late_ms,
    }
}
