//! Direction latch with deadband and a ramped forward/reverse switch. The direction itself is the
//! shared definition of `retrocomp_model::approach` (also used by diagnose); this file adds the blend.
//!
//! Bidirectional error functions (forward/reverse tables: Graves' Error File, Asad Ullah's F/R data)
//! need the direction of travel. Noise around a standstill must not flip it, so the latch only
//! reverses once the axis has moved `deadband_mm` back from the extreme it reached (hysteresis — Spaan
//! Ch6's remedy for "virtual hysteresis" and limit cycles). A reversal never makes the output jump: the
//! forward weight moves between 1 and 0 along a sin² profile over `switch_time_s` (ISG spreads
//! backlash sin² over cycles; LinuxCNC ramps it). Before the first latch the weight is ½ (mean of F/R).
//!
//! Use: `value = w·forward + (1 − w)·reverse` with `w = weight_forward()`.

use serde::{Deserialize, Serialize};

use retrocomp_model::approach::{Approach, ApproachLatch};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DirectionConfig {
    /// Travel back from the extreme needed to latch a reversal, mm.
    pub deadband_mm: f64,
    /// Duration of the F/R blend after a reversal, s (0 = immediate, which jumps).
    pub switch_time_s: f64,
}

#[derive(Clone, Debug)]
pub struct DirectionLatch {
    cfg: DirectionConfig,
    /// The shared definition of the direction of approach (`retrocomp_model::approach`).
    approach: ApproachLatch,
    /// Blend start: (time, weight at that time, target weight).
    blend: (f64, f64, f64),
    weight: f64,
}

impl DirectionLatch {
    pub fn new(cfg: DirectionConfig) -> Self {
        Self {
            cfg,
            approach: ApproachLatch::new(cfg.deadband_mm),
            blend: (0.0, 0.5, 0.5),
            weight: 0.5,
        }
    }

    pub fn direction(&self) -> Option<Approach> {
        self.approach.approach()
    }

    pub fn weight_forward(&self) -> f64 {
        self.weight
    }

    /// Feed the (set-point or measured) position; returns the forward weight for this cycle.
    pub fn update(&mut self, pos_mm: f64, now_s: f64) -> f64 {
        if self.approach.update(pos_mm).is_some() {
            let target = if self.approach.dir() > 0 { 1.0 } else { 0.0 };
            self.blend = (now_s, self.weight, target);
        }
        let (t0, w0, w1) = self.blend;
        let phase = if self.cfg.switch_time_s > 0.0 {
            ((now_s - t0) / self.cfg.switch_time_s).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let s = (phase * std::f64::consts::FRAC_PI_2).sin();
        self.weight = w0 + (w1 - w0) * s * s;
        self.weight
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_inside_deadband_does_not_flip() {
        let mut l = DirectionLatch::new(DirectionConfig {
            deadband_mm: 0.01,
            switch_time_s: 0.1,
        });
        l.update(0.0, 0.0);
        l.update(1.0, 0.1);
        assert_eq!(l.direction(), Some(Approach::Forward));
        for (k, p) in [0.995, 1.0, 0.992, 0.999].iter().enumerate() {
            l.update(*p, 0.2 + k as f64 * 0.01);
            assert_eq!(l.direction(), Some(Approach::Forward), "flipped at {p}");
        }
        l.update(0.98, 0.3);
        assert_eq!(l.direction(), Some(Approach::Reverse));
    }

    #[test]
    fn reversal_blends_without_jump() {
        let cfg = DirectionConfig {
            deadband_mm: 0.005,
            switch_time_s: 0.05,
        };
        let mut l = DirectionLatch::new(cfg);
        // Forward 0 → 10 mm, then back: a 6 µm backlash table (F = +3, R = −3) must not step.
        let (fwd, rev) = (3.0, -3.0);
        let mut last: Option<f64> = None;
        let mut t = 0.0;
        let mut worst = 0.0f64;
        let path = (0..=100)
            .map(|k| f64::from(k) * 0.1)
            .chain((0..100).map(|k| 10.0 - f64::from(k) * 0.1));
        for p in path {
            t += 0.001;
            let w = l.update(p, t);
            let v = w * fwd + (1.0 - w) * rev;
            if let Some(prev) = last {
                worst = worst.max((v - prev).abs());
            }
            last = Some(v);
        }
        assert_eq!(l.direction(), Some(Approach::Reverse));
        // sin² over 50 cycles: max slope π/2 · 6 µm / 50 ≈ 0.19 µm per cycle.
        assert!(worst < 0.2 && worst > 0.05, "largest step {worst} µm");
    }
}
