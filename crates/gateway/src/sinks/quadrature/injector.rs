//! The real-time shell around the edge scheduler: a thread that owns the A/B output pins, takes
//! injection deltas (whole counts) from the gateway's cycle and native edges (the simulated scale,
//! [`super::native`]) through a channel ([`Feed`]), and writes each owed edge when it falls due.
//! With an [`EdgeTrace`] it records every level it put on the lines, right where it wrote them.
//!
//! Generic over `embedded_hal::digital::OutputPin`, so the same loop drives `CdevPin`s (cargo feature
//! `gpio`, see [`super::gpio`]) and the recording pins of the tests. Time is the thread's monotonic
//! clock in ns since the injector started (`_ns`, as everywhere in [`super`]).
//!
//! The scheduler guarantees the minimum edge gap between the instants it is *polled* at; a GPIO
//! write takes time of its own (a cdev ioctl is 1–3 µs), so the shell also waits one gap (one rate
//! interval after an injected edge) after the previous write has *returned* before it polls again.
//! Both limits then hold between the real edges, not only between their planned times. Userspace timing jitters (sleep overshoot, preemption):
//! edges come late, never early, so the gap and rate limits are kept and only throughput suffers.

use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use embedded_hal::digital::OutputPin;

use super::driver::{PinError, QuadraturePins};
use super::gray::Step;
use super::scheduler::{EdgeScheduler, Source, Transition};
use super::trace::{EdgeTrace, TraceSource};

/// Sleep when the next edge is further away than this; spin closer to it (sleep overshoots by
/// ~50–100 µs on a stock kernel).
const SPIN_WINDOW_NS: u64 = 200_000;
/// How long the idle thread waits for a delta before looking again.
const IDLE_WAIT: Duration = Duration::from_millis(50);

/// What the injector thread is fed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feed {
    /// Counts to inject (a delta of the target, signed).
    Inject(i64),
    /// A native edge arrived from the scale.
    Native(Step),
}

/// What the injector has done so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InjectorCounts {
    /// Injected counts written to the pins (signed).
    pub injected: i64,
    /// Counts still owed (requested but not yet written).
    pub owed: i64,
    /// Edges written to the pins.
    pub edges: u64,
}

/// Scheduler + pins: the sans-clock part of the loop, driven by [`run_injector`] or a test clock.
#[derive(Debug)]
pub struct Injector<A, B> {
    sched: EdgeScheduler,
    pins: QuadraturePins<A, B>,
    edges: u64,
}

impl<A, B, E> Injector<A, B>
where
    A: OutputPin<Error = E>,
    B: OutputPin<Error = E>,
    E: core::fmt::Debug,
{
    /// Drives both lines to the scheduler's current levels first, so the receiver sees no edge.
    pub fn new(sched: EdgeScheduler, a: A, b: B) -> Result<Self, PinError<E>> {
        let pins = QuadraturePins::new(a, b, sched.levels())?;
        Ok(Self {
            sched,
            pins,
            edges: 0,
        })
    }

    pub fn add_inject_counts(&mut self, delta: i64) {
        self.sched.add_inject_counts(delta);
    }

    fn feed(&mut self, f: Feed) {
        match f {
            Feed::Inject(d) => self.sched.add_inject_counts(d),
            Feed::Native(step) => self.sched.native_edge(step),
        }
    }

    /// Levels the lines hold now.
    pub fn levels(&self) -> (bool, bool) {
        self.pins.levels()
    }

    /// Earliest time the next edge may be written, if one is owed.
    pub fn next_due_ns(&self) -> Option<u64> {
        self.sched.next_due_ns()
    }

    /// Write the edge due at `now_ns`, if any, and return it (its levels are the lines' now).
    pub fn service(&mut self, now_ns: u64) -> Result<Option<Transition>, PinError<E>> {
        match self.sched.poll(now_ns) {
            Some(tr) => {
                self.pins.apply(&tr)?;
                self.edges += 1;
                Ok(Some(tr))
            }
            None => Ok(None),
        }
    }

    pub fn counts(&self) -> InjectorCounts {
        InjectorCounts {
            injected: self.sched.injected_total(),
            owed: self.sched.inject_remaining(),
            edges: self.edges,
        }
    }

    /// Spacing to keep after a written edge, measured from the end of its write.
    fn spacing_after_ns(&self, source: Source) -> u64 {
        let cfg = self.sched.config();
        match source {
            Source::Native => cfg.min_edge_gap_ns,
            Source::Injected => cfg.inject_interval_ns(),
        }
    }

    /// Give the pins back (tests check what was written).
    pub fn release(self) -> (A, B) {
        self.pins.release()
    }
}

