//! `retrocomp fleet --broker HOST:PORT [--group G] [--tls-ca-file CA.pem] [--every-s S] [--seconds N] [--json]`: a
//! Sparkplug B host that shows every box's health (alive, compensating, degraded, idle) from its
//! NBIRTH/NDATA/NDEATH (crates/fleet/src/fleet.rs), asking boxes it has no birth for to rebirth.
//! Prints the table (headed by the time it was drawn) every `--every-s`; with `--json` it streams
//! instead one JSON object per update, one line each: `{"drawn_at", "drawn_ms", "nodes": [...]}`,
//! at most one per `--every-s` and only when something changed, plus a last one at the end.
//! With `--seconds` it stops after that long.
//! With `--collect-dir` it also collects the machines' recordings (crates/gateway/src/northbound/telemetry/recordings.rs);
//! with `--models` it diagnoses each machine's latest recording against its own model every
//! `--diagnose-every-s` and flags model drift (crates/fleet/src/drift.rs); with `--workers` it
//! publishes those diagnoses as jobs for `retrocomp fleet-worker` processes instead and arbitrates
//! who does which (crates/fleet/src/dispatch.rs).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;
use retrocomp_model::error::Chain;

use retrocomp_fleet::FleetClient;
use retrocomp_fleet::FleetView;
use retrocomp_fleet::dispatch::{Dispatcher, Finished, Job};
use retrocomp_fleet::drift::{self, DriftState, MachineDrift};
use retrocomp_gateway::northbound::telemetry::TlsConfig;
use retrocomp_gateway::northbound::telemetry::now_ms;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// MQTT broker, HOST:PORT.
    #[arg(long)]
    pub broker: String,
    /// Sparkplug group to watch (default: every group).
    #[arg(long)]
    pub group: Option<String>,
    /// PEM CA that signed the broker's certificate: connect over TLS (as a box's
    /// `[telemetry.mqtt.tls] ca_file`).
    #[arg(long)]
    pub tls_ca_file: Option<PathBuf>,
    /// Print the table this often, s.
    #[arg(long, default_value_t = 5.0)]
    pub every_s: f64,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Stream JSON instead of the table: one object per update, one line each.
    #[arg(long)]
    pub json: bool,
    /// Ask a box it has no birth for to rebirth at most this often, s.
    #[arg(long, default_value_t = 5.0)]
    pub rebirth_every_s: f64,
    /// Collect the machines' recordings into DIR/GROUP/EDGE_NODE/ (from MQTT, and what
    /// `ship-recording --to-dir DIR` wrote there).
    #[arg(long)]
    pub collect_dir: Option<PathBuf>,
    /// MQTT topic filter of the recordings.
    #[arg(long, default_value = "retrocomp/recordings/#")]
    pub recordings_topic: String,
    /// Machine models, DIR/EDGE_NODE.toml: with --collect-dir, diagnose every machine's latest
    /// recording against its own model on a schedule and flag model drift.
    #[arg(long)]
    pub models: Option<PathBuf>,
    /// Diagnose schedule, s.
    #[arg(long, default_value_t = 3600.0)]
    pub diagnose_every_s: f64,
    /// Residual against the model (µm RMS) from which an explained residual is model drift.
    #[arg(long, default_value_t = 2.0)]
    pub drift_um: f64,
    /// Stop once this many machines have been diagnosed (for scripts and tests).
    #[arg(long)]
    pub stop_after_diagnosed: Option<usize>,
    /// Do not diagnose here: publish each diagnosis as a job for `retrocomp fleet-worker`
    /// processes (an MQTT 5 shared subscription) and grant each job to one of them.
    #[arg(long)]
    pub workers: bool,
    /// With --workers: publish a job again when no worker claimed it within this long, s.
    #[arg(long, default_value_t = 30.0)]
    pub unclaimed_s: f64,
    /// With --workers: take a job back from a worker that has not finished it this long after
    /// its grant (alive but stuck), s; doubled for that job at every take-back.
    #[arg(long, default_value_t = 1800.0)]
    pub owner_timeout_s: f64,
}

