//! The drift a block will have when it runs, predicted from evaluations at the present.
//!
//! A block is compensated when it is sent, but the control runs it later (the lead estimate,
//! [`super::lead::ExecEstimate`], says when it is estimated to end). The engine cannot be
//! evaluated at a future time (its lag states advance with time, and the next block is asked at
//! an earlier time than this one runs), so the correction's rate of change is measured at the
//! present and extrapolated: the engine is also evaluated, at the same `now`, at one fixed
//! reference point (the first compensated block's end point and approach directions), which makes
//! a time series of the correction with the position held still. Its least-squares slope over the
//! last `window_s` (a line through many samples averages the inputs' quantisation: a 0.1 °C step
//! × 3 µm/K is a 0.3 µm step) is the drift per second, and a block carries
//! `c(its point, now) + slope · min(t_end − now, max_horizon_s)`.
//!
//! Bounds: no extrapolation (the plain present value) until the window holds at least
//! [`MIN_SAMPLES`] samples spanning a quarter of it (a thermal growth is fastest at its start,
//! so the prediction should start early; a shorter span lets the inputs' quantisation through),
//! and none while an input is degraded or refused
//! (the series restarts then: a substituted or returning input is a step, not a drift). The
//! slope at the reference point stands for the slope at every point (a thermal growth that
//! depends on position is extrapolated as the reference point's). What leaves the box still goes
//! through the last-step guard (clamp, per-block cap) in [`super::live`].
//!
//! Sans-IO, fixed memory: at most [`CAPACITY`] samples, taken at least `window_s / 64` apart.
//! Units: s of the sources' clock, µm (corrections, = −error).

use std::collections::VecDeque;

use retrocomp_model::approach::Approach;

/// Fewest samples a slope is taken from.
pub(crate) const MIN_SAMPLES: usize = 4;
/// Most samples kept (`window_s / 64` apart: a full window holds ≈ 65).
pub(crate) const CAPACITY: usize = 128;

/// The `[dnc]` keys of the prediction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftConfig {
    /// The slope is fitted over this much of the past, s.
    pub window_s: f64,
    /// Extrapolate at most this far ahead, s.
    pub max_horizon_s: f64,
}

/// The reference point's correction over time and the slope fitted to it.
#[derive(Debug)]
pub(crate) struct DriftPredictor {
    cfg: DriftConfig,
    reference: Option<([f64; 3], [Approach; 3])>,
    /// (t_s, correction per axis X, Y, Z µm) at the reference point, oldest first.
    samples: VecDeque<(f64, [Option<f64>; 3])>,
}

impl DriftPredictor {
    pub(crate) fn new(cfg: DriftConfig) -> Self {
        Self {
            cfg,
            reference: None,
            samples: VecDeque::with_capacity(CAPACITY),
        }
    }

    /// The point the series is taken at (None before the first compensated block).
    pub(crate) fn reference(&self) -> Option<([f64; 3], [Approach; 3])> {
        self.reference
    }

    /// Whether a sample at `now_s` would be kept (the caller evaluates the reference point only
    /// then).
    pub(crate) fn due(&self, now_s: f64) -> bool {
        self.samples
            .back()
            .is_none_or(|&(t, _)| now_s - t >= self.cfg.window_s / 64.0 || now_s < t)
    }

    /// The correction at `pos_mm`/`dirs` at `now_s`, from healthy inputs. The first one fixes
    /// the reference point; later ones count only at the reference point.
    pub(crate) fn record(
        &mut self,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
        now_s: f64,
        c: [Option<f64>; 3],
    ) {
        let r = *self.reference.get_or_insert((pos_mm, dirs));
        if r.0.map(f64::to_bits) != pos_mm.map(f64::to_bits) || r.1 != dirs || !self.due(now_s) {
            return;
        }
        if self.samples.back().is_some_and(|&(t, _)| now_s < t) {
            // The clock went back: the series is not one any more.
            self.samples.clear();
        }
        while self.samples.len() >= CAPACITY
            || self
                .samples
                .front()
                .is_some_and(|&(t, _)| now_s - t > self.cfg.window_s)
        {
            self.samples.pop_front();
        }
        self.samples.push_back((now_s, c));
    }

    /// An input is degraded or refused: the series restarts (the reference point stays).
    pub(crate) fn reset(&mut self) {
        self.samples.clear();
    }

    /// What to add to the present correction of each axis for a block estimated to end at
    /// `end_s`, µm (0 while the series is too short or the block is not in the future).
    pub(crate) fn ahead_um(&self, now_s: f64, end_s: f64) -> [f64; 3] {
        let h = (end_s - now_s).clamp(0.0, self.cfg.max_horizon_s);
        let mut out = [0.0; 3];
        if !h.is_finite() || h == 0.0 {
            return out;
        }
        for (k, o) in out.iter_mut().enumerate() {
            *o = self.slope_um_per_s(k, now_s).map_or(0.0, |s| s * h);
        }
        out
    }

    /// Least-squares slope of axis `k` over the samples within the window before `now_s`.
    fn slope_um_per_s(&self, k: usize, now_s: f64) -> Option<f64> {
        let in_window = || {
            self.samples
                .iter()
                .filter(move |(t, _)| now_s - t <= self.cfg.window_s)
                .filter_map(move |&(t, c)| Some((t, c[k]?)))
        };
        let (mut n, mut first, mut last) = (0usize, f64::INFINITY, f64::NEG_INFINITY);
        let (mut sum_t, mut sum_c) = (0.0, 0.0);
        for (t, c) in in_window() {
            n += 1;
            first = first.min(t);
            last = last.max(t);
            sum_t += t;
            sum_c += c;
        }
        if n < MIN_SAMPLES || last - first < self.cfg.window_s / 4.0 {
            return None;
        }
        #[allow(
            clippy::cast_precision_loss,
            reason = "n ≤ CAPACITY = 128, exact in f64"
        )]
        let (mean_t, mean_c) = (sum_t / n as f64, sum_c / n as f64);
        let (mut stc, mut stt) = (0.0, 0.0);
        for (t, c) in in_window() {
            stc += (t - mean_t) * (c - mean_c);
            stt += (t - mean_t) * (t - mean_t);
        }
        (stt > 0.0).then(|| stc / stt)
    }
}
