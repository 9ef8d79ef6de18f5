//! When the cycle runs: the gateway clock is cut into slots of `period` (`start + k·period`), and
//! each slot gets one cycle — at once when a source delivers samples in it (so a position frame
//! does not wait for a clock unrelated to its own), else at the slot's end. All times are seconds
//! on the gateway clock, passed in (sans-IO: [`Pacer::handle_arrival`], [`Pacer::poll_timeout`],
//! [`Pacer::poll_run`]); the cycle thread parks until the timeout or until a source unparks it
//! ([`CycleWake`]).
//!
//! Rate: one cycle per slot, so any window of `n` periods holds at most `n + 1` cycles (two can
//! come close together: a slot's fallback at its end, then an arrival just after), and two
//! cycles are never more than two periods apart. The engine's per-cycle rate limit therefore
//! bounds the correction's rate per second as before (within one cycle's step), and what reaches
//! the controller is bounded per write by the sink's guard whatever the cycle did. Samples that
//! arrive in a slot whose cycle already ran wait for the next slot's start (≤ one period, as with
//! a plain periodic cycle). Without arrivals the cycles run on the grid; a late cycle (host pause)
//! is not repeated to catch up.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::thread::Thread;

/// The cycle's schedule (see the module comment).
#[derive(Clone, Debug)]
pub struct Pacer {
    start_s: f64,
    period_s: f64,
    /// The last slot that had its cycle (`-1`: none yet).
    done_slot: i64,
    /// Samples arrived since the last cycle.
    pending: bool,
    due_s: f64,
}

impl Pacer {
    /// Slots start at `start_s`; the first cycle runs at once (`start_s`), so the outputs exist
    /// from the start, then one per slot.
    pub fn new(start_s: f64, period_s: f64) -> Self {
        Self {
            start_s,
            period_s,
            done_slot: -2,
            pending: false,
            due_s: start_s,
        }
    }

    fn slot(&self, t_s: f64) -> i64 {
        #[allow(
            clippy::cast_possible_truncation,
            reason = "slots of ≥ 1 ms since the gateway started: far inside i64 (saturating beyond)"
        )]
        let slot = ((t_s - self.start_s) / self.period_s).floor() as i64;
        slot
    }

    fn slot_start(&self, slot: i64) -> f64 {
        self.start_s + slot as f64 * self.period_s
    }

    /// New samples reached the cycle at `now_s`.
    pub fn handle_arrival(&mut self, now_s: f64) {
        self.pending = true;
        let k = self.slot(now_s);
        self.due_s = if k > self.done_slot {
            now_s.min(self.due_s)
        } else {
            // This slot had its cycle: the next one's start.
            self.slot_start(self.done_slot + 1).min(self.due_s)
        };
    }

    /// When the next cycle is due, s.
    pub fn poll_timeout(&self) -> f64 {
        self.due_s
    }

    /// At `now_s`: `Some(late_s)` if a cycle runs now (the caller runs it; `late_s` is how long
    /// after its due time, s), and schedules the next.
    pub fn poll_run(&mut self, now_s: f64) -> Option<f64> {
        if now_s < self.due_s {
            return None;
        }
        let late_s = now_s - self.due_s;
        let k = self.slot(now_s);
        self.done_slot = if self.done_slot < -1 {
            // The first cycle, at start: it closes the slot before the first.
            k - 1
        } else if self.pending {
            k
        } else {
            // The fallback at a slot's end belongs to the slot that ends (the one before now's,
            // or now's own when a host pause made it late: missed slots are skipped).
            (k - 1).max(self.done_slot + 1)
        };
        self.pending = false;
        // The next slot's fallback: at its end.
        self.due_s = self.slot_start(self.done_slot + 2);
        Some(late_s)
    }
}

/// Sources → cycle thread: "new samples are in the channel". Cheap on the sending side (an atomic
/// and, when the cycle thread is parked, one futex wake); allocation-free on both.
#[derive(Clone, Debug, Default)]
pub struct CycleWake(Arc<WakeInner>);

#[derive(Debug, Default)]
struct WakeInner {
    pending: AtomicBool,
    thread: OnceLock<Thread>,
}

