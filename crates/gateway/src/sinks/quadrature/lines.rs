//! The sink's output lines: per axis one injector thread ([`super::injector`]) on GPIO lines
//! (`gpio = …`, cargo feature `gpio`) or on [`SimulatedPin`]s (no lines configured: the same thread
//! and timing, nothing leaves the process), the simulated scale of a simulated axis
//! ([`super::native`]) and the edge trace ([`super::trace`]) they all record into.
//!
//! Dropping [`Lines`] stops the simulated scales, closes the injectors' feeds and waits until every
//! owed edge is on the lines (what was persisted ahead is what the controller gets), then until the
//! trace has written what it was given.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Instant;

use embedded_hal::digital::OutputPin;

use super::config::{QuadratureAxis, QuadratureSink};
use super::driver::SimulatedPin;
use super::injector::{Feed, Injector, InjectorCounts, run_injector_traced};
use super::native::spawn_scale;
use super::scheduler::{EdgeScheduler, SchedulerConfig};
use super::trace::{EdgeTrace, TraceWriter};
use crate::sinks::SinkError;

/// One axis's injector thread and the simulated scale feeding it, if any.
struct AxisLines {
    feed: Option<Sender<Feed>>,
    counts: Arc<Mutex<InjectorCounts>>,
    injector: Option<JoinHandle<()>>,
    scale: Option<(JoinHandle<()>, Arc<AtomicBool>)>,
    kind: &'static str,
}

/// Every configured axis's lines (config order) and the trace.
pub(crate) struct Lines {
    axes: Vec<AxisLines>,
    trace: Option<TraceWriter>,
}

impl std::fmt::Debug for Lines {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lines")
            .field("axes", &self.axes.len())
            .field("trace", &self.trace)
            .finish()
    }
}

impl Lines {
    /// Open every axis at its `held` counts (the lines start at that phase's levels: no edge).
    pub(crate) fn open(
        q: &QuadratureSink,
        held: &BTreeMap<String, i64>,
    ) -> Result<Self, SinkError> {
        let trace = match &q.trace {
            Some(t) => Some(
                TraceWriter::start(t, q.axes.iter().map(|a| a.axis.clone()).collect()).map_err(
                    |e| SinkError::setup(format!("sink.quadrature.trace {}", t.path.display()), e),
                )?,
            ),
            None => None,
        };
        // One clock for every axis, so the trace's rows of different axes compare.
        let start = Instant::now();
        let mut lines = Lines {
            axes: Vec::with_capacity(q.axes.len()),
            trace,
        };
        for (i, a) in q.axes.iter().enumerate() {
            let tr = lines.trace.as_ref().and_then(|t| t.for_axis(i));
            let n = held.get(&a.axis).copied().unwrap_or(0);
            lines.axes.push(open_axis(a, n, start, tr)?);
        }
        Ok(lines)
    }

    /// Hand `delta` counts to axis `i`; false if its injector is gone.
    pub(crate) fn inject(&mut self, i: usize, delta: i64) -> bool {
        self.axes[i]
            .feed
            .as_ref()
            .is_some_and(|f| f.send(Feed::Inject(delta)).is_ok())
    }

    /// Counts axis `i` was given but has not yet written to its lines.
    pub(crate) fn owed(&self, i: usize) -> i64 {
        self.axes[i].counts.lock().map(|c| c.owed).unwrap_or(0)
    }

    /// `"quadrature (gpio)"` or `"quadrature (simulated)"` (the first axis's).
    pub(crate) fn kind(&self) -> &'static str {
        self.axes.first().map_or("quadrature", |a| a.kind)
    }

    /// Trace entries lost so far, and whether the trace stopped on a write error.
    pub(crate) fn trace_lost(&self) -> Option<(u64, bool)> {
        self.trace.as_ref().map(|t| (t.dropped(), t.failed()))
    }
}

impl Drop for Lines {
    fn drop(&mut self) {
        for a in &mut self.axes {
            if let Some((join, stop)) = a.scale.take() {
                stop.store(true, Ordering::Relaxed);
                let _ = join.join();
            }
            a.feed = None;
        }
        for a in &mut self.axes {
            if let Some(join) = a.injector.take() {
                let _ = join.join();
            }
        }
        if let Some(t) = self.trace.as_mut() {
            t.finish();
        }
    }
}

fn open_axis(
    a: &QuadratureAxis,
    held: i64,
    start: Instant,
    trace: Option<EdgeTrace>,
) -> Result<AxisLines, SinkError> {
    let sched = EdgeScheduler::new(SchedulerConfig {
        min_edge_gap_ns: a.min_edge_gap_ns,
        max_inject_rate_hz: a.max_inject_rate_hz,
    })
    .map_err(|e| SinkError::setup(format!("sink.quadrature axis {}", a.axis), e))?
    .starting_at(held);
    let (mut lines, feed) = match &a.gpio {
        None => {
            let (pa, pb) = (SimulatedPin::default(), SimulatedPin::default());
            spawn_injector(a, sched, pa, pb, start, trace, "quadrature (simulated)")?
        }
        #[cfg(all(feature = "gpio", target_os = "linux"))]
        Some(gpio) => {
            let (pa, pb) = super::gpio::open_output_pins(gpio, sched.levels())
                .map_err(|e| SinkError::setup(format!("sink.quadrature axis {}", a.axis), e))?;
            spawn_injector(a, sched, pa, pb, start, trace, "quadrature (gpio)")?
        }
        #[cfg(not(all(feature = "gpio", target_os = "linux")))]
        Some(_) => {
            return Err(SinkError::Refused(format!(
                "sink.quadrature axis {}: this build has no GPIO support (feature `gpio`)",
                a.axis
            )));
        }
    };
    if let Some(sim) = &a.simulated_native {
        let stop = Arc::new(AtomicBool::new(false));
        let join = spawn_scale(sim.clone(), feed, stop.clone(), &a.axis)
            .map_err(|e| SinkError::setup("spawning the simulated scale's thread", e))?;
        lines.scale = Some((join, stop));
    }
    Ok(lines)
}

/// Start axis `a`'s injector thread on pins `pa`, `pb`; also returns a sender of its feed.
fn spawn_injector<A, B, E>(
    a: &QuadratureAxis,
    sched: EdgeScheduler,
    pa: A,
    pb: B,
    start: Instant,
    trace: Option<EdgeTrace>,
    kind: &'static str,
) -> Result<(AxisLines, Sender<Feed>), SinkError>
where
    A: OutputPin<Error = E> + Send + 'static,
    B: OutputPin<Error = E> + Send + 'static,
    E: core::fmt::Debug,
{
    let inj = Injector::new(sched, pa, pb)
        .map_err(|e| SinkError::Refused(format!("axis {}: {e}", a.axis)))?;
    let (tx, rx) = std::sync::mpsc::channel();
    let counts = Arc::new(Mutex::new(InjectorCounts::default()));
    let shared = counts.clone();
    let axis = a.axis.clone();
    let join = std::thread::Builder::new()
        .name(format!("quadrature-{axis}"))
        .spawn(move || {
            let report = |c| *shared.lock().unwrap_or_else(|p| p.into_inner()) = c;
            if let Err(e) = run_injector_traced(inj, rx, report, start, trace) {
                tracing::error!(axis, ?e, "quadrature injector stopped");
            }
        })
        .map_err(|e| SinkError::setup("spawning the injector thread", e))?;
    let lines = AxisLines {
        feed: Some(tx.clone()),
        counts,
        injector: Some(join),
        scale: None,
        kind,
    };
    Ok((lines, tx))
}
