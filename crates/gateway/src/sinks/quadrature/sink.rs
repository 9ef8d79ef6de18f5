//! The quadrature sink: per axis, the cycle's correction (µm, = −error) becomes whole counts
//! ([`CountQuantizer`]: sign, resolution, carried residual) and goes to that axis's injector thread
//! ([`super::lines`]) — on GPIO lines (`gpio` configured, cargo feature `gpio`) or on simulated
//! pins (no lines configured: the same thread and timing, nothing leaves the process). With
//! `[sink.quadrature.trace]` every level those threads write is traced ([`super::trace`]); a lost
//! trace entry or a failed trace write is a `sink.quadrature.trace` `WriteFailed` fault.
//!
//! Restart (pulses have no read-back): the counts the controller holds are persisted per axis in
//! `state_file` ([`super::held`]), written ahead of every step's edges. [`Sink::start`] reads them:
//! the quantizer continues from them, the lines start at their phase (no edge at takeover) and the
//! engine is seeded with the correction they realise. No file = first start (all 0, one INFO line);
//! a corrupt or unreadable file refuses the start (nothing is injected until it is fixed); a failed
//! write-ahead is a fault of the sink and that step injects nothing.
//!
//! Every count passes the box's one last-step guard first ([`super::core`]): within the clamp, one
//! cap per step from what the controller may hold; held counts beyond the clamp are a
//! `sink.quadrature.<axis>` `BeyondClamp` fault (nothing injected on that axis, status shows the
//! held value). Stop (`[gateway] on_stop = "ramp_out"`): counts back to 0 within the cap per step,
//! every [`RAMP_PERIOD_MS`], for at most `stop_ramp_max_s`; the outcome is logged.
//!
//! A field file that names GPIO lines on a build without the `gpio` feature is refused when it
//! loads, at the line of the first `gpio` (the config's check of the build's parts), rather than
//! silently simulated: the technician would otherwise see a healthy status while nothing reaches
//! the controller.

use std::collections::BTreeMap;
use tokio::sync::watch;

use super::config::QuadratureSink;
use super::core::QuadratureCore;
use super::held::{FileHeldCounts, HeldCounts, HeldError};
use super::lines::Lines;
use crate::sinks::guard::AxisLimits;
use crate::sinks::origin_shift::sink_task::{SinkSources, update_sink_faults};
use crate::sinks::quadrature::CountQuantizer;
use crate::sinks::{LocalFuture, Sink, SinkError, SinkIo, SinkStatus, StartValues};
use retrocomp_bus::fault::{FaultKind, FaultLog, FaultSource};
use retrocomp_model::error::Chain;

/// Period of the stop ramp-out's steps (no cycle runs then), ms.
pub(crate) const RAMP_PERIOD_MS: u64 = 10;

/// The sink's fault source (`<SOURCE>.<axis>` per axis).
pub(crate) const SOURCE: &str = "sink.quadrature";

/// The edge trace's fault source: entries lost (buffer full) or the file could not be written.
pub(crate) const TRACE_SOURCE: &str = "sink.quadrature.trace";

/// Read the persisted counts: per configured axis the held count (0 when none is persisted) and
/// the start values (µm the controller holds) the engine continues from.
pub(crate) fn held_at_start(
    q: &QuadratureSink,
    store: &mut dyn HeldCounts,
) -> Result<(BTreeMap<String, i64>, StartValues), HeldError> {
    let persisted = store.load()?;
    if persisted.is_none() {
        tracing::info!(
            "sink.quadrature: no held-counts file, first start: the controller holds 0 counts \
             (delete the file after homing or power-cycling the controller)"
        );
    }
    let persisted = persisted.unwrap_or_default();
    let mut held = BTreeMap::new();
    let mut start = StartValues::new();
    for a in &q.axes {
        let n = persisted.get(&a.axis).copied().unwrap_or(0);
        let quant = CountQuantizer::continuing_from(a.resolution_um, a.count_sign, n)?;
        held.insert(a.axis.clone(), n);
        start.insert(a.axis.clone(), quant.correction_um_of(n));
    }
    Ok((held, start))
}

/// The quadrature injector as the run loop's [`Sink`]: [`Sink::start`] reads the persisted held
/// counts ([`held_at_start`]); [`Sink::run`] is [`quadrature_task`].
#[derive(Debug)]
pub(crate) struct QuadratureOutput {
    cfg: QuadratureSink,
    limits: Vec<AxisLimits>,
    held: BTreeMap<String, i64>,
    epoch: std::time::Instant,
}

