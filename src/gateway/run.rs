//! The async runtime shell around [`Engine`]: samples arrive on a channel (from the bus sources),
//! the engine runs every `cycle_ms`, the latest status goes to the HTTP endpoint, and a separate sink
//! task writes the outputs so a slow or dead controller never stalls the cycle.
//!
//! Origin-shift start-up: the sink reads what the controller holds before the engine starts, and the
//! engine continues from it (no jump after a gateway restart). The sink reads the controller again
//! before every write (`origin_shift/sink.rs`); when the controller changed the value behind our back
//! (it restarted, an operator cleared it) the engine is reseeded from what it holds.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context as _, bail};
use tokio::sync::{mpsc, watch};
use tokio::time::MissedTickBehavior;

use super::config::FieldConfig;
use super::engine::{Engine, ErrorModel};
use super::http::{Api, Control, Limits, serve};
use super::origin_shift_sink::{SinkChannels, origin_shift_task};
use super::status::{SinkStatus, StatusSnapshot};
use super::supervise::SourceFeed;
use crate::bus::Sample;
use crate::origin_shift::{OriginShiftClient, SinkAxis};

/// What a run reports when it stops.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    pub cycles: u64,
    pub writes_ok: u64,
    pub writes_failed: u64,
    /// Engine compute time per cycle, µs (p50, p99) over the last 65 536 cycles.
    pub compute_us_p50: f64,
    pub compute_us_p99: f64,
}

type Outputs = Vec<(String, f64)>;

