//! `retrocomp demo [--out DIR] [--json] [--seconds N] [--seed N] [--serve [ADDR]] [--mqtt HOST:PORT]`: the main job on a machine with no hardware
//! (crates/gateway/src/demo). Prints what the fit of the measurement runs found, then per axis the
//! tool-tip error RMS and max (µm) of the four runs; with
//! `--json` the last stdout line is the machine-readable summary (fixed keys, see
//! docs/demo.md).

use std::path::PathBuf;

use retrocomp::demo::{DemoOptions, Mode, locate_hil_sim, run_demo};

use super::report_args::ReportArgs;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Output folder: recordings, configs, models, SVG plots.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// End with one JSON line on stdout.
    #[arg(long)]
    pub json: bool,
    /// Length of the accelerated warm-up (X strokes with the spindle at 4000 rpm), simulated s;
    /// the part program follows. The sim runs in real time, so this adds to the wall time.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Seed of the simulated machine's noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// After the runs, keep a live gateway (full model) running against hil-sim, its page at
    /// http://ADDR/ (the shop-floor page, /status, /metrics), until Ctrl-C. Loopback by default.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8080")]
    pub serve: Option<String>,
    /// Publish each compensated run as Sparkplug B to this MQTT broker (HOST:PORT; group
    /// `retrocomp-demo`, one edge node per run: `mill-geometric`, `mill-full`, `mill-fitted`, and
    /// `mill-live` for the `--serve` gateway), for any Sparkplug client to watch.
    #[arg(long, value_name = "HOST:PORT")]
    pub mqtt: Option<String>,
    /// `SCHED_FIFO` priority (1–99) for each run's simulated machine, CAN hub and the gateway's
    /// cycle, sink and readers, so a busy host does not stall them (issue 18.5); 0 = the normal
    /// scheduler. Refused (no root / CAP_SYS_NICE / RLIMIT_RTPRIO) → the normal scheduler.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u8).range(0..=99))]
    pub realtime_priority: u8,
    /// The report's header hashes the models the demo wrote (truth geometry, full, fitted).
    #[command(flatten)]
    pub report: ReportArgs,
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    // Quiet by default: the table and the JSON line are the output (RUST_LOG overrides). The CAN
    // source reports "bus closed" when hil-sim ends its program and leaves the hub: expected here.
    super::term::init_tracing("error,retrocomp_gateway::sources=off");
    anyhow::ensure!(
        args.seconds.is_finite() && (0.0..=60.0).contains(&args.seconds),
        "--seconds {}: the warm-up must be between 0 and 60 s (the demo runs in real time)",
        args.seconds
    );
    if let Some(b) = &args.mqtt {
        retrocomp_gateway::northbound::telemetry::demo_section(b, "check")
            .mqtt
            .as_ref()
            .map_or(Ok(()), |m| m.check())
            .map_err(|(key, what)| anyhow::anyhow!("--mqtt {b}: {key}: {what}"))?;
    }
    if let Some(listen) = &args.serve {
        // Checked before the four runs (≈ 40 s), not after them; the live gateway binds it again.
        let addr: std::net::SocketAddr = listen.parse().map_err(|e| {
            anyhow::anyhow!("--serve {listen}: expected IP:PORT, e.g. 127.0.0.1:8080 ({e})")
        })?;
        std::net::TcpListener::bind(addr)
            .map_err(|e| anyhow::anyhow!("--serve {listen}: cannot listen there: {e}"))?;
    }
    let hil_sim = locate_hil_sim()?;
    if args.realtime_priority > 0 {
        warn_if_fifo_refused(args.realtime_priority);
    }
    let opts = DemoOptions {
        out: args.out.clone(),
        seed: args.seed,
        warmup_s: args.seconds,
        hil_sim,
        mqtt: args.mqtt.clone(),
        realtime_priority: (args.realtime_priority > 0).then_some(args.realtime_priority),
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let progress = super::term::Progress::spinner(
        "demo: four runs of the program (uncompensated, geometric truth, full truth, fitted)",
    );
    let r = rt.block_on(run_demo(&opts))?;
    progress.finish();
    println!(
        "retrocomp demo: model fitted from hil-sim measurement runs ({:.1} s; {}/models/mill-fitted.toml):",
        r.campaign_s,
        args.out.display()
    );
    for l in &r.fit_report {
        println!("  {l}");
    }
    println!("retrocomp demo: tool-tip error (actual − nominal), µm, over the whole program");
    println!(
        "{:<14} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>10}",
        "run", "x rms", "x max", "y rms", "y max", "z rms", "z max", "|e| max"
    );
    for run in &r.runs {
        let s = &run.stats;
        println!(
            "{:<14} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>8.2} {:>10.2}",
            run.mode.key(),
            s.x.rms_um,
            s.x.max_um,
            s.y.rms_um,
            s.y.max_um,
            s.z.rms_um,
            s.z.max_um,
            s.volumetric_max_um
        );
    }
    print_gateway_health(&r.runs);
    println!(
        "max volumetric error falls {:.1} % with the full (truth) model, {:.1} % with the fitted model; {:.1} s wall; files in {}",
        r.stats.volumetric_reduction_pct(),
        r.stats.fitted_volumetric_reduction_pct(),
        r.wall_s,
        args.out.display()
    );
    let models = args.out.join("models");
    let inputs =
        ["mill-geometric.toml", "mill-full.toml", "mill-fitted.toml"].map(|f| models.join(f));
    args.report.write(
        "retrocomp demo: compensation on a simulated mill",
        &inputs.iter().map(|p| p.as_path()).collect::<Vec<_>>(),
        || Ok(super::demo_report::sections(&r, args.seed, args.seconds)),
    )?;
    if args.json {
        println!("{}", serde_json::to_string(&r.stats)?);
    }
    if let Some(listen) = &args.serve {
        // With --json the summary stays the last stdout line: the address goes to stderr then.
        let json = args.json;
        let live = retrocomp::demo::serve_live(&opts, listen, move |addr, opcua| {
            let line = format!(
                "retrocomp demo: live page http://{addr}/ (JSON /status, Prometheus /metrics); OPC UA {opcua} (read-only); Ctrl-C stops"
            );
            if json {
                eprintln!("{line}");
            } else {
                println!("{line}");
            }
        });
        rt.block_on(async {
            tokio::select! {
                r = live => r,
                _ = tokio::signal::ctrl_c() => Ok(()),
            }
        })?;
    }
    Ok(())
}

