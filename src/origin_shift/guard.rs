//! The last-step guard: the final check on every value before it goes to the controller, judged
//! against what the controller ACTUALLY holds (its registers, read just before the write), not
//! against what the box believes it wrote. Sans-IO and transport-agnostic, so every sink that writes
//! a correction the controller applies as a step (origin-shift client, a Modbus server sink) can use
//! the same rule.
//!
//! Per axis, the guard keeps the set of values the controller may be applying now, as an interval
//! `[lo, hi]` (µm):
//! - a read of the registers adds the read value; when nothing of ours is unconfirmed, or the value is
//!   none of ours (a controller restart, an operator, another writer), the read value is the whole
//!   set;
//! - a write that was not confirmed (no ack, read-back mismatch, a request failed after the values
//!   went out) keeps the values from before it in the set: the controller may have applied either;
//! - a confirmed write (acknowledged / read back) makes the written value the whole set.
//!
//! A value may be written only when it is within `max_correction_um` (the clamp) and within
//! `max_change_um_per_write` (the cap) of EVERY value in the set. The guard moves the wanted value
//! into that window; the sink never sends anything else.
//!
//! Policy for a controller holding a value beyond the clamp (at start, after a reconnect, after a
//! controller restart or a foreign write; the same everywhere): no write can be within both the
//! clamp and the cap of it, so the axis is NOT written: [`Verdict::BeyondClamp`] (the sink raises a
//! fault and shows the controller's value) until the controller's value is back within the clamp
//! (operator, or the PLC's watchdog rule ramping it out). The box never ramps from out of range.
//!
//! Every write is within the cap of every member, so the set stays narrower than one cap and a write
//! always fits; [`Verdict::Uncertain`] (a fault, no write) is the defensive answer should it not.
//! Assumption (documented in docs/gateway.md): another writer changes the value registers only
//! together with what the controller applies (a restart, the PLC's own logic, a strobed write); a
//! foreign register write that the controller does not apply cannot be seen from outside.
//!
//! Units: µm. Values are corrections as the sink writes them (register = sign × value / lsb).

/// Limits of one axis at the last step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuardLimits {
    /// Clamp on the absolute value written, µm.
    pub max_correction_um: f64,
    /// Largest step between what the controller holds and what is written, µm per write.
    pub max_change_um_per_write: f64,
    /// Register resolution, µm: the tolerance for values that went through the register encoding.
    pub lsb_um: f64,
}

/// What the guard allows for one axis this write.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Verdict {
    /// Write this value (the wanted one moved into the safe window).
    Write(f64),
    /// Nothing known about the controller's value yet (no read): do not write.
    Unknown,
    /// The controller holds `held_um`, beyond the clamp: do not write (fault until it is back).
    BeyondClamp { held_um: f64 },
    /// The controller may be applying values more than two caps apart: do not write (fault).
    Uncertain { lo_um: f64, hi_um: f64 },
}

#[derive(Clone, Debug)]
struct AxisGuard {
    limits: GuardLimits,
    /// Values the controller may be applying now (None before the first read).
    may_hold: Option<(f64, f64)>,
    /// Last value read from the registers.
    read_um: Option<f64>,
    /// A write of ours is unconfirmed (its predecessor may still be applied).
    unconfirmed: bool,
}

/// The last-step guard of one sink, axes by index (the sink's order).
#[derive(Clone, Debug)]
pub struct WriteGuard {
    axes: Vec<AxisGuard>,
}