/// Run until `shutdown` resolves. `epoch` is the clock the sources stamp samples with (`t_s` =
/// seconds since it); the engine runs on the same clock so staleness is judged right.
/// `status_addr` receives the bound status address (port 0 allowed).
/// `sources` is the sample channel, or a [`SourceFeed`] from `spawn_sources` (then the sources'
/// links show in the status, and the run stops with an error when a source or the sink task ends).
pub async fn run(
    cfg: FieldConfig,
    mut model: Box<dyn ErrorModel + Send>,
    sources: impl Into<SourceFeed>,
    epoch: std::time::Instant,
    shutdown: impl std::future::Future<Output = ()>,
    status_addr: Option<tokio::sync::oneshot::Sender<SocketAddr>>,
) -> anyhow::Result<RunSummary> {
    let SourceFeed {
        mut samples,
        board: source_board,
        mut deaths,
        cycles: cycle_counter,
    } = sources.into();
    let (status_tx, status_rx) = watch::channel::<Option<Arc<StatusSnapshot>>>(None);
    let listen: SocketAddr = cfg
        .gateway
        .status_listen
        .parse()
        .context("gateway.status_listen")?;
    // Actions from the endpoint (token-guarded) reach the cycle loop through this channel.
    let (control_tx, mut control_rx) = mpsc::channel::<Control>(8);
    let api = Api {
        token: cfg.gateway.api_token.clone(),
        control_tx: Some(control_tx),
    };
    // The OPC UA server (if configured) reads the same snapshots on its own tasks.
    let opcua = match &cfg.opcua {
        Some(o) => {
            let rx = status_rx.clone();
            let srv = super::opcua::start(o, &cfg.gateway.name, rx, model.identity()).await?;
            tracing::info!("OPC UA endpoint {} (read-only)", srv.endpoint);
            Some(srv)
        }
        None => None,
    };
    let (bound, http_task) = serve(listen, status_rx, api, Limits::default())
        .await
        .with_context(|| format!("binding status endpoint {listen}"))?;
    tracing::info!(%bound, "status endpoint: GET /status, /metrics");
    if let Some(tx) = status_addr {
        let _ = tx.send(bound);
    }

    // Sink first: origin shift must know what the controller holds before the engine starts.
    let (out_tx, out_rx) = watch::channel::<Outputs>(Vec::new());
    let (reseed_tx, mut reseed_rx) = mpsc::channel::<(String, f64)>(8);
    let (sink_status_tx, sink_status_rx) = watch::channel::<SinkStatus>(SinkStatus::default());
    let mut initial = BTreeMap::new();
    // Positions the controller writes into a served register image (origin-shift server).
    let (served_tx, mut served_rx) = mpsc::channel::<Sample>(1024);
    let mut sink_task = if let Some(srv) = cfg.sink.origin_shift_server.clone() {
        let (task, held) =
            start_origin_shift_server(&cfg, srv, out_rx, served_tx, sink_status_tx, epoch).await?;
        initial = held;
        Some(task)
    } else if let Some(os) = cfg.sink.origin_shift.clone() {
        let mut client =
            OriginShiftClient::new(os.client(), os.map.clone()).context("sink.origin_shift.map")?;
        initial = read_initial(&mut client).await;
        // A value beyond the clamp is not a start value: the sink refuses to write that axis (a
        // fault) until the controller's value is back in range, then the engine continues from it.
        initial.retain(|axis, held_um| {
            let max = cfg.safety_for(axis).max_correction_um;
            let ok = held_um.is_finite() && held_um.abs() <= max;
            if !ok {
                tracing::error!(axis, held_um, max, "controller holds a correction beyond the clamp: not writing this axis until it is back in range");
            }
            ok
        });
        let axes = cfg
            .axes
            .iter()
            .map(|a| {
                let s = cfg.safety_for(&a.name);
                SinkAxis {
                    axis: a.name.clone(),
                    max_correction_um: s.max_correction_um,
                    max_change_um_per_write: s.max_change_um_per_cycle,
                }
            })
            .collect();
        Some(tokio::spawn(origin_shift_task(
            os,
            client,
            axes,
            SinkChannels {
                out_rx,
                reseed_tx,
                status: sink_status_tx,
            },
            epoch,
        )))
    } else {
        cfg.sink.quadrature.clone().map(|q| {
            tokio::spawn(super::quadrature_sink::quadrature_task(
                q,
                out_rx,
                sink_status_tx,
            ))
        })
    };

    let mut engine = Engine::new(&cfg, &initial)?;
    let mut tick = tokio::time::interval(Duration::from_millis(cfg.gateway.cycle_ms));
    tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
    // The last COMPUTE_WINDOW cycles' compute times, overwritten in a ring: a gateway runs for
    // months, so an ever-growing log would be a leak (1 kHz × 8 B = 690 MB a day).
    let mut compute_ns: Vec<u64> = Vec::with_capacity(COMPUTE_WINDOW);
    let mut summary = RunSummary::default();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            _ = &mut shutdown => break,
            _ = tick.tick() => {}
            why = deaths.next() => bail!("{why}: stopping the gateway"),
            end = async { match sink_task.as_mut() { Some(t) => t.await, None => std::future::pending().await } } => {
                let why = match end { Ok(()) => "returned".to_string(), Err(e) => e.to_string() };
                tracing::error!(why, "the sink task ended; stopping so the service manager restarts the gateway");
                bail!("the sink task ended ({why}): stopping the gateway");
            }
        }
        while let Ok(s) = samples.try_recv() {
            engine.ingest(&s);
        }
        while let Ok(s) = served_rx.try_recv() {
            engine.ingest(&s);
        }
        while let Ok((axis, held)) = reseed_rx.try_recv() {
            if let Err(e) = engine.reseed(&axis, held) {
                tracing::error!(%e, axis, "cannot continue from the controller's value; holding");
            }
        }
        // Disabling ramps each axis to zero through the safety ramps (Engine::set_enabled).
        while let Ok(Control::SetCompensation { enabled }) = control_rx.try_recv() {
            engine.set_enabled(enabled);
        }
        let t0 = std::time::Instant::now();
        let outs = engine.cycle_in_place(epoch.elapsed().as_secs_f64(), model.as_mut());
        let took_ns = t0.elapsed().as_nanos() as u64;
        if compute_ns.len() < COMPUTE_WINDOW {
            compute_ns.push(took_ns);
        } else {
            compute_ns[(summary.cycles as usize) % COMPUTE_WINDOW] = took_ns;
        }
        // Reuse the channel's buffer (String::clone_from keeps the axis names' allocations).
        out_tx.send_modify(|held| copy_outputs(held, outs));
        let mut snap = engine.snapshot();
        let sink = sink_status_rx.borrow().clone();
        snap.active_faults.extend(sink.faults.iter().cloned());
        snap.sink = Some(sink);
        source_board.copy_into(&mut snap.sources);
        for src in &snap.sources {
            let faults = src.faults.iter().map(|&(k, t)| (src.name.clone(), k, t));
            snap.active_faults.extend(faults);
        }
        let _ = status_tx.send(Some(Arc::new(snap)));
        summary.cycles += 1;
        cycle_counter.set(summary.cycles);
    }
    if let Some(t) = sink_task {
        t.abort();
    }
    http_task.abort();
    if let Some(o) = opcua {
        o.stop();
    }
    let st = sink_status_rx.borrow().clone();
    summary.writes_ok = st.writes_ok;
    summary.writes_failed = st.writes_failed;
    compute_ns.sort_unstable();
    let pct = |p: f64| {
        compute_ns
            .get(((compute_ns.len() as f64 - 1.0) * p) as usize)
            .map_or(0.0, |n| *n as f64 / 1e3)
    };
    summary.compute_us_p50 = pct(0.5);
    summary.compute_us_p99 = pct(0.99);
    Ok(summary)
}

