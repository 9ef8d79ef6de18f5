//! The cycle loop, on its own OS thread (see [`retrocomp_bus::realtime`]): once per `cycle_ms` slot it
//! drains the samples, reseeds and actions that arrived into the [`CycleCore`] (the sans-IO cycle
//! the closed-loop harness drives too), runs it, hands the outputs to the sink and,
//! at most [`STATUS_PERIOD_S`] apart, publishes a status snapshot. The loop body ([`CycleLoop::step`])
//! allocates nothing on a cycle that does not publish (tests/gateway/no_alloc.rs counts it).
//!
//! Timing ([`crate::pacer`]): cycles are due every `period` on the gateway clock (`epoch`) and run
//! at once when a source delivers samples, never two closer than a period; a cycle that ran late
//! (host pause) is not repeated to catch up — the next one is the next due time after now — and is
//! counted in [`CycleReport`] (`late_cycles`, `max_late_ms`): the engine judges staleness from the
//! samples' own times, so one late cycle does not by itself make any channel stale.
//!
//! Compensation dropped: whenever compensation is enabled but an axis is not tracking its target
//! (inputs stale → holding or ramping out, model fault), the engine reports the fault
//! `compensation.<axis>` (logged at start and clear, in status and metrics); this loop also sums the
//! time, so a run's summary says how long compensation was off ([`CompensationTime::not_compensating_s`] in [`CycleReport`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, watch};

use crate::engine::{Engine, ErrorModel};
use crate::gateway_core::{CompensationTime, Control, CycleCore};
use crate::pacer::{CycleWake, Pacer};
use crate::sources::health::SourceBoard;
use crate::status::{SinkStatus, StatusSnapshot};
use crate::supervise::CycleCounter;
use retrocomp_bus::Sample;
use retrocomp_model::Axis;

/// Status snapshots are published at most this often (10 Hz), s: building one allocates (names,
/// term maps), so never every cycle.
pub const STATUS_PERIOD_S: f64 = 0.1;

/// How many recent cycles the compute-time percentiles cover.
pub const COMPUTE_WINDOW: usize = 1 << 16;

/// Per-axis outputs handed to the sink: (axis, correction µm).
pub type Outputs = Vec<(Axis, f64)>;

/// The channels between the cycle and the rest of the runtime.
#[derive(Debug)]
pub struct CycleIo {
    /// Samples from the bus sources.
    pub samples: mpsc::Receiver<Sample>,
    /// Positions the controller writes into a served register image (origin-shift server).
    pub served: mpsc::Receiver<Sample>,
    /// The sink found another value in the controller: continue from it.
    pub reseed: mpsc::Receiver<(Axis, f64)>,
    /// Token-guarded actions from the status endpoint.
    pub control: mpsc::Receiver<Control>,
    pub outputs: watch::Sender<Outputs>,
    pub status: watch::Sender<Option<Arc<StatusSnapshot>>>,
    pub sink_status: watch::Receiver<SinkStatus>,
    pub board: SourceBoard,
    pub counter: CycleCounter,
    /// Raised by the sources when samples arrive: the cycle may run at once ([`Pacer`]).
    pub wake: CycleWake,
    /// The Sparkplug B publisher's state for the snapshots (`[telemetry.mqtt]`), if configured.
    pub telemetry: Option<crate::northbound::telemetry::annotate::TelemetryAnnotator>,
}

/// What the loop reports when it stops.
#[derive(Clone, Debug, Default)]
pub struct CycleReport {
    /// Engine compute time per cycle, µs (p50, p99) over the last [`COMPUTE_WINDOW`] cycles.
    pub compute_us_p50: f64,
    pub compute_us_p99: f64,
    /// Cycles that started more than one period after they were due, and the worst lateness.
    pub late_cycles: u64,
    pub max_late_ms: f64,
    /// Cycles run and the time without (full) compensation, as the [`CycleCore`] summed them.
    pub time: CompensationTime,
}

#[derive(Debug)]
pub struct CycleLoop {
    /// What a cycle does (sans-IO, shared with the closed-loop harness).
    core: CycleCore,
    io: CycleIo,
    compute_ns: Vec<u64>,
    /// The ring slot the next compute time goes to once the ring is full.
    compute_next: usize,
    last_publish_s: Option<f64>,
    report: CycleReport,
    /// Compute-time histogram and late cycles, copied into every snapshot (`/metrics`).
    timing: crate::status::CycleTiming,
}

impl CycleLoop {
    pub fn new(engine: Engine, model: Box<dyn ErrorModel + Send>, io: CycleIo) -> Self {
        Self {
            core: CycleCore::new(engine, model),
            io,
            // The ring of compute times is allocated once: a gateway runs for months.
            compute_ns: Vec::with_capacity(COMPUTE_WINDOW),
            compute_next: 0,
            last_publish_s: None,
            report: CycleReport::default(),
            timing: Default::default(),
        }
    }

