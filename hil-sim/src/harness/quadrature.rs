//! The quadrature sink's box in the closed-loop harness: per axis the real [`CountQuantizer`]
//! (correction µm → whole counts, residual carried) and [`EdgeScheduler`] (A/B edges under the
//! receiver's gap and the injection rate), as `retrocomp_gateway::sinks::quadrature::sink::quadrature_task` runs
//! them, stepped in the harness' virtual time (ns). The controller's side (its ×4 receiver counting
//! the edges into the servo's feedback) is in `super` ([`crate::harness::ClosedLoop`]).
//!
//! Like the real shell, the box hands the counts of every changed engine output to the scheduler at
//! once; edges are emitted when due (never before the cycle that asked for them). As the shell, it
//! persists what the controller holds ahead of every step (`retrocomp_gateway::sinks::quadrature::held`), here in
//! memory ([`MemoryHeld`], kept by the harness across restarts): a restarted box continues from
//! the held counts, takes the lines at their phase and seeds the engine with what they realise.
//!
//! Sign (crates/gateway/src/sinks/quadrature/mod.rs): injecting +n counts makes the controller believe the slide moved
//! +n, so its servo moves the slide −n counts; a correction `c_um` injects `−c_um / resolution_um`
//! counts (× `count_sign`).

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::rc::Rc;

use retrocomp_gateway::config::QuadratureSink;
use retrocomp_gateway::sinks::StartValues;
use retrocomp_gateway::sinks::quadrature::held::{HeldCounts, HeldError, write_ahead};
use retrocomp_gateway::sinks::quadrature::sink::held_at_start;
use retrocomp_gateway::sinks::quadrature::{
    CountQuantizer, EdgeScheduler, SchedulerConfig, Transition,
};
use retrocomp_model::Axis;

/// The held-counts store in memory: the harness keeps one across gateway restarts (the file of the
/// real shell); clones share it. Every save is logged so tests can check it came before the edges.
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
struct BoxAxis {
    axis: Axis,
    quant: CountQuantizer,
    sched: EdgeScheduler,
    /// Edges owed now are not emitted before this instant (the cycle that asked for them), ns.
    not_before_ns: u64,
}

/// The in-process quadrature box: one quantizer and one edge scheduler per configured axis.
#[derive(Debug)]
pub struct QuadratureBox {
    axes: Vec<BoxAxis>,
    store: MemoryHeld,
}

impl QuadratureBox {
    /// Start as the shell does: read the held counts from `store`, continue from them; returns the
    /// box and the start values (µm the controller holds) the engine continues from.
    pub fn new(cfg: &QuadratureSink, store: MemoryHeld) -> anyhow::Result<(Self, StartValues)> {
        let mut store = store;
        let (held, start) = held_at_start(cfg, &mut store)?;
        let axes = cfg
            .axes
            .iter()
            .map(|a| {
                let axis = Axis::from_name(&a.axis)
                    .ok_or_else(|| anyhow::anyhow!("sink.quadrature: axis {}", a.axis))?;
                anyhow::ensure!(a.gpio.is_none(), "the harness drives simulated lines only");
                let n = held[&a.axis];
                Ok(BoxAxis {
                    axis,
                    quant: CountQuantizer::continuing_from(a.resolution_um, a.count_sign, n)?,
                    sched: EdgeScheduler::new(SchedulerConfig {
                        min_edge_gap_ns: a.min_edge_gap_ns,
                        max_inject_rate_hz: a.max_inject_rate_hz,
                    })?
                    .starting_at(n),
                    not_before_ns: 0,
                })
            })
            .collect::<anyhow::Result<_>>()?;
        Ok((Self { axes, store }, start))
    }

    /// The engine's outputs of a cycle at `now_ns` (µm): each axis's count delta goes to its
    /// scheduler, as the shell does on every changed output. Returns the deltas (axis, counts).
    pub fn on_outputs(&mut self, outs: &[(Axis, f64)], now_ns: u64) -> Vec<(Axis, i64)> {
        let mut deltas = Vec::new();
        for a in &mut self.axes {
            let Some((_, v)) = outs.iter().find(|(x, _)| *x == a.axis) else {
                continue;
            };
            // The safety layer hands out finite values only and the memory store cannot fail: an
            // error here is a harness bug.
            let d = write_ahead(&mut self.store, a.axis.name(), &mut a.quant, *v)
                .expect("finite correction, infallible store");
            if d != 0 {
                a.sched.add_inject_counts(d);
                a.not_before_ns = a.not_before_ns.max(now_ns);
            }
            deltas.push((a.axis, d));
        }
        deltas
    }

    /// Every edge due at or before `now_ns`, in time order per axis.
    pub fn edges_until(&mut self, now_ns: u64) -> Vec<(Axis, Transition)> {
        let mut out = Vec::new();
        for a in &mut self.axes {
            while let Some(due) = a.sched.next_due_ns() {
                let at = due.max(a.not_before_ns);
                if at > now_ns {
                    break;
                }
                if let Some(tr) = a.sched.poll(at) {
                    out.push((a.axis, tr));
                }
            }
        }
        out
    }

    /// The levels (A, B) the box holds on `axis`'s lines.
    pub fn levels(&self, axis: Axis) -> Option<(bool, bool)> {
        self.axes
            .iter()
            .find(|a| a.axis == axis)
            .map(|a| a.sched.levels())
    }

    /// Counts the box has put on `axis`'s lines so far, and still owes.
    pub fn counts(&self, axis: Axis) -> Option<(i64, i64)> {
        self.axes
            .iter()
            .find(|a| a.axis == axis)
            .map(|a| (a.sched.injected_total(), a.sched.inject_remaining()))
    }
}
