//! Drive-train errors between the motor encoder and the slide: lost motion (backlash, optionally
//! varying along the axis) and cyclic lead-screw error. Both are in µm, slide − motor.
//!
//! Backlash: the slide trails the screw by half the play, so after a move in +direction the slide is
//! b/2 short (error −b/2), after a move in −direction it is b/2 beyond (+b/2). In docs/diagnose-json.md terms:
//! `e += b_um/2 · sign(v)` with `b_um = −b` (the manifest reports it that way).

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BacklashConfig {
    /// Play (full lost motion) where no profile is given.
    #[serde(default)]
    pub b_um: f64,
    /// Reversal value varying along the axis: `[[pos_mm, b_um], …]`, increasing positions,
    /// linearly interpolated, held constant outside.
    #[serde(default)]
    pub profile: Vec<[f64; 2]>,
}

impl BacklashConfig {
    pub fn b_at_um(&self, pos_mm: f64) -> f64 {
        let p = &self.profile;
        if p.is_empty() {
            return self.b_um;
        }
        let i = p.partition_point(|r| r[0] <= pos_mm);
        if i == 0 {
            p[0][1]
        } else if i == p.len() {
            p[p.len() - 1][1]
        } else {
            let (a, b) = (p[i - 1], p[i]);
            a[1] + (b[1] - a[1]) * (pos_mm - a[0]) / (b[0] - a[0])
        }
    }
}

/// Lost-motion state: the slide position relative to the motor.
#[derive(Clone, Debug)]
pub(crate) struct Backlash {
    cfg: BacklashConfig,
    offset_um: f64,
}

impl Backlash {
    /// Starts as if the axis last moved in +direction (slide b/2 short).
    pub(crate) fn new(cfg: BacklashConfig, motor_mm: f64) -> Self {
        let offset_um = -cfg.b_at_um(motor_mm) / 2.0;
        Self { cfg, offset_um }
    }

    /// Move the motor to `motor_mm` (after the previous position `prev_mm`); returns slide − motor, µm.
    pub(crate) fn update(&mut self, prev_mm: f64, motor_mm: f64) -> f64 {
        let half = self.cfg.b_at_um(motor_mm).abs() / 2.0;
        let dp_um = (motor_mm - prev_mm) * 1000.0;
        // The slide does not move until the screw takes up the play: slide − motor shrinks by the motion.
        self.offset_um = (self.offset_um - dp_um).clamp(-half, half);
        self.offset_um
    }

    pub(crate) fn offset_um(&self) -> f64 {
        self.offset_um
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CyclicConfig {
    pub period_mm: f64,
    pub amplitude_um: f64,
    #[serde(default)]
    pub phase_rad: f64,
}

impl CyclicConfig {
    /// Slide − motor from lead-screw pitch error at a motor position.
    pub fn error_um(&self, motor_mm: f64) -> f64 {
        self.amplitude_um
            * (std::f64::consts::TAU * motor_mm / self.period_mm + self.phase_rad).sin()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backlash_flips_sign_on_reversal_and_takes_up_play_gradually() {
        let mut b = Backlash::new(
            BacklashConfig {
                b_um: 6.0,
                profile: vec![],
            },
            0.0,
        );
        let mut p = 0.0;
        for _ in 0..100 {
            let q = p + 0.01;
            b.update(p, q);
            p = q;
        }
        assert_eq!(b.offset_um(), -3.0);
        // Reverse by 4 µm: the slide has not moved yet (offset grew by 4 µm, from −3 to +1).
        let off = b.update(p, p - 0.004);
        assert!((off - 1.0).abs() < 1e-9, "{off}");
        p -= 0.004;
        let off = b.update(p, p - 0.010);
        assert_eq!(off, 3.0);
    }

    #[test]
    fn profile_interpolates_and_holds_outside() {
        let c = BacklashConfig {
            b_um: 0.0,
            profile: vec![[0.0, 2.0], [100.0, 8.0]],
        };
        assert_eq!(c.b_at_um(-5.0), 2.0);
        assert_eq!(c.b_at_um(50.0), 5.0);
        assert_eq!(c.b_at_um(500.0), 8.0);
    }

    #[test]
    fn cyclic_error_is_periodic() {
        let c = CyclicConfig {
            period_mm: 5.0,
            amplitude_um: 2.0,
            phase_rad: 0.0,
        };
        assert!((c.error_um(1.25) - 2.0).abs() < 1e-12);
        assert!((c.error_um(1.25 + 5.0) - 2.0).abs() < 1e-9);
        assert!((c.error_um(3.75) + 2.0).abs() < 1e-12);
    }
}