/// One line per compensated run: did the gateway compensate the whole program? A run that dropped
/// compensation (stale inputs under host load, a model fault) says so here, not only in a log.
fn print_gateway_health(runs: &[retrocomp::demo::RunResult]) {
    for run in runs.iter().filter(|r| r.mode != Mode::Uncompensated) {
        let g = &run.gateway;
        if g.not_compensating_episodes > 0 {
            println!(
                "retrocomp demo: WARNING: the {} run did NOT compensate for {:.2} s in {} episode(s) \
                 (stale inputs; {} late cycles, worst {:.1} ms): its figures include that time",
                run.mode.key(),
                g.not_compensating_s,
                g.not_compensating_episodes,
                g.late_cycles,
                g.max_late_ms
            );
        } else {
            println!(
                "retrocomp demo: the {} run compensated throughout ({} late cycles, worst {:.1} ms)",
                run.mode.key(),
                g.late_cycles,
                g.max_late_ms
            );
        }
        if g.partial_episodes > 0 {
            println!(
                "retrocomp demo: WARNING: the {} run compensated WITHOUT its load terms (force \
                 stale) for {:.2} s in {} episode(s)",
                run.mode.key(),
                g.partial_s,
                g.partial_episodes
            );
        }
    }
}

/// The demo's machine, hub and gateway ask for `SCHED_FIFO` (`--realtime-priority`); refused (not
/// root, no rtprio limit), each logs it only into its run's log, and on a busy host the compensated
/// runs come out worse (the fitted run measured 4.10 µm instead of 2.57). Say so here, once, with
/// what to do; probed on a throwaway thread so this one keeps its policy.
fn warn_if_fifo_refused(priority: u8) {
    let probe =
        std::thread::spawn(move || retrocomp_bus::realtime::set_current_thread_fifo(priority));
    if let Ok(retrocomp_bus::realtime::RtOutcome::Refused { why, .. }) = probe.join() {
        eprintln!(
            "retrocomp demo: SCHED_FIFO {priority} refused ({why}): the simulated machine, the hub \
             and the gateway run under the normal scheduler, so on a busy host the compensated runs \
             lose accuracy (docs/realtime.md). To allow it: run as root, or give your user a \
             real-time limit (`ulimit -r {priority}` after adding `<user> - rtprio {priority}` to \
             /etc/security/limits.d/retrocomp.conf and logging in again), or pass \
             --realtime-priority 0 to silence this."
        );
    }
}