impl WriteGuard {
    pub fn new(limits: impl IntoIterator<Item = GuardLimits>) -> Self {
        Self {
            axes: limits
                .into_iter()
                .map(|limits| AxisGuard {
                    limits,
                    may_hold: None,
                    read_um: None,
                    unconfirmed: false,
                })
                .collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.axes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.axes.is_empty()
    }

    /// The controller's registers hold `held_um` now (read just before the write).
    pub fn observe_read(&mut self, axis: usize, held_um: f64) {
        let a = &mut self.axes[axis];
        a.read_um = Some(held_um);
        let tol = a.limits.lsb_um;
        a.may_hold = match (a.may_hold, a.unconfirmed) {
            // Our own unconfirmed write may or may not be applied: both stay in the set.
            (Some((lo, hi)), true) if held_um >= lo - tol && held_um <= hi + tol => {
                Some((lo.min(held_um), hi.max(held_um)))
            }
            // Nothing of ours pending, or a value none of ours could explain (controller restart,
            // operator, another writer): the controller's registers are the truth.
            _ => {
                a.unconfirmed = false;
                Some((held_um, held_um))
            }
        };
    }

    /// The last value read from the controller's registers (for status and metrics).
    pub fn read_um(&self, axis: usize) -> Option<f64> {
        self.axes[axis].read_um
    }

    /// The interval of values the controller may be applying.
    pub fn may_hold(&self, axis: usize) -> Option<(f64, f64)> {
        self.axes[axis].may_hold
    }

    /// The value to write for `want_um`, or why none may be written.
    pub fn check(&self, axis: usize, want_um: f64) -> Verdict {
        let a = &self.axes[axis];
        let GuardLimits {
            max_correction_um: max,
            max_change_um_per_write: cap,
            lsb_um,
        } = a.limits;
        let Some((lo, hi)) = a.may_hold else {
            return Verdict::Unknown;
        };
        // Half a count of tolerance: a value we wrote at the clamp reads back rounded.
        let tol = lsb_um * 0.5;
        for held_um in [lo, hi] {
            if !held_um.is_finite() || held_um.abs() > max + tol {
                return Verdict::BeyondClamp { held_um };
            }
        }
        let (from, to) = ((hi - cap).max(-max), (lo + cap).min(max));
        if from > to {
            return Verdict::Uncertain {
                lo_um: lo,
                hi_um: hi,
            };
        }
        // A NaN want stays where the controller is (the closest value of the window to it).
        let want = if want_um.is_finite() {
            want_um
        } else {
            (lo + hi) / 2.0
        };
        Verdict::Write(want.clamp(from, to))
    }

    /// A write of `wrote_um` went out. `confirmed`: the controller acknowledged / read back exactly
    /// this value, so it is what it applies now.
    pub fn wrote(&mut self, axis: usize, wrote_um: f64, confirmed: bool) {
        let a = &mut self.axes[axis];
        if confirmed {
            a.may_hold = Some((wrote_um, wrote_um));
            a.unconfirmed = false;
        } else {
            let (lo, hi) = a.may_hold.unwrap_or((wrote_um, wrote_um));
            a.may_hold = Some((lo.min(wrote_um), hi.max(wrote_um)));
            a.unconfirmed = true;
        }
    }

    /// After [`Verdict::Uncertain`]: take the next read as the truth.
    pub fn forget_unconfirmed(&mut self, axis: usize) {
        self.axes[axis].unconfirmed = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guard() -> WriteGuard {
        WriteGuard::new([GuardLimits {
            max_correction_um: 60.0,
            max_change_um_per_write: 0.5,
            lsb_um: 0.1,
        }])
    }

    #[test]
    fn nothing_is_written_before_the_controller_was_read() {
        assert_eq!(guard().check(0, 1.0), Verdict::Unknown);
    }

    #[test]
    fn writes_are_capped_from_what_the_controller_holds_not_from_what_we_wrote() {
        let mut g = guard();
        g.observe_read(0, 10.0);
        assert_eq!(g.check(0, 40.0), Verdict::Write(10.5));
        g.wrote(0, 10.5, true);
        // The controller was reset behind our back: cap from its 0, not from our 10.5.
        g.observe_read(0, 0.0);
        assert_eq!(g.check(0, 11.0), Verdict::Write(0.5));
        assert_eq!(g.check(0, f64::NAN), Verdict::Write(0.0));
    }

    #[test]
    fn a_value_beyond_the_clamp_is_never_written_from_or_towards() {
        let mut g = guard();
        g.observe_read(0, 100.0);
        assert_eq!(g.check(0, 0.0), Verdict::BeyondClamp { held_um: 100.0 });
        g.observe_read(0, -60.04);
        assert_eq!(
            g.check(0, 0.0),
            Verdict::Write(-59.54),
            "within half a count"
        );
        g.observe_read(0, 59.8);
        assert_eq!(g.check(0, 1e9), Verdict::Write(60.0));
    }

    #[test]
    fn an_unconfirmed_write_keeps_its_predecessor_in_the_set() {
        let mut g = guard();
        g.observe_read(0, 0.0);
        g.wrote(0, 0.5, false);
        // The registers show 0.5, but the controller may still apply 0 (the strobe got lost).
        g.observe_read(0, 0.5);
        assert_eq!(g.may_hold(0), Some((0.0, 0.5)));
        assert_eq!(g.check(0, 5.0), Verdict::Write(0.5));
        assert_eq!(g.check(0, -5.0), Verdict::Write(0.0));
        // A foreign 30 (none of ours): the registers are the truth.
        g.observe_read(0, 30.0);
        assert_eq!(g.may_hold(0), Some((30.0, 30.0)));
        assert_eq!(g.check(0, 31.0), Verdict::Write(30.5));
        g.wrote(0, 30.5, true);
        assert_eq!(g.may_hold(0), Some((30.5, 30.5)));
    }
}