impl CycleWake {
    /// Called once by the cycle thread before it parks on this wake.
    pub fn register_current_thread(&self) {
        let _ = self.0.thread.set(std::thread::current());
    }

    /// New samples were sent: wake the cycle thread.
    pub fn notify(&self) {
        self.0.pending.store(true, Ordering::Release);
        if let Some(t) = self.0.thread.get() {
            t.unpark();
        }
    }

    /// Whether samples arrived since the last call.
    pub fn take(&self) -> bool {
        self.0.pending.swap(false, Ordering::Acquire)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: f64 = 1e-3;

    /// Drive the pacer in virtual time with arrivals at `arrivals` (sorted), stepping to each
    /// event; returns (run times, per-arrival wait until the next run).
    fn drive(arrivals: &[f64], until: f64) -> (Vec<f64>, Vec<f64>) {
        let mut p = Pacer::new(0.0, P);
        let (mut runs, mut waits) = (Vec::new(), Vec::new());
        let mut pending: Vec<f64> = Vec::new();
        let mut k = 0;
        loop {
            let next_arrival = arrivals.get(k).copied().unwrap_or(f64::INFINITY);
            let now = p.poll_timeout().min(next_arrival);
            if now > until {
                break;
            }
            if next_arrival <= p.poll_timeout() {
                p.handle_arrival(now);
                pending.push(now);
                k += 1;
            }
            if p.poll_run(now).is_some() {
                runs.push(now);
                waits.extend(pending.drain(..).map(|a| now - a));
            }
        }
        (runs, waits)
    }

    #[test]
    fn without_arrivals_cycles_run_on_the_grid() {
        let (runs, _) = drive(&[], 10.5 * P);
        assert_eq!(runs.len(), 11);
        for (k, t) in runs.iter().enumerate() {
            assert!((t - k as f64 * P).abs() < 1e-12, "run {k} at {t}");
        }
    }

    #[test]
    fn one_cycle_per_slot_never_two_periods_apart_and_no_arrival_waits_a_period() {
        // Arrivals at awkward rates and phases, a burst, a silence.
        let mut arrivals: Vec<f64> = (0..200).map(|k| 0.3e-3 + f64::from(k) * 0.77e-3).collect();
        arrivals.extend((0..100).map(|k| 0.05e-3 + f64::from(k) * 2.31e-3));
        arrivals.extend((0..50).map(|k| 0.4 + f64::from(k) * 1e-6));
        arrivals.sort_by(f64::total_cmp);
        let (runs, waits) = drive(&arrivals, 0.6);
        for n in [1usize, 2, 5, 50] {
            let window = n as f64 * P;
            for (i, t) in runs.iter().enumerate() {
                let inside = runs[i..].iter().take_while(|u| **u < t + window).count();
                assert!(
                    inside <= n + 1,
                    "{inside} cycles within {n} periods from {t}"
                );
            }
        }
        for w in runs.windows(2) {
            assert!(
                w[1] - w[0] <= 2.0 * P + 1e-12,
                "cycles {} s apart",
                w[1] - w[0]
            );
        }
        let worst = waits.iter().copied().fold(0.0, f64::max);
        assert!(worst <= P + 1e-12, "an arrival waited {worst} s");
    }

    #[test]
    fn a_source_no_faster_than_the_cycle_triggers_its_cycle_at_once() {
        for (rate, phase) in [(1.0, 0.3), (1.5, 0.05), (2.31, 0.9), (7.0, 0.5)] {
            let arrivals: Vec<f64> = (0..300)
                .map(|k| (phase + f64::from(k) * rate) * P)
                .collect();
            let (_, waits) = drive(&arrivals, 300.0 * rate * P);
            assert_eq!(waits.len(), arrivals.len());
            let worst = waits.iter().copied().fold(0.0, f64::max);
            assert!(
                worst < 1e-12,
                "period {rate}·P: an arrival waited {worst} s"
            );
        }
    }

    #[test]
    fn the_wake_is_taken_once() {
        let w = CycleWake::default();
        assert!(!w.take());
        w.notify();
        w.notify();
        assert!(w.take());
        assert!(!w.take());
    }
}
