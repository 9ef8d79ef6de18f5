//! The quadrature sink in virtual time: the sink's own [`QuadratureCore`] (last-step guard,
//! quantizer, write-ahead of the held counts) stepped through the sink's own [`step_axes`], with
//! lines that are one [`EdgeScheduler`] per axis polled at the driver's time instead of injector
//! threads. Faults are the sink's own mapping ([`update_sink_faults`]). What differs from the
//! runtime's task is only where the edges go and when they are due.
//!
//! Edges owed are never emitted before the cycle that asked for them. The held counts live in a
//! [`MemoryHeld`] store the driver keeps across gateway restarts (the state file of the real
//! shell).
//!
//! Sign (`sinks/quadrature/mod.rs`): injecting +n counts makes the controller believe the slide
//! moved +n, so its servo moves the slide −n counts; a correction `c_um` injects
//! `−c_um / resolution_um` counts (× `count_sign`). Time: ns on the lines, s for fault times.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;

use retrocomp_bus::fault::{FaultEvent, FaultLog};
use retrocomp_model::Axis;

use crate::config::QuadratureSink;
use crate::sinks::guard::AxisLimits;
use crate::sinks::origin_shift::sink_task::{SinkSources, update_sink_faults};
use crate::sinks::quadrature::core::QuadratureCore;
use crate::sinks::quadrature::held::{HeldCounts, HeldError};
use crate::sinks::quadrature::sink::{CountLines, SOURCE, held_at_start, step_axes};
use crate::sinks::quadrature::{EdgeScheduler, SchedulerConfig, Transition};
use crate::sinks::{SinkError, SinkStatus, StartValues};

/// The held-counts store in memory: a driver keeps one across gateway restarts (the file of the
/// real shell); clones share it.
#[derive(Clone, Debug, Default)]
pub struct MemoryHeld {
    counts: Rc<RefCell<Option<BTreeMap<String, i64>>>>,
}

impl MemoryHeld {
    /// What is persisted for `axis` (None: nothing yet).
    pub fn get(&self, axis: &str) -> Option<i64> {
        self.counts.borrow().as_ref()?.get(axis).copied()
    }
}

impl HeldCounts for MemoryHeld {
    fn load(&mut self) -> Result<Option<BTreeMap<String, i64>>, HeldError> {
        Ok(self.counts.borrow().clone())
    }

    fn save(&mut self, axis: &str, count: i64) -> Result<(), HeldError> {
        self.counts
            .borrow_mut()
            .get_or_insert_default()
            .insert(axis.to_string(), count);
        Ok(())
    }
}

#[derive(Debug)]
struct VirtualAxis {
    axis: Option<Axis>,
    sched: EdgeScheduler,
    /// Edges owed now are not emitted before this instant (the cycle that asked for them), ns.
    not_before_ns: u64,
}

/// One edge scheduler per axis, polled at the driver's time.
#[derive(Debug)]
struct VirtualLines {
    axes: Vec<VirtualAxis>,
    now_ns: u64,
}

impl CountLines for VirtualLines {
    fn inject(&mut self, i: usize, delta: i64) -> bool {
        let a = &mut self.axes[i];
        if delta != 0 {
            a.sched.add_inject_counts(delta);
            a.not_before_ns = a.not_before_ns.max(self.now_ns);
        }
        true
    }

    fn owed(&self, i: usize) -> i64 {
        self.axes[i].sched.inject_remaining()
    }
}

/// The quadrature box of a [`super::GatewayCore`]: core, virtual lines, store, status and faults.
#[derive(Debug)]
pub struct QuadratureBox {
    core: QuadratureCore,
    lines: VirtualLines,
    store: MemoryHeld,
    status: SinkStatus,
    sources: SinkSources,
    faults: FaultLog,
}