/// Start the origin-shift server, wait until the controller reports what it holds (the engine's
/// start value), and spawn its update task.
async fn start_origin_shift_server(
    cfg: &FieldConfig,
    srv: crate::origin_shift::server::ServerConfig,
    out_rx: watch::Receiver<Outputs>,
    samples: mpsc::Sender<Sample>,
    status: watch::Sender<SinkStatus>,
    epoch: std::time::Instant,
) -> anyhow::Result<(tokio::task::JoinHandle<()>, BTreeMap<String, f64>)> {
    use crate::origin_shift::server::OriginShiftServer;
    use crate::origin_shift::server_core::Guard;
    let guards: Vec<(String, Guard)> = cfg
        .axes
        .iter()
        .map(|a| {
            let s = cfg.safety_for(&a.name);
            let g = Guard {
                max_correction_um: s.max_correction_um,
                max_change_um_per_update: s.max_change_um_per_cycle,
            };
            (a.name.clone(), g)
        })
        .collect();
    let mut server = OriginShiftServer::start(srv, &guards)
        .await
        .context("sink.origin_shift_server")?;
    let clock = move || epoch.elapsed().as_secs_f64();
    let held = server.wait_seeded(&samples, &clock).await;
    let task = tokio::spawn(server.run(out_rx, samples, status, clock));
    Ok((task, held))
}

/// How many recent cycles the compute-time percentiles of [`RunSummary`] cover.
const COMPUTE_WINDOW: usize = 1 << 16;

/// `dst = src` without allocating when the axes are the same as last cycle.
fn copy_outputs(dst: &mut Outputs, src: &[(String, f64)]) {
    if dst.len() != src.len() {
        dst.clear();
        dst.extend_from_slice(src);
        return;
    }
    for ((dn, dv), (sn, sv)) in dst.iter_mut().zip(src) {
        dn.clone_from(sn);
        *dv = *sv;
    }
}

/// Read the controller's current values, retrying until it answers (without them the first write
/// could jump). Logs every 20th failure.
async fn read_initial(client: &mut OriginShiftClient) -> BTreeMap<String, f64> {
    let mut attempt = 0u64;
    loop {
        match client.read_current().await {
            Ok(v) => {
                tracing::info!(
                    ?v,
                    "controller holds these corrections; continuing from them"
                );
                return v.into_iter().collect();
            }
            Err(e) => {
                if attempt.is_multiple_of(20) {
                    tracing::warn!(%e, "waiting for the controller before starting");
                }
                attempt += 1;
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    }
}

/// Refuse to run a config that would correct nothing in a field deployment.
pub fn require_sink(cfg: &FieldConfig) -> anyhow::Result<()> {
    if cfg.sink.origin_shift.is_none()
        && cfg.sink.quadrature.is_none()
        && cfg.sink.origin_shift_server.is_none()
    {
        bail!(
            "no [sink.origin_shift], [sink.origin_shift_server] or [sink.quadrature] in the config: nothing would be corrected"
        );
    }
    super::quadrature_sink::check_buildable(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_copied_in_place_and_follow_a_changed_axis_set() {
        let mut held: Outputs = vec![("x".into(), 1.0), ("z".into(), 2.0)];
        let names_at = held[0].0.as_ptr();
        copy_outputs(&mut held, &[("x".into(), -3.5), ("z".into(), 4.0)]);
        assert_eq!(held, [("x".to_string(), -3.5), ("z".to_string(), 4.0)]);
        assert_eq!(held[0].0.as_ptr(), names_at, "the name's buffer was reused");
        copy_outputs(&mut held, &[("y".into(), 0.25)]);
        assert_eq!(held, [("y".to_string(), 0.25)]);
    }
}