/// Publish a job for every machine that has a recording (paths relative to the directories the
/// workers share with the host); how many.
fn submit_all(d: &mut Dispatcher, collect: &std::path::Path, drift_um: f64) -> usize {
    let mut n = 0;
    for (g, node) in drift::machines(collect) {
        let Some(rec) = drift::latest_recording(collect, &g, &node) else {
            continue;
        };
        let Some(rel) = rec.strip_prefix(collect).ok().and_then(|r| r.to_str()) else {
            continue;
        };
        let job = Job {
            job: 0,
            recording: rel.to_string(),
            model: format!("{node}.toml"),
            group: g,
            edge_node: node,
            drift_um,
        };
        d.submit(job, now_ms());
        n += 1;
    }
    n
}

/// A worker's accepted result into the machine's history (as the in-process path keeps it).
fn take_result(drifts: &mut BTreeMap<(String, String), MachineDrift>, f: Finished) {
    let key = (f.job.group, f.job.edge_node);
    let p = drifts.get(&key);
    let d = drift::with_history(f.drift, p);
    if d.state == DriftState::Drifted && p.is_none_or(|p| p.state != DriftState::Drifted) {
        tracing::warn!(group = key.0, edge_node = key.1, rms_um = d.rms_um, worker = f.worker, effect = ?d.finding.as_ref().map(|f| &f.effect), "fleet: model drift");
    }
    drifts.insert(key, d);
}

/// Diagnose every machine that has a recording and a model; `prev` keeps each machine's history.
fn diagnose_all(
    collect: &std::path::Path,
    models: &std::path::Path,
    drift_um: f64,
    prev: &BTreeMap<(String, String), MachineDrift>,
) -> BTreeMap<(String, String), MachineDrift> {
    let mut out = prev.clone();
    for (g, n) in drift::machines(collect) {
        let Some(rec) = drift::latest_recording(collect, &g, &n) else {
            continue;
        };
        let model = models.join(format!("{n}.toml"));
        let p = prev.get(&(g.clone(), n.clone()));
        let d = match drift::diagnose_against(&rec, &model) {
            Ok(r) => drift::judge(&r, &rec, &model, drift_um, p),
            Err(e) => drift::failed(&rec, &model, Chain(&e).to_string(), p),
        };
        if d.state == DriftState::Drifted && p.is_none_or(|p| p.state != DriftState::Drifted) {
            tracing::warn!(group = g, edge_node = n, rms_um = d.rms_um, effect = ?d.finding.as_ref().map(|f| &f.effect), "fleet: model drift");
        }
        out.insert((g, n), d);
    }
    out
}

