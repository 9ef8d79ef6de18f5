//! Subcommand logic of the `hil-sim` binary (main.rs only parses and dispatches).

use crate::compensators::Oracle;
use crate::recording::run_to_end;
use crate::{SimConfig, World};
use std::path::{Path, PathBuf};

/// In-process compensation during `run` (to demonstrate the loop without a bus).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Compensate {
    None,
    /// Write −(static truth error at the set-point) into the origin-shift registers every PLC scan.
    Oracle,
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Simulator config (TOML).
    #[arg(long)]
    pub config: PathBuf,
    /// Output folder: recording.csv and manifest.json are written there.
    #[arg(long)]
    pub out: PathBuf,
    /// Override the config's seed.
    #[arg(long)]
    pub seed: Option<u64>,
    #[arg(long, value_enum, default_value_t = Compensate::None)]
    pub compensate: Compensate,
}

/// Run a config to the end (as fast as possible, or paced when `clock.realtime`); write the
/// recording and the manifest.
pub fn run(args: &RunArgs) -> anyhow::Result<()> {
    let mut cfg = SimConfig::from_toml_path(&args.config)?;
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    let (rows, t_s) = run_config(cfg, &args.out, args.compensate)
        .map_err(|e| e.context(format!("config {}", args.config.display())))?;
    eprintln!(
        "hil-sim: {rows} rows, {t_s:.3} s simulated → {}",
        args.out.display()
    );
    Ok(())
}

/// Library entry point of `run` (also used by tests).
pub fn run_config(
    cfg: SimConfig,
    out: &Path,
    compensate: Compensate,
) -> anyhow::Result<(u64, f64)> {
    anyhow::ensure!(
        cfg.io.dnc.is_none(),
        "[io.dnc]: the program arrives on a serial device; run it with `hil-sim serve`"
    );
    std::fs::create_dir_all(out).map_err(|e| anyhow::anyhow!("--out {}: {e}", out.display()))?;
    let scan = cfg.plc.scan_s;
    let realtime = cfg.clock.realtime;
    let pacer = crate::clock::RealtimePacer::new(cfg.dt_s() / cfg.clock.speed);
    let mut world = World::new(cfg)?;
    let manifest = serde_json::to_string_pretty(&world.manifest())?;
    std::fs::write(out.join("manifest.json"), manifest + "\n")?;
    let file = std::fs::File::create(out.join("recording.csv"))?;
    let mut oracle = Oracle::new(scan);
    let mut failure: Option<anyhow::Error> = None;
    let mut dwell_ends = String::new();
    let (_, rows) = run_to_end(&mut world, std::io::BufWriter::new(file), |w| {
        if let Some(d) = w.take_dwell_end() {
            dwell_ends.push_str(&d.csv_row());
        }
        if realtime {
            std::thread::sleep(pacer.until_next(w.ticks()));
        }
        if compensate == Compensate::Oracle
            && failure.is_none()
            && let Err(e) = oracle.update(w)
        {
            failure = Some(e);
        }
    })?;
    if let Some(e) = failure {
        return Err(e.context("oracle compensator"));
    }
    if !dwell_ends.is_empty() {
        let text = crate::world::DwellEnd::CSV_HEADER.to_string() + &dwell_ends;
        std::fs::write(out.join("dwell_ends.csv"), text)?;
    }
    Ok((rows, world.t_s()))
}

#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Simulator config (TOML) with an `[io]` section.
    #[arg(long)]
    pub config: PathBuf,
    /// Optional output folder for recording.csv + manifest.json.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override the config's seed.
    #[arg(long)]
    pub seed: Option<u64>,
}

/// Run the world with its buses until the program ends or Ctrl-C.
pub fn serve(args: &ServeArgs) -> anyhow::Result<()> {
    let mut cfg = SimConfig::from_toml_path(&args.config)?;
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    anyhow::ensure!(
        cfg.io.modbus.is_some() || cfg.io.can.is_some() || cfg.io.weighing.is_some(),
        "{}: serve needs an [io.modbus], [io.can] or [io.weighing] section",
        args.config.display()
    );
    // Before the runtime exists: its threads inherit the policy of the thread that creates them.
    if let (true, Some(p)) = (cfg.clock.realtime, cfg.clock.realtime_priority) {
        use retrocomp_bus::realtime::{RtOutcome, set_current_thread_fifo};
        match set_current_thread_fifo(p) {
            RtOutcome::Granted { priority } => eprintln!("hil-sim: SCHED_FIFO {priority} granted"),
            RtOutcome::Refused { priority, why } => eprintln!(
                "hil-sim: clock.realtime_priority {priority}: SCHED_FIFO refused ({why}); \
                 running under the normal scheduler"
            ),
            RtOutcome::NotRequested => {}
        }
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mem = retrocomp_bus::can::MemBus::default();
        let running = crate::io::serve::start(cfg, Some(mem), args.out.as_deref()).await?;
        if let Some(a) = running.modbus_tcp {
            eprintln!("hil-sim: modbus tcp on {a}");
        }
        if let Some(p) = &running.rtu_pty {
            eprintln!("hil-sim: modbus rtu on {}", p.display());
        }
        if let Some(p) = &running.weighing_pty {
            eprintln!("hil-sim: weighing lines on {}", p.display());
        }
        // SIGTERM as Ctrl-C: `running` is dropped on the way out, which removes the pty links.
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        tokio::select! {
            r = running.join() => { let steps = r?; eprintln!("hil-sim: program ended after {steps} steps"); }
            _ = tokio::signal::ctrl_c() => eprintln!("hil-sim: interrupted"),
            _ = term.recv() => eprintln!("hil-sim: terminated"),
        }
        Ok(())
    })
}

#[derive(Debug, clap::Args)]
pub struct GenCasesArgs {
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of cases per family (30 % nulls; in the standard family every effect id appears
    /// every 20 cases).
    #[arg(long, default_value_t = 100)]
    pub count: usize,
    /// Comma-separated case families: standard (`case_NNNN`, unchanged), ar099, random_walk,
    /// rw_decoy, rpm_heat, ambient_drift, regime (`<family>_NNNN`); `hard` = the six hard ones,
    /// `all` = all seven (docs/diagnose.md).
    #[arg(long, default_value = "standard", value_delimiter = ',')]
    pub families: Vec<String>,
    #[arg(long)]
    pub out: PathBuf,
}

/// `hil-sim gen-cases`: the concealed-effect cases with their truth manifests.
pub fn gen_cases(a: &GenCasesArgs) -> anyhow::Result<()> {
    use crate::cases::Family;
    let mut fams = vec![];
    for name in &a.families {
        match name.as_str() {
            "all" => fams.extend(Family::ALL),
            "hard" => fams.extend(Family::HARD),
            n => fams.push(Family::parse(n).ok_or_else(|| {
                anyhow::anyhow!(
                    "--families: unknown family `{n}` (expected all, hard or one of {})",
                    Family::ALL.map(Family::name).join(", ")
                )
            })?),
        }
    }
    fams.dedup();
    let files = crate::cases::write_family_cases(a.seed, a.count, &fams, &a.out)?;
    println!("wrote {} cases to {}", files.len(), a.out.display());
    Ok(())
}
