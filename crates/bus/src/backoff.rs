//! The one reconnect backoff of the workspace: every source (CAN backends, Modbus pollers, serial
//! lines), every sink (origin-shift client), the MQTT telemetry publisher and recording shipper,
//! and the status endpoint's accept loop retry a lost link (or a failed accept) by this type.
//!
//! Sans-IO: it never sleeps and never reads a clock. After each failed attempt the shell asks
//! [`Backoff::next_delay`] (or [`Backoff::retry_at`] with its own `now`) how long to wait; after a
//! success it calls [`Backoff::reset`]. Delays start at `min`, double after every failure and stop
//! at `max`, so a peer that is down for hours is tried every `max` and one that blinks is back
//! within `min`. Units: [`Duration`]; `from_secs_f64` takes seconds from config files.

use std::ops::Add;
use std::time::Duration;

/// Exponential backoff: `min`, `2·min`, `4·min`, … capped at `max`; [`Backoff::reset`] after a success.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Backoff {
    min: Duration,
    max: Duration,
    next: Duration,
}

impl Backoff {
    /// `max` below `min` is raised to `min`. A zero `min` retries at once the first time, then
    /// doubles from one millisecond (a zero delay must never become a busy loop).
    pub fn new(min: Duration, max: Duration) -> Self {
        let max = max.max(min);
        Backoff {
            min,
            max,
            next: min,
        }
    }

    /// From seconds as written in config files; negative or non-finite values become 0 (min) or
    /// `min` (max), so a bad value can never panic here (the config validation names it).
    pub fn from_secs_f64(min_s: f64, max_s: f64) -> Self {
        let d = |s: f64| {
            if s.is_finite() && s > 0.0 {
                Duration::from_secs_f64(s.min(86_400.0))
            } else {
                Duration::ZERO
            }
        };
        Self::new(d(min_s), d(max_s))
    }

    /// From milliseconds (the sink config's unit).
    pub fn from_millis(min_ms: u64, max_ms: u64) -> Self {
        Self::new(Duration::from_millis(min_ms), Duration::from_millis(max_ms))
    }

    /// The wait before the next attempt after a failure; the one after it is twice as long (≤ max).
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        let doubled = self.next.max(Duration::from_millis(1)).saturating_mul(2);
        self.next = doubled.min(self.max).max(self.min);
        d
    }

    /// When to try again after a failure at `now` (any clock: std or tokio `Instant`, seconds…).
    pub fn retry_at<T: Add<Duration, Output = T>>(&mut self, now: T) -> T {
        now + self.next_delay()
    }

    /// The link works again: the next failure waits `min` again.
    pub fn reset(&mut self) {
        self.next = self.min;
    }

    /// The delay the next failure will get (without consuming it).
    pub fn peek(&self) -> Duration {
        self.next
    }

    pub fn min(&self) -> Duration {
        self.min
    }

    pub fn max(&self) -> Duration {
        self.max
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn doubles_caps_and_resets() {
        let mut b = Backoff::new(ms(100), ms(500));
        let d: Vec<Duration> = (0..5).map(|_| b.next_delay()).collect();
        assert_eq!(d, [ms(100), ms(200), ms(400), ms(500), ms(500)]);
        b.reset();
        assert_eq!(b.next_delay(), ms(100));
    }

    #[test]
    fn retry_at_adds_the_delay_to_the_callers_clock() {
        let mut b = Backoff::from_secs_f64(0.25, 1.0);
        let t0 = std::time::Instant::now();
        assert_eq!(b.retry_at(t0), t0 + ms(250));
        assert_eq!(b.retry_at(t0), t0 + ms(500));
        assert_eq!(b.retry_at(t0), t0 + ms(1000));
        assert_eq!(b.retry_at(t0), t0 + ms(1000));
    }

    #[test]
    fn zero_min_never_stays_a_busy_loop_and_bad_inputs_do_not_panic() {
        let mut b = Backoff::new(Duration::ZERO, ms(8));
        let d: Vec<Duration> = (0..6).map(|_| b.next_delay()).collect();
        assert_eq!(d, [ms(0), ms(2), ms(4), ms(8), ms(8), ms(8)]);
        let mut b = Backoff::from_secs_f64(f64::NAN, -1.0);
        assert_eq!(b.next_delay(), Duration::ZERO);
        let mut b = Backoff::from_secs_f64(2.0, 1.0);
        assert_eq!((b.next_delay(), b.next_delay()), (ms(2000), ms(2000)));
        let mut b = Backoff::new(Duration::MAX, Duration::MAX);
        assert_eq!(
            (b.next_delay(), b.next_delay()),
            (Duration::MAX, Duration::MAX)
        );
    }
}
