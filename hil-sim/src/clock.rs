//! The simulation clock: as fast as possible (tests, batch recordings) or paced to the wall clock
//! (demos, live buses). The world itself never reads a clock; this shell decides when to step it.
//! [`LagMeter`] says how far a paced run fell behind the wall clock.

use std::time::{Duration, Instant};

/// Paces steps of `dt_s` against the wall clock, in batches so timer jitter does not accumulate.
#[derive(Debug)]
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
        let due =
            retrocomp_analysis::numeric::trunc_u64(self.start.elapsed().as_secs_f64() / self.dt_s);
        due.saturating_sub(done_steps)
    }

    /// Wall time since the pacer started, s.
    pub fn elapsed_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// Wall time until the next step is due.
    pub fn until_next(&self, done_steps: u64) -> Duration {
        let next = Duration::from_secs_f64((done_steps + 1) as f64 * self.dt_s);
        next.saturating_sub(self.start.elapsed())
    }
}

/// How far the simulated machine runs behind the wall clock when paced in real time (a real
/// machine never stalls; a starved simulator does, and everything it publishes comes late by this
/// much). Sans-IO: fed the wall time since the pacer's start and the simulated time after each
/// batch of steps. A lag beyond [`LagMeter::BEHIND_S`] is one "behind real time" episode, reported
/// once at its start and once at its clear.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LagMeter {
    /// Lag at the last observation, s (wall − simulated, ≥ 0).
    pub lag_s: f64,
    pub max_lag_s: f64,
    /// Episodes of running more than [`LagMeter::BEHIND_S`] behind, and their total wall time, s.
    pub episodes: u64,
    pub behind_s: f64,
    behind_since_s: Option<f64>,
}

/// An edge of a "behind real time" episode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LagEdge {
    Started { lag_s: f64 },
    Cleared { lasted_s: f64, max_lag_s: f64 },
}

impl LagMeter {
    /// Lag that counts as running behind: 50 ms, ten encoder periods of the demo.
    pub const BEHIND_S: f64 = 0.05;

    /// Observe the lag after a batch; returns an edge when an episode starts or clears.
    pub fn observe(&mut self, wall_s: f64, sim_s: f64) -> Option<LagEdge> {
        let lag = (wall_s - sim_s).max(0.0);
        self.lag_s = lag;
        self.max_lag_s = self.max_lag_s.max(lag);
        match (self.behind_since_s, lag > Self::BEHIND_S) {
            (None, true) => {
                self.behind_since_s = Some(wall_s);
                self.episodes += 1;
                Some(LagEdge::Started { lag_s: lag })
            }
            (Some(t0), false) => {
                self.behind_since_s = None;
                self.behind_s += wall_s - t0;
                Some(LagEdge::Cleared {
                    lasted_s: wall_s - t0,
                    max_lag_s: self.max_lag_s,
                })
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lag_episode_is_reported_once_at_start_and_once_at_clear() {
        let mut m = LagMeter::default();
        assert_eq!(m.observe(1.0, 0.999), None);
        let started = m.observe(2.0, 1.75);
        assert_eq!(started, Some(LagEdge::Started { lag_s: 0.25 }));
        assert_eq!(m.observe(2.5, 2.0), None);
        let cleared = m.observe(3.0, 3.0).unwrap();
        assert!(
            matches!(cleared, LagEdge::Cleared { lasted_s, max_lag_s }
                if (lasted_s - 1.0).abs() < 1e-9 && (max_lag_s - 0.5).abs() < 1e-9),
            "{cleared:?}"
        );
        assert_eq!((m.episodes, m.lag_s), (1, 0.0));
        assert!((m.behind_s - 1.0).abs() < 1e-9);
    }
}
