//! Motion programs of the concealed-effect cases, sampled at a fixed period: ISO 230-2-style
//! bidirectional step-and-dwell laser runs (irregular targets, overshoot past the end targets so each
//! end is approached from its own side), slow continuous scans, X–Y diagonals, cutting passes (force
//! only in cut) and a single forward sweep (the confounded case). Positions in mm, time in s.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Sampled commanded path. `cut` marks samples in cut (force applied); `run` the block id.
#[derive(Clone, Debug, Default)]
pub(crate) struct Path {
    pub dt_s: f64,
    pub x_mm: Vec<f64>,
    pub y_mm: Vec<f64>,
    pub cut: Vec<bool>,
    pub run: Vec<i64>,
    pub tool_mm: Vec<f64>,
}

impl Path {
    pub(crate) fn new(dt_s: f64) -> Self {
        Path {
            dt_s,
            ..Default::default()
        }
    }
    pub(crate) fn len(&self) -> usize {
        self.x_mm.len()
    }
    fn last(&self) -> (f64, f64) {
        (
            self.x_mm.last().copied().unwrap_or(0.0),
            self.y_mm.last().copied().unwrap_or(0.0),
        )
    }
    fn push(&mut self, x: f64, y: f64, cut: bool, run: i64, tool: f64) {
        self.x_mm.push(x);
        self.y_mm.push(y);
        self.cut.push(cut);
        self.run.push(run);
        self.tool_mm.push(tool);
    }

    /// Linear move at `feed` mm/s to (x, y), one sample per period (the last sample lands on target).
    pub(crate) fn move_to(&mut self, x: f64, y: f64, feed: f64, cut: bool, run: i64, tool: f64) {
        let (x0, y0) = self.last();
        let d = (x - x0).hypot(y - y0);
        let steps = retrocomp_analysis::numeric::ceil_usize(d / feed / self.dt_s).max(1);
        for k in 1..=steps {
            let f = k as f64 / steps as f64;
            self.push(x0 + f * (x - x0), y0 + f * (y - y0), cut, run, tool);
        }
    }

    pub(crate) fn dwell(&mut self, seconds: f64, run: i64, tool: f64) {
        let (x, y) = self.last();
        for _ in 0..retrocomp_analysis::numeric::round_usize(seconds / self.dt_s).max(1) {
            self.push(x, y, false, run, tool);
        }
    }

    /// ISO 230-2-style bidirectional run on X (or Y when `on_y`) over [lo, hi] with irregular target
    /// spacing (so periodic errors are not aliased onto the targets) and `overshoot` past both ends.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn laser_run(
        &mut self,
        rng: &mut ChaCha8Rng,
        lo: f64,
        hi: f64,
        n_targets: usize,
        on_y: bool,
        feed: f64,
        dwell_s: f64,
        run: i64,
        tool: f64,
    ) {
        let step = (hi - lo) / (n_targets - 1) as f64;
        let targets: Vec<f64> = (0..n_targets)
            .map(|i| {
                let jitter = if i == 0 || i + 1 == n_targets {
                    0.0
                } else {
                    rng.random_range(-0.3..0.3) * step
                };
                lo + i as f64 * step + jitter
            })
            .collect();
        let (x0, y0) = self.last();
        let go = |p: &mut Path, v: f64| {
            if on_y {
                p.move_to(x0, v, feed, false, run, tool);
            } else {
                p.move_to(v, y0, feed, false, run, tool);
            }
        };
        go(self, lo - 2.0);
        for &t in &targets {
            go(self, t);
            self.dwell(dwell_s, run, tool);
        }
        go(self, hi + 2.0);
        for &t in targets.iter().rev() {
            go(self, t);
            self.dwell(dwell_s, run, tool);
        }
        go(self, lo - 2.0);
    }
}

/// Draw helper.
pub(crate) fn uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    rng.random_range(lo..hi)
}
