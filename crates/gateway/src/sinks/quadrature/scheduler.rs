//! Pure edge scheduler: merges the native encoder edges with injected correction edges into one A/B
//! stream for the controller.
//!
//! Guarantees (property-tested in `tests/gateway/quadrature.rs`):
//! - the output count is exactly native + injected (every output edge is one Gray-code step);
//! - no two output edges are closer than `min_edge_gap_ns` (the receiver's minimum edge separation,
//!   e.g. 400 ns for RS-422 at 400 kHz: Heidenhain "a ≥ 0.4 µs");
//! - injected edges are never closer than `1 / max_inject_rate_hz` to each other.
//!
//! Native edges have priority: a native edge is emitted on arrival unless the previous output edge is
//! less than one gap ago, in which case it is delayed to the end of that gap (latency < one gap while
//! the native edges respect the gap themselves). An edge is only injected when no native edge is
//! waiting. If native edges arrive faster than the gap (encoder beyond spec) they queue and are counted
//! in [`EdgeScheduler::native_backlog`]; none is ever dropped.

use std::collections::VecDeque;

use super::gray::{Step, levels_of_phase};

/// Native edges the backlog holds without allocating (the injector thread must not allocate; an
/// in-spec encoder never queues more than one or two).
pub(crate) const NATIVE_BACKLOG_PREALLOC: usize = 1024;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SchedulerConfig {
    /// Minimum separation between any two output edges, ns.
    pub min_edge_gap_ns: u64,
    /// Maximum rate of injected edges, counts per second.
    pub max_inject_rate_hz: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SchedulerConfigError {
    #[error("min_edge_gap_ns must be > 0")]
    ZeroGap,
    #[error("max_inject_rate_hz must be finite and > 0, got {0}")]
    BadRate(f64),
}

impl SchedulerConfig {
    /// Interval between injected edges, ns (never below the edge gap).
    pub fn inject_interval_ns(&self) -> u64 {
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "the config refuses a rate ≤ 0 or non-finite: 1e9/rate is a positive ns count, saturating beyond u64"
        )]
        let interval = (1e9 / self.max_inject_rate_hz).ceil() as u64;
        interval.max(self.min_edge_gap_ns)
    }

    pub fn validate(&self) -> Result<(), SchedulerConfigError> {
        if self.min_edge_gap_ns == 0 {
            return Err(SchedulerConfigError::ZeroGap);
        }
        if !(self.max_inject_rate_hz.is_finite() && self.max_inject_rate_hz > 0.0) {
            return Err(SchedulerConfigError::BadRate(self.max_inject_rate_hz));
        }
        Ok(())
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    Native,
    Injected,
}

/// One output edge: at `t_ns` the lines take levels (`a`, `b`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transition {
    pub t_ns: u64,
    pub step: Step,
    pub source: Source,
    pub a: bool,
    pub b: bool,
}

#[derive(Clone, Debug)]
pub struct EdgeScheduler {
    cfg: SchedulerConfig,
    inject_interval_ns: u64,
    /// Output position in counts (its phase mod 4 gives the line levels).
    position: i64,
    last_out_ns: Option<u64>,
    last_inject_ns: Option<u64>,
    pending_native: VecDeque<Step>,
    injected_total: i64,
    inject_target: i64,
    native_total: i64,
}