impl QuadratureOutput {
    /// `limits`: clamp and per-write cap per axis; `epoch`: the gateway's clock (fault times).
    pub(crate) fn new(
        cfg: QuadratureSink,
        limits: Vec<AxisLimits>,
        epoch: std::time::Instant,
    ) -> Self {
        Self {
            cfg,
            limits,
            held: BTreeMap::new(),
            epoch,
        }
    }

    fn store(&self) -> FileHeldCounts {
        FileHeldCounts::new(self.cfg.state_path(std::path::Path::new(".")))
    }
}

impl Sink for QuadratureOutput {
    fn start<'a>(&'a mut self, _io: &'a SinkIo) -> LocalFuture<'a, Result<StartValues, SinkError>> {
        Box::pin(async move {
            let (held, _) = held_at_start(&self.cfg, &mut self.store()).map_err(|e| {
                SinkError::setup(
                    "sink.quadrature state_file (nothing is injected until it is fixed)",
                    e,
                )
            })?;
            let core = QuadratureCore::new(&self.cfg, &self.limits, &held)
                .map_err(|e| SinkError::setup("sink.quadrature", e))?;
            let start = core.start_values();
            if start.len() < core.len() {
                tracing::error!(
                    ?held,
                    "sink.quadrature: the held counts realise a correction beyond the clamp: that axis is not injected until the file is fixed"
                );
            }
            self.held = held;
            Ok(start)
        })
    }

    fn run(self: Box<Self>, io: SinkIo) -> LocalFuture<'static, ()> {
        let mut store = self.store();
        // `load` fills the store's map, so a save rewrites every axis, not only the changed one.
        if let Err(e) = store.load() {
            tracing::error!("{}", Chain(&e));
        }
        Box::pin(quadrature_task(
            QuadratureSetup {
                cfg: self.cfg,
                limits: self.limits,
                held: self.held,
                store: Box::new(store),
                epoch: self.epoch,
            },
            io,
        ))
    }
}

/// What [`quadrature_task`] starts from.
pub(crate) struct QuadratureSetup {
    pub cfg: QuadratureSink,
    /// Clamp and per-write cap per axis.
    pub limits: Vec<AxisLimits>,
    /// Counts the controller holds per axis.
    pub held: BTreeMap<String, i64>,
    pub store: Box<dyn HeldCounts>,
    /// The gateway's clock (fault times are seconds since it).
    pub epoch: std::time::Instant,
}

impl std::fmt::Debug for QuadratureSetup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QuadratureSetup")
            .field("cfg", &self.cfg)
            .field("limits", &self.limits)
            .field("held", &self.held)
            .finish_non_exhaustive()
    }
}