/// A positive period in ms (saturating), or what is wrong with `flag`.
fn positive_ms(s: f64, flag: &str) -> anyhow::Result<u64> {
    Duration::try_from_secs_f64(s)
        .ok()
        .filter(|d| !d.is_zero())
        .map(|d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
        .with_context(|| format!("{flag} must be > 0"))
}

/// The arguments' checks; the unclaimed-job timeout and the owners' lease, ms.
fn checked(args: &Args) -> anyhow::Result<(u64, u64)> {
    anyhow::ensure!(
        args.every_s.is_finite() && args.every_s > 0.0,
        "--every-s must be > 0"
    );
    anyhow::ensure!(
        args.diagnose_every_s.is_finite() && args.diagnose_every_s > 0.0,
        "--diagnose-every-s must be > 0"
    );
    anyhow::ensure!(
        args.rebirth_every_s.is_finite() && args.rebirth_every_s >= 0.0,
        "--rebirth-every-s must be >= 0"
    );
    anyhow::ensure!(
        args.models.is_none() || args.collect_dir.is_some(),
        "--models needs --collect-dir (the recordings to diagnose)"
    );
    anyhow::ensure!(
        !args.workers || args.models.is_some(),
        "--workers needs --models and --collect-dir (the diagnoses to share out)"
    );
    Ok((
        positive_ms(args.unclaimed_s, "--unclaimed-s")?,
        positive_ms(args.owner_timeout_s, "--owner-timeout-s")?,
    ))
}

/// The workers' accepted results into `drifts`; true when there were any.
fn take_results(
    fc: &mut FleetClient,
    drifts: &mut BTreeMap<(String, String), MachineDrift>,
) -> bool {
    let mut took = false;
    while let Some(f) = fc.dispatch.as_mut().and_then(Dispatcher::poll_finished) {
        take_result(drifts, f);
        took = true;
    }
    took
}

/// `--stop-after-diagnosed` machines have a diagnosis.
fn enough(args: &Args, drifts: &BTreeMap<(String, String), MachineDrift>) -> bool {
    let done = drifts
        .values()
        .filter(|d| d.state != DriftState::Error)
        .count();
    args.stop_after_diagnosed.is_some_and(|n| done >= n)
}

/// The host's MQTT client as the arguments configure it: TLS, rebirth requests, the job
/// dispatcher (`--workers`), the recordings' collection. Needs a tokio runtime.
fn fleet_client(
    args: &Args,
    unclaimed_ms: u64,
    owner_timeout_ms: u64,
) -> anyhow::Result<FleetClient> {
    let tls = args.tls_ca_file.clone().map(TlsConfig::with_ca);
    let mut fc = FleetClient::with_tls(&args.broker, args.group.as_deref(), tls.as_ref())?;
    // A negative or non-finite period asks at every sweep (0 ms); a huge one saturates.
    let rebirth_every_ms = Duration::try_from_secs_f64(args.rebirth_every_s)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX));
    fc.view = FleetView::new(rebirth_every_ms);
    if args.workers {
        // Job ids start at the host's start time: a restarted host's ids are new ones.
        let d = Dispatcher::new(now_ms(), unclaimed_ms).with_owner_timeout(owner_timeout_ms);
        fc.dispatch = Some(d);
    }
    if let Some(d) = &args.collect_dir {
        std::fs::create_dir_all(d).with_context(|| d.display().to_string())?;
        fc.collect(d.clone(), &args.recordings_topic);
    }
    Ok(fc)
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let (unclaimed_ms, owner_timeout_ms) = checked(args)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut fc = fleet_client(args, unclaimed_ms, owner_timeout_ms)?;
        // Something changed since the last JSON line.
        let mut changed = true;
        let mut every = tokio::time::interval(Duration::from_secs_f64(args.every_s));
        let mut diag_every =
            tokio::time::interval(Duration::from_secs_f64(args.diagnose_every_s));
        let end = tokio::time::sleep(Duration::from_secs_f64(args.seconds.unwrap_or(1e9)));
        tokio::pin!(end);
        let mut warned = false;
        let mut said_subscribed = false;
        let mut drifts: BTreeMap<(String, String), MachineDrift> = BTreeMap::new();
        let mut diag: Option<tokio::task::JoinHandle<BTreeMap<(String, String), MachineDrift>>> =
            None;
        // With --workers: a round of jobs is due (published once the host hears the claims:
        // a claim sent before its subscription is acknowledged would be lost).
        let mut round_due = false;
        loop {
            if let (Some(d), Some(c)) = (&mut fc.dispatch, &args.collect_dir)
                && round_due
                && fc.subscribed
                && d.unfinished() == 0
            {
                round_due = false;
                let n = submit_all(d, c, args.drift_um);
                tracing::info!(jobs = n, "fleet: diagnose jobs published");
                fc.send_pending()?;
            }
            tokio::select! {
                _ = &mut end => break,
                _ = every.tick() => {
                    if !args.json {
                        print!("{}", table(&fc.view, &drifts));
                    } else if changed {
                        println!("{}", json(&fc.view, &drifts)?);
                        changed = false;
                    }
                }
                _ = diag_every.tick(), if diag.is_none() => {
                    if fc.dispatch.is_some() {
                        round_due = true;
                    } else if let (Some(c), Some(m)) = (&args.collect_dir, &args.models) {
                        let (c, m, prev, um) = (c.clone(), m.clone(), drifts.clone(), args.drift_um);
                        // diagnose is CPU work: off the MQTT loop.
                        diag = Some(tokio::task::spawn_blocking(move || diagnose_all(&c, &m, um, &prev)));
                    }
                }
                r = async { diag.as_mut().expect("guarded").await }, if diag.is_some() => {
                    diag = None;
                    drifts = r?;
                    changed = true;
                    if enough(args, &drifts) {
                        break;
                    }
                }
                r = fc.poll() => match r {
                    Ok(c) => {
                        let took = take_results(&mut fc, &mut drifts);
                        changed |= c || took;
                        if took && enough(args, &drifts) {
                            break;
                        }
                        warned = false;
                        if fc.subscribed && !said_subscribed {
                            said_subscribed = true;
                            eprintln!("retrocomp fleet: subscribed at {}", args.broker);
                        }
                    }
                    Err(e) => {
                        if !warned {
                            eprintln!("retrocomp fleet: {}: {e}; retrying", args.broker);
                            warned = true;
                        }
                    }
                },
            }
        }
        if args.json {
            println!("{}", json(&fc.view, &drifts)?);
        } else {
            print!("{}", table(&fc.view, &drifts));
        }
        Ok(())
    })
}