impl EdgeScheduler {
    pub fn new(cfg: SchedulerConfig) -> Result<Self, SchedulerConfigError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            inject_interval_ns: cfg.inject_interval_ns(),
            position: 0,
            last_out_ns: None,
            last_inject_ns: None,
            pending_native: VecDeque::with_capacity(NATIVE_BACKLOG_PREALLOC),
            injected_total: 0,
            inject_target: 0,
            native_total: 0,
        })
    }

    /// Start at output position `held_counts` (what the controller's receiver holds from an earlier
    /// box, `super::held`): the lines then start at its phase's levels, so taking them over shows
    /// the receiver no edge. Injection totals still count from this box's start.
    pub fn starting_at(mut self, held_counts: i64) -> Self {
        self.position = held_counts;
        self
    }

    pub fn config(&self) -> SchedulerConfig {
        self.cfg
    }

    /// Set the total number of counts that should have been injected (absolute, signed).
    pub fn set_inject_target(&mut self, total_counts: i64) {
        self.inject_target = total_counts;
    }

    /// Add to the injection target (a delta from [`super::CountQuantizer::delta_counts`]).
    pub fn add_inject_counts(&mut self, delta: i64) {
        self.inject_target += delta;
    }

    /// A native edge arrived (decoded from the scale's A/B lines). Call [`Self::poll`] afterwards.
    pub fn native_edge(&mut self, step: Step) {
        self.native_total += step.sign();
        self.pending_native.push_back(step);
    }

    /// Native edges waiting for the gap to expire.
    pub fn native_backlog(&self) -> usize {
        self.pending_native.len()
    }

    /// Counts injected so far, and still to inject.
    pub fn injected_total(&self) -> i64 {
        self.injected_total
    }
    pub fn inject_remaining(&self) -> i64 {
        self.inject_target - self.injected_total
    }

    /// Output position in counts (native + injected emitted so far).
    pub fn position(&self) -> i64 {
        self.position
    }

    /// Levels the output lines hold now.
    pub fn levels(&self) -> (bool, bool) {
        levels_of_phase(self.position)
    }

    fn gap_free_at(&self) -> u64 {
        self.last_out_ns.map_or(0, |t| t + self.cfg.min_edge_gap_ns)
    }

    /// Earliest time at which [`Self::poll`] would emit an edge, if any edge is owed.
    pub fn next_due_ns(&self) -> Option<u64> {
        if !self.pending_native.is_empty() {
            return Some(self.gap_free_at());
        }
        if self.inject_remaining() != 0 {
            let rate_free = self
                .last_inject_ns
                .map_or(0, |t| t + self.inject_interval_ns);
            return Some(self.gap_free_at().max(rate_free));
        }
        None
    }

    /// Emit at most one edge at `now_ns` (times must be non-decreasing across calls).
    pub fn poll(&mut self, now_ns: u64) -> Option<Transition> {
        let due = self.next_due_ns()?;
        if now_ns < due {
            return None;
        }
        let (step, source) = match self.pending_native.pop_front() {
            Some(step) => (step, Source::Native),
            None => {
                let step = Step::of_sign(self.inject_remaining())?;
                self.injected_total += step.sign();
                self.last_inject_ns = Some(now_ns);
                (step, Source::Injected)
            }
        };
        self.position += step.sign();
        self.last_out_ns = Some(now_ns);
        let (a, b) = levels_of_phase(self.position);
        Some(Transition {
            t_ns: now_ns,
            step,
            source,
            a,
            b,
        })
    }
}

/// Input event for [`simulate`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// A native edge arrives.
    Native(Step),
    /// The injection target (total counts) changes.
    Target(i64),
}

/// Discrete-event run of the scheduler over time-ordered input events, until every owed edge has been
/// emitted. Used by the property test, the benchmark and the demo.
pub fn simulate(sched: &mut EdgeScheduler, events: &[(u64, Event)]) -> Vec<Transition> {
    let mut out = Vec::with_capacity(events.len() * 2);
    let mut i = 0;
    loop {
        let next_in = events.get(i).map(|e| e.0);
        let next_due = sched.next_due_ns();
        match (next_in, next_due) {
            (None, None) => break,
            (Some(t_in), due) if due.is_none_or(|d| t_in <= d) => {
                // Apply every input at this instant before emitting at it.
                while let Some(&(t, ev)) = events.get(i) {
                    if t != t_in {
                        break;
                    }
                    match ev {
                        Event::Native(s) => sched.native_edge(s),
                        Event::Target(n) => sched.set_inject_target(n),
                    }
                    i += 1;
                }
                if let Some(tr) = sched.poll(t_in) {
                    out.push(tr);
                }
            }
            (_, Some(d)) => {
                if let Some(tr) = sched.poll(d) {
                    out.push(tr);
                }
            }
            (Some(_), None) => unreachable!("guard above takes every input when nothing is due"),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sched(gap: u64, rate: f64) -> EdgeScheduler {
        EdgeScheduler::new(SchedulerConfig {
            min_edge_gap_ns: gap,
            max_inject_rate_hz: rate,
        })
        .unwrap()
    }

    #[test]
    fn injection_respects_rate() {
        // 100 kHz injection → one edge per 10 µs.
        let mut s = sched(400, 100e3);
        let out = simulate(&mut s, &[(0, Event::Target(-5))]);
        assert_eq!(out.len(), 5);
        assert!(out.windows(2).all(|w| w[1].t_ns - w[0].t_ns >= 10_000));
        assert_eq!(s.position(), -5);
    }

    #[test]
    fn native_edge_inside_gap_is_delayed_not_dropped() {
        let mut s = sched(400, 1e6);
        let out = simulate(
            &mut s,
            &[(0, Event::Target(1)), (100, Event::Native(Step::Up))],
        );
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].source, Source::Injected);
        assert_eq!(out[1].source, Source::Native);
        assert_eq!(out[1].t_ns, 400, "delayed to the end of the gap");
        assert_eq!(s.position(), 2);
    }

    #[test]
    fn rejects_bad_config() {
        assert!(
            EdgeScheduler::new(SchedulerConfig {
                min_edge_gap_ns: 0,
                max_inject_rate_hz: 1.0
            })
            .is_err()
        );
        assert!(
            EdgeScheduler::new(SchedulerConfig {
                min_edge_gap_ns: 1,
                max_inject_rate_hz: f64::NAN
            })
            .is_err()
        );
    }
}