/// Follow the cycle's outputs until the runtime drops its sender, or ramp out on `io.stop`.
pub(crate) async fn quadrature_task(setup: QuadratureSetup, io: SinkIo) {
    let QuadratureSetup {
        cfg: q,
        limits,
        held,
        mut store,
        epoch,
    } = setup;
    let SinkIo {
        mut out_rx,
        status,
        mut stop,
        ..
    } = io;
    let mut core = match QuadratureCore::new(&q, &limits, &held) {
        Ok(c) => c,
        Err(e) => return refuse(&status, &e),
    };
    let mut lines = match Lines::open(&q, &held) {
        Ok(l) => l,
        Err(e) => return refuse(&status, &e),
    };
    let mut st = SinkStatus {
        kind: lines.kind().into(),
        connected: true,
        ..Default::default()
    };
    let sources = SinkSources::named(SOURCE, core.axis_names());
    let trace_source = FaultSource::named(TRACE_SOURCE);
    let mut faults = FaultLog::default();
    let mut stop_by: Option<std::time::Instant> = None;
    let mut ramp = tokio::time::interval(std::time::Duration::from_millis(RAMP_PERIOD_MS));
    loop {
        if let Some(by) = stop_by {
            ramp.tick().await;
            if core.is_ramped_out() {
                tracing::info!("ramped out: the controller holds 0 counts on every axis");
                return;
            }
            if std::time::Instant::now() >= by {
                let held: Vec<(&str, i64)> = core
                    .axis_names()
                    .zip((0..core.len()).map(|i| core.held_counts(i)))
                    .collect();
                tracing::warn!(
                    ?held,
                    "stopping before the counts are ramped out: the controller keeps these"
                );
                return;
            }
        } else {
            let closed = tokio::select! {
                r = out_rx.changed() => r.is_err(),
                r = stop.wait_for(Option::is_some) => if r.is_err() { return } else { false },
            };
            // The run is ending: ramp out if asked to, else end here.
            if closed && stop.wait_for(Option::is_some).await.is_err() {
                return;
            }
            if let Some(max_s) = *stop.borrow() {
                stop_by =
                    Some(std::time::Instant::now() + std::time::Duration::from_secs_f64(max_s));
                core.begin_ramp_out();
                tracing::info!(
                    max_s,
                    "stopping: ramping the counts out within the per-write cap"
                );
            }
        }
        let outs = out_rx.borrow().clone();
        step_axes(&mut core, &mut lines, &outs, store.as_mut(), &mut st);
        let now_s = epoch.elapsed().as_secs_f64();
        let mut events =
            update_sink_faults(&mut faults, &sources, core.faults(), st.connected, now_s);
        let trace_lost = lines.trace_lost();
        let trace_kinds: &[FaultKind] = match trace_lost {
            Some((dropped, failed)) if dropped > 0 || failed => &[FaultKind::WriteFailed],
            _ => &[],
        };
        events.extend(faults.update(&trace_source, trace_kinds, now_s));
        for e in events.iter().filter(|e| e.started) {
            tracing::warn!(source = e.source.as_str(), kind = e.kind.as_str(), held_um = ?st.held_um, ?trace_lost, "quadrature sink fault");
        }
        if !events.is_empty() {
            st.faults = faults.active_by_name();
        }
        let _ = status.send(st.clone());
    }
}

/// Where a step's counts go: the injector threads' lines ([`Lines`]), or lines stepped in virtual
/// time (`gateway_core::quadrature`). Axis `i` is the core's axis order.
pub(crate) trait CountLines {
    /// Hand `delta` counts to axis `i`; false if that axis can take no more (its injector is gone).
    fn inject(&mut self, i: usize, delta: i64) -> bool;
    /// Counts axis `i` was given but has not yet put on its lines.
    fn owed(&self, i: usize) -> i64;
}

impl CountLines for Lines {
    fn inject(&mut self, i: usize, delta: i64) -> bool {
        Lines::inject(self, i, delta)
    }
    fn owed(&self, i: usize) -> i64 {
        Lines::owed(self, i)
    }
}

/// One update of every axis: the wanted correction through the guard to the lines (while the
/// core ramps out, 0 for every axis, also one without an output), then the status and the axes' held values. Every
/// driver of the quadrature sink steps through here (the runtime's task and the harness).
pub(crate) fn step_axes(
    core: &mut QuadratureCore,
    lines: &mut dyn CountLines,
    outs: &[(retrocomp_model::Axis, f64)],
    store: &mut dyn HeldCounts,
    st: &mut SinkStatus,
) {
    for i in 0..core.len() {
        let Some(axis) = core.axis(i) else { continue };
        let want = match outs.iter().find(|(a, _)| *a == axis) {
            Some((_, v)) => *v,
            None if core.is_ramping_out() => 0.0,
            None => continue,
        };
        // The last step's edges are all on the lines: the controller holds exactly the emitted
        // count. Said before this step, or the guard would still allow for the count before it
        // and move this axis only every other step.
        if lines.owed(i) == 0 {
            core.settled(i);
        }
        match core.step(i, want, store) {
            Ok(d) if lines.inject(i, d) => st.writes_ok += 1,
            Ok(_) => {
                st.writes_failed += 1;
                st.connected = false;
                st.last_error = Some(format!("axis {axis}: injector stopped"));
            }
            Err(e) => {
                st.writes_failed += 1;
                st.last_error = Some(format!("axis {axis}: {}", Chain(&e)));
            }
        }
        if lines.owed(i) == 0 {
            core.settled(i);
        } else {
            tracing::debug!(
                axis = axis.name(),
                owed = lines.owed(i),
                "counts still owed to the lines"
            );
        }
    }
    for (i, name) in core.axis_names().enumerate() {
        match st.held_um.get_mut(name) {
            Some(v) => *v = core.held_um(i),
            None => {
                st.held_um.insert(name.to_string(), core.held_um(i));
            }
        }
    }
}