/// Run the injector on the calling thread until the feed closes and every owed edge has been
/// written (so a stop after the gateway's ramp to zero leaves the controller where it should
/// be). `report` is called after every batch of the feed and when the loop ends.
pub fn run_injector<A, B, E>(
    inj: Injector<A, B>,
    feed: Receiver<Feed>,
    report: impl FnMut(InjectorCounts),
) -> Result<Injector<A, B>, PinError<E>>
where
    A: OutputPin<Error = E>,
    B: OutputPin<Error = E>,
    E: core::fmt::Debug,
{
    run_injector_traced(inj, feed, report, Instant::now(), None)
}

/// [`run_injector`] on the clock started at `start` (shared by the sink's axes), recording every
/// level written to the lines into `trace`: first the levels at takeover, then one row per edge
/// with the time it was polled at (just before its pin write).
pub fn run_injector_traced<A, B, E>(
    mut inj: Injector<A, B>,
    deltas: Receiver<Feed>,
    mut report: impl FnMut(InjectorCounts),
    start: Instant,
    trace: Option<EdgeTrace>,
) -> Result<Injector<A, B>, PinError<E>>
where
    A: OutputPin<Error = E>,
    B: OutputPin<Error = E>,
    E: core::fmt::Debug,
{
    // u64 nanoseconds last 584 years.
    let now_ns = || u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
    if let Some(t) = &trace {
        t.record(now_ns(), inj.levels(), TraceSource::Start);
    }
    // No poll before one gap (one rate interval after an injected edge) after the previous write
    // returned (see the module comment).
    let mut not_before_ns = 0u64;
    let mut open = true;
    loop {
        let due = inj.next_due_ns().map(|d| d.max(not_before_ns));
        // Take every delta that is already waiting; block only when nothing is owed.
        let mut got = false;
        loop {
            let msg = if due.is_none() && open && !got {
                deltas.recv_timeout(IDLE_WAIT)
            } else {
                deltas.try_recv().map_err(|e| match e {
                    std::sync::mpsc::TryRecvError::Empty => RecvTimeoutError::Timeout,
                    std::sync::mpsc::TryRecvError::Disconnected => RecvTimeoutError::Disconnected,
                })
            };
            match msg {
                Ok(f) => {
                    inj.feed(f);
                    got = true;
                }
                Err(RecvTimeoutError::Timeout) => break,
                Err(RecvTimeoutError::Disconnected) => {
                    open = false;
                    break;
                }
            }
        }
        if got {
            report(inj.counts());
            continue;
        }
        let Some(due) = due else {
            if open {
                continue;
            }
            report(inj.counts());
            return Ok(inj);
        };
        let now = now_ns();
        if now < due {
            let wait = due - now;
            if wait > SPIN_WINDOW_NS {
                std::thread::sleep(Duration::from_nanos(wait - SPIN_WINDOW_NS / 2));
            } else {
                std::hint::spin_loop();
            }
            continue;
        }
        if let Some(tr) = inj.service(now)? {
            if let Some(t) = &trace {
                t.record(tr.t_ns, (tr.a, tr.b), tr.source.into());
            }
            not_before_ns = now_ns() + inj.spacing_after_ns(tr.source);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sinks::quadrature::{QuadDecoder, SchedulerConfig};
    use std::convert::Infallible;
    use std::sync::{Arc, Mutex};

    /// One line's writes, with the instant each write happened.
    #[derive(Clone, Default)]
    struct Log(Arc<Mutex<Vec<(Instant, char, bool)>>>);

    struct RecPin {
        line: char,
        log: Log,
    }
    impl embedded_hal::digital::ErrorType for RecPin {
        type Error = Infallible;
    }
    impl OutputPin for RecPin {
        fn set_low(&mut self) -> Result<(), Infallible> {
            self.log
                .0
                .lock()
                .unwrap()
                .push((Instant::now(), self.line, false));
            Ok(())
        }
        fn set_high(&mut self) -> Result<(), Infallible> {
            self.log
                .0
                .lock()
                .unwrap()
                .push((Instant::now(), self.line, true));
            Ok(())
        }
    }

    fn injector(gap_ns: u64, rate_hz: f64, log: &Log) -> Injector<RecPin, RecPin> {
        let sched = EdgeScheduler::new(SchedulerConfig {
            min_edge_gap_ns: gap_ns,
            max_inject_rate_hz: rate_hz,
        })
        .unwrap();
        let a = RecPin {
            line: 'A',
            log: log.clone(),
        };
        let b = RecPin {
            line: 'B',
            log: log.clone(),
        };
        Injector::new(sched, a, b).unwrap()
    }

    /// Decode the written levels back into a count, checking every step is one Gray-code step.
    fn decode(log: &Log) -> (i64, Vec<Instant>) {
        let writes = log.0.lock().unwrap().clone();
        let (mut a, mut b) = (false, false);
        // The first two writes are the initial levels (phase 0 = both low).
        assert!(writes.len() >= 2, "the initial levels are written first");
        let mut dec = QuadDecoder::new(a, b);
        let mut edge_times = Vec::new();
        for (t, line, level) in writes.into_iter().skip(2) {
            match line {
                'A' => a = level,
                _ => b = level,
            }
            dec.update(a, b).expect("every write is one Gray-code step");
            edge_times.push(t);
        }
        (dec.count(), edge_times)
    }

    #[test]
    fn writes_exactly_the_requested_counts_then_stops_when_the_channel_closes() {
        let log = Log::default();
        let inj = injector(400, 100_000.0, &log);
        let (tx, rx) = std::sync::mpsc::channel();
        let worker = std::thread::spawn(move || run_injector(inj, rx, |_| {}));
        for d in [5, -2, 7, 0, -13] {
            tx.send(Feed::Inject(d)).unwrap();
            std::thread::sleep(Duration::from_millis(1));
        }
        drop(tx);
        let inj = worker.join().unwrap().unwrap();
        let c = inj.counts();
        assert_eq!((c.injected, c.owed), (-3, 0));
        let (count, _) = decode(&log);
        assert_eq!(
            count, -3,
            "decoder of the pin writes counts native + injected"
        );
        // A delta that arrives while earlier counts are still owed nets against them, so the edge
        // count depends on timing; it is never below the net and never above the sum of |delta|.
        assert!((3..=27).contains(&c.edges), "{} edges", c.edges);
    }

    #[test]
    fn real_edges_never_come_closer_than_the_rate_interval() {
        // 20 kHz → 50 µs between injected edges, measured between the actual pin writes.
        let log = Log::default();
        let inj = injector(400, 20_000.0, &log);
        let (tx, rx) = std::sync::mpsc::channel();
        tx.send(Feed::Inject(40)).unwrap();
        drop(tx);
        let inj = run_injector(inj, rx, |_| {}).unwrap();
        assert_eq!(inj.counts().injected, 40);
        let (count, times) = decode(&log);
        assert_eq!(count, 40);
        let min_gap = times
            .windows(2)
            .map(|w| w[1].duration_since(w[0]))
            .min()
            .unwrap();
        assert!(
            min_gap >= Duration::from_micros(50),
            "closest edges {min_gap:?} apart"
        );
    }
}
