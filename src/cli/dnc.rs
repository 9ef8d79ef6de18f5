//! `retrocomp dnc --config FIELD.toml (--program FILE | --listen tcp:ADDR | --sender-port DEV)
//! [--port DEV] [--resume-from N] [--log SENT.csv] [--model MODEL.toml]`
//!
//! DNC drip-feed with live offsets (docs/dnc.md): streams the program to the controller's serial
//! DNC input with the `[dnc]` link settings of the field config, adding to each motion block, as it
//! is sent, the correction the live model (the field config's model, fed by its sources) has for
//! the block's end point, through the last-step guard (clamp, per-block cap). The send log (one CSV
//! row per block: line, nominal end point, correction, time) is flushed per block. An interrupted
//! or refused transfer prints the block to resume from; resuming is only ever from the block the
//! operator names with `--resume-from`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use retrocomp::dnc::{
    CoreConfig, DncCore, DncIo, DriftConfig, EngineAtPoint, LeadConfig, LiveCorrections,
    ProgramSource, StatusTx, run_dnc,
};
use retrocomp_gateway::northbound::http::{Api, Limits, serve};
use retrocomp_gateway::sources::spawn_sources;
use retrocomp_model::Axis;

#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("source").args(["program", "listen", "sender_port"])))]
pub(crate) struct Args {
    /// `--config` (with a `[dnc]` section; model and sensors as for `run`) and `--model`.
    #[command(flatten)]
    pub field: super::run::FieldArgs,
    /// The NC program to send.
    #[arg(long)]
    pub program: Option<PathBuf>,
    /// Take the program from a DNC sender connecting here: "tcp:127.0.0.1:7000".
    #[arg(long, value_parser = parse_listen)]
    pub listen: Option<std::net::SocketAddr>,
    /// Take the program from a DNC sender on this serial device (in-line between the DNC PC and
    /// the controller; the sender is held back with XON/XOFF). Default: `dnc.sender_port` when
    /// neither --program nor --listen is given.
    #[arg(long)]
    pub sender_port: Option<String>,
    /// The controller's DNC serial device; overrides `dnc.port`.
    #[arg(long)]
    pub port: Option<String>,
    /// Send from this source line on (after an interrupted transfer: the line the box printed,
    /// or any the operator chooses); the lines before set the modal state only.
    #[arg(long, default_value_t = 1)]
    pub resume_from: u64,
    /// Where the send log goes (CSV, one row per block).
    #[arg(long, default_value = "dnc-sent.csv")]
    pub log: PathBuf,
}

fn parse_listen(s: &str) -> Result<std::net::SocketAddr, String> {
    let a = s
        .strip_prefix("tcp:")
        .ok_or_else(|| format!("{s:?}: expected tcp:HOST:PORT"))?;
    a.parse()
        .map_err(|e| format!("{a:?}: {e} (expected tcp:127.0.0.1:7000)"))
}

/// Per axis X, Y, Z: the clamp of the field config's safety and the per-block cap (an axis the
/// config does not drive gets clamp 0: never a correction).
fn guard_limits(
    cfg: &retrocomp_gateway::config::FieldConfig,
    dnc: &retrocomp_gateway::sinks::dnc::DncSection,
) -> [(f64, f64); 3] {
    let mut limits = [(0.0, 0.0); 3];
    for a in &cfg.axes {
        let Some(ax) = Axis::from_name(&a.name) else {
            continue;
        };
        let s = cfg.safety_for(&a.name);
        let cap = dnc
            .max_change_um_per_block
            .unwrap_or(s.max_change_um_per_cycle);
        limits[ax.index()] = (s.max_correction_um, cap);
    }
    limits
}

