//! Safety in one place, per axis: every value that leaves the box passes through [`AxisSafety::step`].
//!
//! - clamp: |output| ≤ `max_correction_um`, always (a NaN or out-of-range target never passes);
//! - dosing: |Δoutput| ≤ `max_change_um_per_cycle` every cycle (Spaan 1995 Ch6 "compensation dosing
//!   system": "never more than a predefined number of increments per NC-controller cycle-time");
//! - ramp at `ramp_um_per_s` (and still within the dosing cap) after start, enable, disable, fault and
//!   return from stale inputs, so none of these makes the output jump;
//! - stale inputs: hold the last output for `stale_hold_s`, then ramp to zero.
//!
//! Units: µm and s. The output is the correction (= −error) handed to a sink.

use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Clamp on the absolute correction, µm.
    pub max_correction_um: f64,
    /// Dosing cap: largest change of the output in one cycle, µm.
    pub max_change_um_per_cycle: f64,
    /// Ramp rate used on enable/disable/fault/stale transitions, µm/s.
    pub ramp_um_per_s: f64,
    /// How long stale inputs hold the last output before it ramps to zero, s.
    pub stale_hold_s: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SafetyError {
    #[error("safety.{key} must be finite and > 0 (got {value})")]
    BadConfig { key: &'static str, value: f64 },
    #[error("safety.{key} = {value} is absurd: expected at most {max}")]
    Absurd {
        key: &'static str,
        value: f64,
        max: f64,
    },
    #[error(
        "the controller already holds {value_um} µm, beyond the clamp ±{max_um} µm: refusing to start (clear the register or raise max_correction_um)"
    )]
    InitialBeyondClamp { value_um: f64, max_um: f64 },
}

/// Largest clamp a config may ask for, µm (10 mm: beyond that the unit is wrong, not the machine).
pub(crate) const MAX_CORRECTION_LIMIT_UM: f64 = 10_000.0;

impl SafetyConfig {
    pub fn validate(&self) -> Result<(), SafetyError> {
        for (key, value) in [
            ("max_correction_um", self.max_correction_um),
            ("max_change_um_per_cycle", self.max_change_um_per_cycle),
            ("ramp_um_per_s", self.ramp_um_per_s),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(SafetyError::BadConfig { key, value });
            }
        }
        if !(self.stale_hold_s.is_finite() && self.stale_hold_s >= 0.0) {
            return Err(SafetyError::BadConfig {
                key: "stale_hold_s",
                value: self.stale_hold_s,
            });
        }
        // Absurd limits: a correction of centimetres is a wrong unit, not a machine error; a cap
        // above the clamp or an hour-long hold means the limit does not limit.
        for (key, value, max) in [
            (
                "max_correction_um",
                self.max_correction_um,
                MAX_CORRECTION_LIMIT_UM,
            ),
            (
                "max_change_um_per_cycle",
                self.max_change_um_per_cycle,
                self.max_correction_um,
            ),
            ("stale_hold_s", self.stale_hold_s, 3600.0),
        ] {
            if value > max {
                return Err(SafetyError::Absurd { key, value, max });
            }
        }
        Ok(())
    }
}

/// What the model side delivers this cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Input {
    /// A fresh correction target, µm (may be NaN or huge: it is checked here).
    Fresh(f64),
    /// The inputs behind the target are stale (no fresh position/temperature).
    Stale,
    /// A fault that forbids compensation (e.g. a required sensor failed without substitute).
    Fault,
}

pub use crate::status::Mode;

#[derive(Clone, Debug)]
pub struct AxisSafety {
    cfg: SafetyConfig,
    output_um: f64,
    mode: Mode,
    stale_since_s: Option<f64>,
    last_t_s: Option<f64>,
    /// Cycles whose model target was beyond `max_correction_um` (clamped), since start.
    clamp_hits: u64,
    /// Cycles whose step was limited by `max_change_um_per_cycle` (dosing cap), since start.
    cap_hits: u64,
}

impl AxisSafety {
    /// Start from the value the controller already holds (read back from its registers), so a
    /// restart does not jump. Refuses a start value beyond the clamp: any write would be out of limit.
    pub fn new(cfg: SafetyConfig, initial_output_um: f64) -> Result<Self, SafetyError> {
        cfg.validate()?;
        if !initial_output_um.is_finite() || initial_output_um.abs() > cfg.max_correction_um {
            return Err(SafetyError::InitialBeyondClamp {
                value_um: initial_output_um,
                max_um: cfg.max_correction_um,
            });
        }
        Ok(Self {
            cfg,
            output_um: initial_output_um,
            mode: Mode::RampingIn,
            stale_since_s: None,
            last_t_s: None,
            clamp_hits: 0,
            cap_hits: 0,
        })
    }