/// The task cannot drive its axes: say why in the status.
fn refuse(status: &watch::Sender<SinkStatus>, e: &(dyn std::error::Error + 'static)) {
    tracing::error!("sink.quadrature: {}", Chain(e));
    let _ = status.send(SinkStatus {
        kind: "quadrature".into(),
        last_error: Some(Chain(e).to_string()),
        ..Default::default()
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines like the injector threads': counts handed over are owed until the thread has put
    /// them out, which happens between two steps ([`Threads::between_steps`]).
    struct Threads {
        out: i64,
        owed: i64,
    }
    impl Threads {
        fn between_steps(&mut self) {
            self.out += std::mem::take(&mut self.owed);
        }
    }
    impl CountLines for Threads {
        fn inject(&mut self, _: usize, delta: i64) -> bool {
            self.owed += delta;
            true
        }
        fn owed(&self, _: usize) -> i64 {
            self.owed
        }
    }

    #[test]
    fn the_counts_follow_the_output_one_cap_every_step_once_the_lines_put_them_out() {
        use crate::sinks::quadrature::core::tests::{Mem, cfg, limits};
        let mut core = QuadratureCore::new(&cfg(), &limits(), &BTreeMap::new()).unwrap();
        let mut lines = Threads { out: 0, owed: 0 };
        let mut store = Mem(BTreeMap::new());
        let mut st = SinkStatus::default();
        // The engine ramps 0 → 5 µm at the cap (1 µm = 2 counts of 0.5 µm per step).
        for k in 1..=5 {
            let outs = [(retrocomp_model::Axis::X, f64::from(k))];
            step_axes(&mut core, &mut lines, &outs, &mut store, &mut st);
            lines.between_steps();
            assert_eq!(
                lines.out,
                -2 * i64::from(k),
                "step {k}: the counts lag the output"
            );
        }
        assert_eq!(st.held_um["x"], 5.0);
    }

    /// A trace that cannot be written (`/dev/full`: every write is ENOSPC) is the
    /// `sink.quadrature.trace` fault in the sink's status, while the counts still go out.
    #[cfg(target_os = "linux")]
    #[tokio::test(flavor = "current_thread")]
    async fn a_trace_that_cannot_be_written_is_a_fault_in_the_status() {
        use crate::sinks::quadrature::core::tests::{Mem, cfg, limits};
        use crate::sinks::quadrature::trace::TraceConfig;
        let mut cfg = cfg();
        cfg.trace = Some(TraceConfig {
            path: "/dev/full".into(),
            max_bytes: 1_000_000,
            buffer_edges: 1024,
        });
        let limits = limits();
        let (out_tx, out_rx) = watch::channel(Vec::new());
        let (status_tx, mut status_rx) = watch::channel(SinkStatus::default());
        let (stop_tx, stop_rx) = watch::channel(None);
        let (reseed_tx, _reseed_rx) = tokio::sync::mpsc::channel(1);
        let (served, _served_rx) = tokio::sync::mpsc::channel(1);
        let setup = QuadratureSetup {
            cfg,
            limits,
            held: BTreeMap::new(),
            store: Box::new(Mem(BTreeMap::new())),
            epoch: std::time::Instant::now(),
        };
        let io = SinkIo {
            out_rx,
            reseed_tx,
            status: status_tx,
            stop: stop_rx,
            served,
        };
        let local = tokio::task::LocalSet::new();
        let task = local.spawn_local(quadrature_task(setup, io));
        let faulted = async {
            loop {
                // One step per output; the writer fails on its first flush of the start row.
                out_tx.send_modify(|o| {
                    *o = vec![(retrocomp_model::Axis::X, 1.0)];
                });
                tokio::time::sleep(std::time::Duration::from_millis(5)).await;
                let st = status_rx.borrow_and_update().clone();
                if st
                    .faults
                    .iter()
                    .any(|(s, k, _)| s == TRACE_SOURCE && *k == FaultKind::WriteFailed)
                {
                    return st;
                }
            }
        };
        let st = local
            .run_until(tokio::time::timeout(
                std::time::Duration::from_secs(30),
                faulted,
            ))
            .await
            .expect("no sink.quadrature.trace fault within 30 s");
        assert_eq!(st.held_um["x"], 1.0, "the counts still go out: {st:?}");
        // The run ends without a ramp-out: the task returns, its lines joined and the trace closed.
        drop((out_tx, stop_tx));
        local.run_until(task).await.unwrap();
    }
}
