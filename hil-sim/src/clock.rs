//! The simulation clock: as fast as possible (tests, batch recordings) or paced to the wall clock
//! (demos, live buses). The world itself never reads a clock; this shell decides when to step it.

use std::time::{Duration, Instant};

/// Paces steps of `dt_s` against the wall clock, in batches so timer jitter does not accumulate.
pub struct RealtimePacer {
    start: Instant,
    dt_s: f64,
}

impl RealtimePacer {
    pub fn new(dt_s: f64) -> Self {
        Self {
            start: Instant::now(),
            dt_s,
        }
    }

    /// How many steps are due now given `done_steps` already taken (0 means: wait).
    pub fn steps_due(&self, done_steps: u64) -> u64 {
        let due = (self.start.elapsed().as_secs_f64() / self.dt_s).floor() as u64;
        due.saturating_sub(done_steps)
    }

    /// Wall time until the next step is due.
    pub fn until_next(&self, done_steps: u64) -> Duration {
        let next = Duration::from_secs_f64((done_steps + 1) as f64 * self.dt_s);
        next.saturating_sub(self.start.elapsed())
    }
}