/// When a table or JSON line is drawn: (ms since the Unix epoch, ISO 8601 UTC to the second).
fn drawn_now() -> (u64, String) {
    let ms = now_ms();
    let at = chrono::DateTime::from_timestamp_millis(i64::try_from(ms).unwrap_or(i64::MAX))
        .map_or_else(String::new, |t| t.format("%Y-%m-%dT%H:%M:%SZ").to_string());
    (ms, at)
}

/// One update: when it was drawn and the nodes (and machines known only by their recordings),
/// each with its `verdict`, `faults`, `applied_um` and, once diagnosed, `drift`.
pub(crate) fn json(
    view: &FleetView,
    drifts: &BTreeMap<(String, String), MachineDrift>,
) -> anyhow::Result<serde_json::Value> {
    let mut nodes = Vec::new();
    for (k, n) in &view.nodes {
        let mut v = n.to_json();
        if let Some(d) = drifts.get(k) {
            v["drift"] = serde_json::to_value(d)?;
        }
        nodes.push(v);
    }
    for ((g, n), d) in drifts {
        if !view.nodes.contains_key(&(g.clone(), n.clone())) {
            nodes.push(serde_json::json!({
                "group": g, "edge_node": n, "verdict": "unknown", "drift": d,
            }));
        }
    }
    let (ms, at) = drawn_now();
    Ok(serde_json::json!({ "drawn_at": at, "drawn_ms": ms, "nodes": nodes }))
}

/// The health table, then one line per diagnosed machine (drift state, residual, finding).
pub(crate) fn table(view: &FleetView, drifts: &BTreeMap<(String, String), MachineDrift>) -> String {
    let (ms, at) = drawn_now();
    let mut s = format!("fleet at {at}, {} nodes\n", view.nodes.len());
    s.push_str(&view.table(ms));
    if !drifts.is_empty() {
        s.push_str(&format!(
            "{:<16} {:<20} {:<11} {:>9} {:>9}  finding\n",
            "group", "edge node", "model", "rms_um", "base_um"
        ));
        for ((g, n), d) in drifts {
            let what = match (&d.finding, &d.error) {
                (Some(f), _) => format!("{} on {}: {}", f.effect, f.signal, f.explanation),
                (None, Some(e)) => e.clone(),
                _ => String::new(),
            };
            s.push_str(&format!(
                "{g:<16} {n:<20} {:<11} {:>9.2} {:>9.2}  {what}\n",
                d.state.as_str(),
                d.rms_um,
                d.baseline_rms_um
            ));
        }
    }
    s
}
