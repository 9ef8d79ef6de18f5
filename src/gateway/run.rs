//! The async runtime shell around [`Engine`]: samples arrive on a channel (from the bus sources),
//! the engine runs every `cycle_ms`, the latest status goes to the HTTP endpoint, and a separate sink
//! task writes the outputs so a slow or dead controller never stalls the cycle.
//!
//! Origin-shift start-up: the sink reads what the controller holds before the engine starts, and the
//! engine continues from it (no jump after a gateway restart). After a reconnect the sink reads again;
//! if the controller lost our value (it restarted), the engine is reseeded from what it holds.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context as _, bail};
use tokio::sync::{mpsc, watch};
use tokio::time::MissedTickBehavior;

use super::config::{FieldConfig, OriginShiftSink};
use super::engine::{Engine, ErrorModel};
use super::health::{FaultKind, FaultLog};
use super::http::{Api, Control, Limits, serve};
use super::status::{SinkStatus, StatusSnapshot};
use crate::bus::Sample;
use crate::origin_shift::{OriginShiftClient, Outcome};

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
pub async fn run(
    cfg: FieldConfig,
    mut model: Box<dyn ErrorModel + Send>,
    mut samples: mpsc::Receiver<Sample>,
    epoch: std::time::Instant,
    shutdown: impl std::future::Future<Output = ()>,
    status_addr: Option<tokio::sync::oneshot::Sender<SocketAddr>>,
) -> anyhow::Result<RunSummary> {
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
    let sink_task = if let Some(os) = cfg.sink.origin_shift.clone() {
        let mut client =
            OriginShiftClient::new(os.client(), os.map.clone()).context("sink.origin_shift.map")?;
        initial = read_initial(&mut client).await;
        let caps = cfg
            .axes
            .iter()
            .map(|a| {
                (
                    a.name.clone(),
                    cfg.safety_for(&a.name).max_change_um_per_cycle,
                )
            })
            .collect();
        Some(tokio::spawn(origin_shift_task(
            os,
            client,
            caps,
            initial.clone(),
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
        }
        while let Ok(s) = samples.try_recv() {
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
        snap.sink = Some(sink_status_rx.borrow().clone());
        let _ = status_tx.send(Some(Arc::new(snap)));
        summary.cycles += 1;
    }
    if let Some(t) = sink_task {
        t.abort();
    }
    http_task.abort();
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

/// The origin-shift sink's channels to the cycle: outputs in, reseeds back, status out.
struct SinkChannels {
    out_rx: watch::Receiver<Outputs>,
    reseed_tx: mpsc::Sender<(String, f64)>,
    status: watch::Sender<SinkStatus>,
}

/// Writes the engine's outputs every `write_period_ms`. The controller applies each write as a step,
/// so the dosing cap is enforced per WRITE here too (the engine doses per cycle and may run ahead).
async fn origin_shift_task(
    os: OriginShiftSink,
    mut client: OriginShiftClient,
    caps_um: BTreeMap<String, f64>,
    initial: BTreeMap<String, f64>,
    channels: SinkChannels,
    epoch: std::time::Instant,
) {
    let SinkChannels {
        out_rx,
        reseed_tx,
        status,
    } = channels;
    let mut tick = tokio::time::interval(Duration::from_millis(os.write_period_ms));
    tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
    let mut st = SinkStatus {
        kind: "origin_shift".into(),
        ..Default::default()
    };
    let mut last_written: BTreeMap<String, f64> = initial;
    let mut was_connected = client.is_connected();
    // The controller link as a fault: logged once when it is lost and once when it is back.
    let mut link = LinkFault::default();
    loop {
        tick.tick().await;
        let mut outs = out_rx.borrow().clone();
        if outs.is_empty() {
            continue;
        }
        for (axis, v) in &mut outs {
            if let (Some(last), Some(cap)) =
                (last_written.get(axis.as_str()), caps_um.get(axis.as_str()))
            {
                *v = last + (*v - last).clamp(-cap, *cap);
            }
        }
        if !was_connected {
            // Reconnected: see whether the controller still holds what we wrote.
            if let Ok(held) = client.read_current().await {
                for (axis, v) in held {
                    let ours = last_written.get(&axis).copied();
                    let lsb = client.map().axis(&axis).map_or(0.1, |r| r.lsb_um);
                    if ours.is_some_and(|o| (o - v).abs() > lsb) {
                        let _ = reseed_tx.send((axis.clone(), v)).await;
                        last_written.insert(axis, v);
                    }
                }
                // Let the engine apply the reseed before writing again.
                was_connected = true;
                st.connected = true;
                link.update(true, epoch.elapsed().as_secs_f64());
                let _ = status.send(st.clone());
                continue;
            }
        }
        let pairs: Vec<(&str, f64)> = outs.iter().map(|(a, v)| (a.as_str(), *v)).collect();
        match client.write(&pairs).await {
            Ok(Outcome::Ok) => {
                st.writes_ok += 1;
                st.last_error = None;
                for (a, v) in &outs {
                    last_written.insert(a.clone(), *v);
                }
            }
            Ok(other) => {
                // Past the value write (strobe/ack/read-back failed) the controller may hold the new
                // values: dose the next write from them.
                if !matches!(other, Outcome::RequestFailed { step: "write", .. }) {
                    for (a, v) in &outs {
                        last_written.insert(a.clone(), *v);
                    }
                }
                st.writes_failed += 1;
                st.last_error = Some(format!("{other:?}"));
            }
            Err(e) => {
                st.writes_failed += 1;
                st.last_error = Some(e.to_string());
            }
        }
        st.connected = client.is_connected();
        was_connected = st.connected;
        link.update(st.connected, epoch.elapsed().as_secs_f64());
        let _ = status.send(st.clone());
    }
}

/// The origin-shift sink's link to the controller, as a fault in a [`FaultLog`] (source
/// `sink.origin_shift`, kind `Disconnected`): one log line when it is lost, one when it is back, however
/// many writes fail in between. Sans-IO: the caller passes the link state after each attempt.
#[derive(Default)]
pub struct LinkFault {
    log: FaultLog,
}

impl LinkFault {
    pub const SOURCE: &'static str = "sink.origin_shift";

    /// Returns true when this call started or cleared the fault.
    pub fn update(&mut self, connected: bool, now_s: f64) -> bool {
        let faults: &[FaultKind] = if connected {
            &[]
        } else {
            &[FaultKind::Disconnected]
        };
        !self.log.update(Self::SOURCE, faults, now_s).is_empty()
    }

    pub fn is_down(&self) -> bool {
        self.log.active().next().is_some()
    }
}

/// Refuse to run a config that would correct nothing in a field deployment.
pub fn require_sink(cfg: &FieldConfig) -> anyhow::Result<()> {
    if cfg.sink.origin_shift.is_none() && cfg.sink.quadrature.is_none() {
        bail!(
            "no [sink.origin_shift] or [sink.quadrature] in the config: nothing would be corrected"
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

    #[test]
    fn link_loss_is_one_fault_however_many_writes_fail() {
        let mut link = LinkFault::default();
        let mut edges = 0;
        // Up for 10 writes, down for 50 (every write fails), up again.
        for k in 0..100 {
            if link.update(!(10..60).contains(&k), k as f64 * 0.01) {
                edges += 1;
            }
            assert_eq!(link.is_down(), (10..60).contains(&k), "write {k}");
        }
        assert_eq!(edges, 2, "one start, one clear");
    }
}