    /// Continue from `held_um`, the value the controller holds now (a foreign write: an operator, a
    /// controller restart), keeping the clock of the last cycle: the next cycle ramps from it by
    /// `ramp_um_per_s × dt` (≤ the dosing cap), as after a start. A fresh state ([`Self::new`]) has
    /// no earlier cycle, so its first step has `dt = 0` and does not move: after a reseed that
    /// would cost one write period standing still. Refuses a value beyond the clamp (unchanged).
    pub fn reseed(&mut self, held_um: f64) -> Result<(), SafetyError> {
        let fresh = Self::new(self.cfg, held_um)?;
        *self = Self {
            last_t_s: self.last_t_s,
            clamp_hits: self.clamp_hits,
            cap_hits: self.cap_hits,
            ..fresh
        };
        Ok(())
    }

    pub fn output_um(&self) -> f64 {
        self.output_um
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    pub fn config(&self) -> &SafetyConfig {
        &self.cfg
    }

    /// The target's make-up changed (an auxiliary input's terms dropped or came back, see the
    /// engine): reach the new target at the ramp rate instead of the dosing cap, like a return
    /// from stale inputs, so a dropped term is ramped out and a returning one ramped in.
    pub fn ramp_to_next_target(&mut self) {
        if self.mode == Mode::Tracking {
            self.mode = Mode::RampingIn;
        }
    }

    /// (clamp hits, dosing-cap hits) since start: how often the safety layer cut the model's wish.
    pub fn hits(&self) -> (u64, u64) {
        (self.clamp_hits, self.cap_hits)
    }

    /// One cycle at time `now_s`. Returns the output to write (clamped, capped, ramped).
    pub fn step(&mut self, now_s: f64, enabled: bool, input: Input) -> f64 {
        let dt_s = match self.last_t_s {
            Some(t) if now_s > t => now_s - t,
            _ => 0.0,
        };
        self.last_t_s = Some(self.last_t_s.map_or(now_s, |t| t.max(now_s)));
        let cap = self.cfg.max_change_um_per_cycle;
        let ramp = (self.cfg.ramp_um_per_s * dt_s).min(cap);
        let max = self.cfg.max_correction_um;

        if let Input::Fresh(v) = input
            && v.is_finite()
            && v.abs() > max
        {
            self.clamp_hits += 1;
        }
        let fresh = match input {
            Input::Fresh(v) if v.is_finite() => Some(v.clamp(-max, max)),
            Input::Fresh(_) | Input::Fault => None,
            Input::Stale => None,
        };
        if !matches!(input, Input::Stale) {
            self.stale_since_s = None;
        }

        let (desired, limit, mode) = if !enabled {
            (0.0, ramp, Mode::RampingOut)
        } else if let Some(target) = fresh {
            let mode = match self.mode {
                Mode::Tracking => Mode::Tracking,
                _ => Mode::RampingIn,
            };
            let limit = if mode == Mode::Tracking { cap } else { ramp };
            (target, limit, mode)
        } else if matches!(input, Input::Stale) {
            let since = *self.stale_since_s.get_or_insert(now_s);
            if now_s - since < self.cfg.stale_hold_s {
                (self.output_um, 0.0, Mode::Holding)
            } else {
                (0.0, ramp, Mode::RampingOut)
            }
        } else {
            // Fault or non-finite target.
            (0.0, ramp, Mode::RampingOut)
        };

        let delta = (desired - self.output_um).clamp(-limit, limit);
        // A cap hit: tracking (the limit is the per-cycle cap, not a ramp) and the step wanted more.
        if mode == Mode::Tracking && cap > 0.0 && (desired - self.output_um).abs() > cap {
            self.cap_hits += 1;
        }
        self.output_um = (self.output_um + delta).clamp(-max, max);
        self.mode = if mode == Mode::RampingIn
            && (desired - self.output_um).abs() <= f64::EPSILON * max.max(1.0)
        {
            Mode::Tracking
        } else {
            mode
        };
        self.output_um
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> SafetyConfig {
        SafetyConfig {
            max_correction_um: 50.0,
            max_change_um_per_cycle: 1.0,
            ramp_um_per_s: 20.0,
            stale_hold_s: 0.5,
        }
    }

    #[test]
    fn dosing_spreads_spaan_2um_step_over_two_cycles() {
        // Spaan 1995 §6 (p. 109–110): a 2 µm compensation jump gave a 5 µm limit cycle on the Maho 700S
        // while 1 µm (= scale resolution) was stable; dosing limits the change per 15 ms NC cycle.
        let c = SafetyConfig {
            max_change_um_per_cycle: 1.0,
            ramp_um_per_s: 1e6,
            ..cfg()
        };
        let mut s = AxisSafety::new(c, 0.0).unwrap();
        s.step(0.0, true, Input::Fresh(0.0));
        assert_eq!(s.mode(), Mode::Tracking);
        assert_eq!(s.step(0.015, true, Input::Fresh(2.0)), 1.0);
        assert_eq!(s.step(0.030, true, Input::Fresh(2.0)), 2.0);
        assert_eq!(s.hits(), (0, 1), "the 2 µm step was cut once by the cap");
        s.step(0.045, true, Input::Fresh(80.0));
        assert_eq!(
            s.hits(),
            (1, 2),
            "80 µm is beyond the 50 µm clamp, then capped"
        );
    }

    #[test]
    fn nan_and_huge_targets_never_pass() {
        let mut s = AxisSafety::new(cfg(), 0.0).unwrap();
        let mut t = 0.0;
        // Ramp-in at 20 µm/s × 10 ms = 0.2 µm per cycle reaches the 50 µm clamp after 250 cycles.
        for _ in 0..300 {
            t += 0.01;
            let o = s.step(t, true, Input::Fresh(1e9));
            assert!(o <= 50.0);
        }
        assert_eq!(s.output_um(), 50.0);
        let before = s.output_um();
        let o = s.step(t + 0.01, true, Input::Fresh(f64::NAN));
        assert!(
            o.is_finite() && (before - o) <= 20.0 * 0.01 + 1e-12,
            "NaN makes it ramp down, not jump"
        );
    }

    #[test]
    fn stale_holds_then_ramps_to_zero_then_ramps_back() {
        let mut s = AxisSafety::new(cfg(), 10.0).unwrap();
        s.step(0.0, true, Input::Fresh(10.0));
        assert_eq!(s.step(0.1, true, Input::Stale), 10.0);
        assert_eq!(s.mode(), Mode::Holding);
        assert_eq!(
            s.step(0.55, true, Input::Stale),
            10.0,
            "still inside the 0.5 s hold"
        );
        let o = s.step(0.7, true, Input::Stale);
        assert_eq!(s.mode(), Mode::RampingOut);
        assert!(
            (o - 9.0).abs() < 1e-9,
            "ramp 20 µm/s × 0.15 s capped at 1 µm: {o}"
        );
        let mut t = 0.7;
        while s.output_um() > 0.0 {
            t += 0.01;
            s.step(t, true, Input::Stale);
        }
        // Source back: ramp in, no jump to 10.
        let o = s.step(t + 0.01, true, Input::Fresh(10.0));
        assert!(o <= 0.2 + 1e-9);
        assert_eq!(s.mode(), Mode::RampingIn);
    }

    #[test]
    fn a_reseed_keeps_the_cycle_clock_so_its_first_cycle_moves_by_at_most_the_cap() {
        // Tracking at 10 µm, 10 ms cycles; a foreign 22 µm arrives, the target stays 10 µm.
        let mut s = AxisSafety::new(cfg(), 10.0).unwrap();
        s.step(0.0, true, Input::Fresh(10.0));
        s.step(0.01, true, Input::Fresh(10.0));
        s.reseed(22.0).unwrap();
        assert_eq!((s.output_um(), s.mode()), (22.0, Mode::RampingIn));
        // The first cycle after the reseed ramps 20 µm/s × 10 ms = 0.2 µm (≤ the 1 µm cap) from
        // the held value, towards the target: not standing still, not jumping back.
        let o = s.step(0.02, true, Input::Fresh(10.0));
        assert!((o - 21.8).abs() < 1e-9, "{o}");
        assert!(s.reseed(60.0).is_err(), "beyond the clamp");
        assert!(
            (s.output_um() - 21.8).abs() < 1e-9,
            "a refused reseed changes nothing"
        );
    }

    #[test]
    fn refuses_start_beyond_clamp() {
        assert!(AxisSafety::new(cfg(), 60.0).is_err());
        assert!(
            AxisSafety::new(
                SafetyConfig {
                    ramp_um_per_s: 0.0,
                    ..cfg()
                },
                0.0
            )
            .is_err()
        );
    }
}