impl QuadratureBox {
    /// Start as the sink does: read the held counts from `store` and continue from them (an axis
    /// whose counts realise a value beyond the clamp injects nothing and is a `BeyondClamp`
    /// fault). Returns the box and the start values (µm the controller holds) for the engine.
    pub fn new(
        cfg: &QuadratureSink,
        limits: &[AxisLimits],
        store: MemoryHeld,
    ) -> Result<(Self, StartValues), SinkError> {
        let mut store = store;
        let (held, _) = held_at_start(cfg, &mut store)
            .map_err(|e| SinkError::setup("sink.quadrature held counts", e))?;
        let core = QuadratureCore::new(cfg, limits, &held)
            .map_err(|e| SinkError::setup("sink.quadrature", e))?;
        let mut axes = Vec::with_capacity(cfg.axes.len());
        for a in &cfg.axes {
            if a.gpio.is_some() {
                return Err(SinkError::Refused(format!(
                    "sink.quadrature axis {}: virtual time drives simulated lines only",
                    a.axis
                )));
            }
            let sched = EdgeScheduler::new(SchedulerConfig {
                min_edge_gap_ns: a.min_edge_gap_ns,
                max_inject_rate_hz: a.max_inject_rate_hz,
            })
            .map_err(|e| SinkError::setup(format!("sink.quadrature axis {}", a.axis), e))?
            .starting_at(held.get(&a.axis).copied().unwrap_or(0));
            axes.push(VirtualAxis {
                axis: Axis::from_name(&a.axis),
                sched,
                not_before_ns: 0,
            });
        }
        let start = core.start_values();
        let sources = SinkSources::named(SOURCE, core.axis_names());
        let status = SinkStatus {
            kind: "quadrature (virtual)".into(),
            connected: true,
            ..Default::default()
        };
        let lines = VirtualLines { axes, now_ns: 0 };
        let b = Self {
            core,
            lines,
            store,
            status,
            sources,
            faults: FaultLog::default(),
        };
        Ok((b, start))
    }

    /// The engine's outputs of a cycle at `now_ns` (µm; `now_s` the same instant on the gateway
    /// clock): one step of every axis through the sink's guard. Returns the fault episodes that
    /// started or cleared.
    pub fn handle_outputs(
        &mut self,
        outs: &[(Axis, f64)],
        now_ns: u64,
        now_s: f64,
    ) -> Vec<FaultEvent> {
        self.lines.now_ns = now_ns;
        step_axes(
            &mut self.core,
            &mut self.lines,
            outs,
            &mut self.store,
            &mut self.status,
        );
        let connected = self.status.connected;
        let f = self.core.faults();
        let events = update_sink_faults(&mut self.faults, &self.sources, f, connected, now_s);
        if !events.is_empty() {
            self.status.faults = self.faults.active_by_name();
        }
        events
    }

    /// Stop as the sink does on SIGTERM with `on_stop = "ramp_out"`: from the next step on, every
    /// axis wants 0 whatever the outputs, at most one cap per step; an axis beyond the clamp is
    /// not ramped (it keeps its count and its fault).
    pub fn begin_ramp_out(&mut self) {
        self.core.begin_ramp_out();
    }

    /// Ramping out, every axis at 0 counts and every edge on the lines.
    pub fn is_ramped_out(&self) -> bool {
        self.core.is_ramped_out()
    }

    /// Every edge due at or before `now_ns`, in time order per axis. (As with the injector
    /// threads, the guard learns that an axis's edges are all out at the sink's next step.)
    pub fn poll_edges(&mut self, now_ns: u64) -> Vec<(Axis, Transition)> {
        let mut out = Vec::new();
        for a in &mut self.lines.axes {
            let Some(axis) = a.axis else { continue };
            while let Some(due) = a.sched.next_due_ns() {
                let at = due.max(a.not_before_ns);
                if at > now_ns {
                    break;
                }
                if let Some(tr) = a.sched.poll(at) {
                    out.push((axis, tr));
                }
            }
        }
        out
    }

    /// The levels (A, B) the box holds on `axis`'s lines.
    pub fn levels(&self, axis: Axis) -> Option<(bool, bool)> {
        self.axis(axis).map(|a| a.sched.levels())
    }

    /// Counts the box has put on `axis`'s lines so far, and still owes.
    pub fn counts(&self, axis: Axis) -> Option<(i64, i64)> {
        self.axis(axis)
            .map(|a| (a.sched.injected_total(), a.sched.inject_remaining()))
    }

    fn axis(&self, axis: Axis) -> Option<&VirtualAxis> {
        self.lines.axes.iter().find(|a| a.axis == Some(axis))
    }
}