/// The gateway's status endpoint on `[gateway] status_listen` (read routes only: a transfer takes
/// no actions), fed with the transfer's snapshots.
async fn serve_status(cfg: &retrocomp_gateway::config::FieldConfig) -> anyhow::Result<StatusTx> {
    let listen: std::net::SocketAddr = cfg
        .gateway
        .status_listen
        .parse()
        .context("gateway.status_listen")?;
    let (tx, rx) = tokio::sync::watch::channel(None);
    let limits = Limits {
        policy: cfg.gateway.listen_policy.clone(),
        ..Limits::default()
    };
    let (bound, _task) = serve(listen, rx, Api::default(), limits)
        .await
        .with_context(|| format!("binding the status endpoint {listen} (gateway.status_listen)"))?;
    eprintln!("dnc: status on http://{bound}/status and /metrics");
    Ok(tx)
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    super::term::init_tracing("info");
    let checked = args.field.check()?;
    let cfg = checked.cfg;
    let Some(dnc) = cfg.dnc.clone() else {
        bail!(
            "{}: no [dnc] section: the link to the controller (baud, parity, flow, max_line_chars …) must be stated (docs/dnc.md)",
            args.field.config.display()
        );
    };
    let port = args
        .port
        .clone()
        .or_else(|| dnc.port.clone())
        .with_context(|| {
            format!(
                "{}: dnc.port: no controller port (or --port)",
                args.field.config.display()
            )
        })?;
    let sender = args.sender_port.clone().or_else(|| dnc.sender_port.clone());
    let source = match (&args.program, args.listen, sender) {
        (Some(p), _, _) => ProgramSource::File(p.clone()),
        (_, Some(a), _) => ProgramSource::Tcp(a),
        (_, _, Some(d)) => ProgramSource::Serial(d),
        _ => bail!(
            "no program source: give --program FILE, --listen tcp:ADDR or --sender-port DEV (or dnc.sender_port)"
        ),
    };
    if let ProgramSource::Serial(d) = &source
        && *d == port
    {
        bail!("--sender-port {d} is the controller's port");
    }
    let limits = guard_limits(&cfg, &dnc);
    // The gateway's engine judges the inputs (its `[[channel]]` limits) and evaluates the model;
    // no safety step of its own runs: the guard below is the one output limit.
    let mut engine = cfg.engine(&Default::default())?;
    engine.report_undelivered(&checked.optional_missing);
    let mut live = LiveCorrections::new(
        Box::new(EngineAtPoint::new(engine, Box::new(checked.model))),
        limits,
    );
    if dnc.predict_drift {
        live = live.with_drift(DriftConfig {
            window_s: dnc.drift_window_s,
            max_horizon_s: dnc.predict_max_s,
        });
    }
    let core_cfg = CoreConfig {
        line_end: dnc.line_end,
        max_line_chars: dnc.max_line_chars,
        leader_nuls: dnc.leader_nuls,
        trailer_nuls: dnc.trailer_nuls,
        stall_timeout_s: dnc.stall_timeout_s,
        start_timeout_s: dnc.start_timeout_s,
        semicolon_is_eob: dnc.semicolon_is_eob,
        diameter_x: dnc.diameter_x,
        resume_from: args.resume_from,
        max_correction_um: cfg.safety.max_correction_um,
        lead: LeadConfig {
            lead_blocks: dnc.lead_blocks.unwrap_or(dnc.buffer_lines),
            buffer_lines: dnc.buffer_lines,
            rapid_mm_min: dnc.rapid_mm_min,
            control_speed: dnc.control_speed,
            dwell_p_ms: dnc.semicolon_is_eob,
        },
    };
    if args.resume_from > 1 {
        eprintln!(
            "dnc: resuming from line {} (the lines before set the modal state only)",
            args.resume_from
        );
    }
    let mut log = std::io::BufWriter::new(
        std::fs::File::create(&args.log)
            .with_context(|| format!("creating the send log {}", args.log.display()))?,
    );
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let summary = rt.block_on(async {
        let epoch = std::time::Instant::now();
        let feed = spawn_sources(&cfg, epoch).await?;
        let status = serve_status(&cfg).await?;
        let mut core = DncCore::new(core_cfg, &live);
        let r = run_dnc(
            &dnc,
            &port,
            &source,
            &mut core,
            &live,
            DncIo {
                samples: Some(feed.samples),
                epoch,
                status: Some(status),
            },
            &mut log,
        )
        .await
        .with_context(|| format!("DNC transfer to {port}"))?;
        anyhow::Ok(r)
    })?;
    eprintln!(
        "dnc: {} blocks sent; {} stall(s), {} block(s) with the held correction (model), {} capped by the guard; log {}",
        summary.blocks_sent,
        summary.stalls,
        summary.model_faults,
        summary.guard_limited,
        args.log.display()
    );
    if let Some((line, why)) = summary.interrupted {
        // The correction travels inside the blocks: the control holds no register of the box's,
        // only the blocks it has received (up to its buffer), the last of them carrying this.
        match summary.last_correction {
            Some((l, c)) => eprintln!(
                "dnc: the control holds only the blocks it received; the last compensated one (line {l}) carries X {:.1} µm, Y {:.1} µm, Z {:.1} µm; no origin or offset register was touched",
                c[0], c[1], c[2]
            ),
            None => eprintln!("dnc: no compensated block reached the control"),
        }
        bail!(
            "transfer stopped: {why}\nresume with --resume-from {line} (the first block not completely sent)"
        );
    }
    Ok(())
}