    /// One cycle at `now_s` (gateway clock): what arrived since the last one goes into the
    /// [`CycleCore`] (samples, served positions, reseeds, actions, in that order), the core runs,
    /// the outputs go to the sink. Returns true when it published a status snapshot (the only part
    /// that allocates).
    pub fn step(&mut self, now_s: f64) -> bool {
        let core = &mut self.core;
        while let Ok(s) = self.io.samples.try_recv() {
            core.handle_sample(&s);
        }
        while let Ok(s) = self.io.served.try_recv() {
            core.handle_sample(&s);
        }
        while let Ok((axis, held)) = self.io.reseed.try_recv() {
            // A refusal is logged by the core; the axis holds.
            let _ = core.handle_reseed(axis, held);
        }
        while let Ok(c) = self.io.control.try_recv() {
            core.handle_control(c);
        }
        let t0 = Instant::now();
        let outs = core.poll_cycle(now_s);
        let took = t0.elapsed();
        // Reuse the channel's buffer (same axes every cycle: no allocation).
        self.io.outputs.send_modify(|held| copy_outputs(held, outs));
        self.timing.observe(took.as_secs_f64());
        let took_ns = u64::try_from(took.as_nanos()).unwrap_or(u64::MAX);
        if self.compute_ns.len() < COMPUTE_WINDOW {
            self.compute_ns.push(took_ns);
        } else {
            self.compute_ns[self.compute_next] = took_ns;
        }
        self.compute_next = (self.compute_next + 1) % COMPUTE_WINDOW;
        let cycles = self.core.compensation_time().cycles;
        self.io.counter.set(cycles);
        let due = self
            .last_publish_s
            .is_none_or(|t| now_s - t >= STATUS_PERIOD_S || now_s < t);
        if due {
            self.publish(now_s);
        }
        due
    }

    /// Build and publish the status snapshot now.
    pub fn publish(&mut self, now_s: f64) {
        let mut snap = self.core.snapshot();
        snap.timing = self.timing;
        if let Some(t) = self.io.telemetry.as_mut() {
            t.annotate(&mut snap);
        }
        add_links(&mut snap, &self.io.sink_status.borrow(), &self.io.board);
        let _ = self.io.status.send(Some(Arc::new(snap)));
        self.last_publish_s = Some(now_s);
    }

    /// Run on the [`Pacer`]'s schedule (every `period` on the gateway clock `epoch`, and at once
    /// when [`CycleIo::wake`] says samples arrived) until `stop` is set; then publish a last
    /// snapshot and report. Between cycles the thread parks: a source's notify or the due time
    /// unparks it.
    pub fn run(mut self, epoch: Instant, period: Duration, stop: &AtomicBool) -> CycleReport {
        let period_s = period.as_secs_f64();
        let mut pacer = Pacer::new(epoch.elapsed().as_secs_f64(), period_s);
        self.io.wake.register_current_thread();
        while !stop.load(Ordering::Acquire) {
            let now_s = epoch.elapsed().as_secs_f64();
            if self.io.wake.take() {
                pacer.handle_arrival(now_s);
            }
            let Some(late_s) = pacer.poll_run(now_s) else {
                let wait_s = pacer.poll_timeout() - now_s;
                std::thread::park_timeout(Duration::from_secs_f64(wait_s.max(0.0)));
                continue;
            };
            if late_s > period_s {
                self.report.late_cycles += 1;
                self.timing.late_cycles += 1;
                self.report.max_late_ms = self.report.max_late_ms.max(late_s * 1e3);
            }
            self.step(now_s);
        }
        self.publish(epoch.elapsed().as_secs_f64());
        self.finish()
    }

    fn finish(mut self) -> CycleReport {
        self.report.time = self.core.compensation_time();
        self.compute_ns.sort_unstable();
        let n = self.compute_ns.len();
        let pct = |p: f64| {
            #[allow(
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss,
                reason = "p in [0, 1] and n ≥ 1 here: the rank is in 0..n (an empty ring gives 0.0 below)"
            )]
            let rank = (n.saturating_sub(1) as f64 * p.clamp(0.0, 1.0)) as usize;
            self.compute_ns.get(rank).map_or(0.0, |ns| *ns as f64 / 1e3)
        };
        self.report.compute_us_p50 = pct(0.5);
        self.report.compute_us_p99 = pct(0.99);
        self.report
    }
}

/// `dst = src` without allocating when the axes are as many as last cycle.
fn copy_outputs(dst: &mut Outputs, src: &[(Axis, f64)]) {
    dst.clear();
    dst.extend_from_slice(src);
}

/// The sink's status and every source's link into `snap`, their faults added to its active ones:
/// the cycle's snapshots and the runtime's start-up ones (before the first cycle) alike.
pub(crate) fn add_links(snap: &mut StatusSnapshot, sink: &SinkStatus, board: &SourceBoard) {
    snap.active_faults.extend(sink.faults.iter().cloned());
    match &mut snap.sink {
        Some(s) => s.clone_from(sink),
        None => snap.sink = Some(sink.clone()),
    }
    board.copy_into(&mut snap.sources);
    for src in &snap.sources {
        let faults = src.faults.iter().map(|&(k, t)| (src.name.clone(), k, t));
        snap.active_faults.extend(faults);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_are_copied_in_place_and_follow_a_changed_axis_set() {
        let mut held: Outputs = vec![(Axis::X, 1.0), (Axis::Z, 2.0)];
        let buffer_at = held.as_ptr();
        copy_outputs(&mut held, &[(Axis::X, -3.5), (Axis::Z, 4.0)]);
        assert_eq!(held, [(Axis::X, -3.5), (Axis::Z, 4.0)]);
        assert_eq!(held.as_ptr(), buffer_at, "the buffer was reused");
        copy_outputs(&mut held, &[(Axis::Y, 0.25)]);
        assert_eq!(held, [(Axis::Y, 0.25)]);
    }
}
