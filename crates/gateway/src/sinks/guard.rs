//! The last-step guard: ONE check every value the box sends toward a controller passes, whatever
//! the sink (the origin-shift client's register writes, the origin-shift server's served registers,
//! the quadrature injector's counts), judged against what the controller holds or may be applying,
//! never against what the box believes it sent. Sans-IO and transport-agnostic.
//!
//! The one policy (docs/gateway.md, "The last-step guard"):
//! - never beyond the clamp (`max_correction_um`), in whole counts of the output's resolution;
//! - never a step beyond the per-write cap (`max_change_um_per_write`) from ANY value the controller
//!   holds or may be applying;
//! - a controller value beyond the clamp is [`Verdict::BeyondClamp`]: a fault, that axis is not
//!   sent (not written, not served, not injected) and never ramped from, the sink shows the held
//!   value; the axis resumes once the controller's value is back within the clamp;
//! - stop = ramp out: the sinks want 0, so the guard moves each axis by at most one cap per write.
//!
//! Per axis, the guard keeps the set of values the controller may be applying now, as an interval
//! `[lo, hi]` (µm). Evidence comes in two kinds, by what the sink can see:
//! - [`WriteGuard::observe_read`], the controller's own registers read back (client sink; the
//!   quadrature sink's persisted held counts): the read value is added while a write of ours is
//!   unconfirmed, and is the whole set otherwise or when it is none of ours (a controller restart,
//!   an operator, another writer);
//! - [`WriteGuard::observe_report`], a value some writer reports the controller applies (the
//!   served image's held register): the exact value last sent confirms it (the whole set); any other
//!   value is ADDED to the set (a report from a rogue writer must not drop the value the controller
//!   really applies), so a report far from what was sent makes the set too wide to write from
//!   ([`Verdict::Uncertain`]) or reaches beyond the clamp ([`Verdict::BeyondClamp`]);
//! - [`WriteGuard::wrote`]: a confirmed write is the whole set, an unconfirmed one (no ack, a failed
//!   request, a served value the controller has not reported back) is added to it.
//!
//! After a refusal ([`Verdict::Uncertain`], or [`Verdict::BeyondClamp`] in a served image) the sink
//! calls [`WriteGuard::forget_unconfirmed`]: the next evidence is the whole set. A writer that can
//! write the served image's held register at will could then be believed: who may write it is the
//! listener's allow-list, not this guard.
//!
//! Every value sent is within the cap of every member, so the set stays narrower than one cap and a
//! write always fits unless foreign evidence widened it. Assumption (documented in docs/gateway.md):
//! another writer changes the client's value registers only together with what the controller
//! applies (a restart, the PLC's own logic, a strobed write).
//!
//! Units: µm. Values are corrections as the sink sends them (register = sign × value / lsb; counts
//! = −value / resolution × count_sign).

/// Clamp and per-write cap of one named axis, as the field config's safety gives them.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisLimits {
    pub axis: String,
    /// Clamp on the absolute correction sent, µm.
    pub max_correction_um: f64,
    /// Largest step from what the controller may hold to what is sent, µm per write.
    pub max_change_um_per_write: f64,
}

impl AxisLimits {
    /// `axis`'s limits in `all`; an axis without limits is never sent anything but 0 from 0.
    pub fn of(all: &[AxisLimits], axis: &str, lsb_um: f64) -> GuardLimits {
        let a = all.iter().find(|a| a.axis == axis);
        GuardLimits {
            max_correction_um: a.map_or(0.0, |a| a.max_correction_um),
            max_change_um_per_write: a.map_or(0.0, |a| a.max_change_um_per_write),
            lsb_um,
        }
    }
}

/// The faults a sink's last step left active, per axis in the sink's order (the shell turns
/// their edges into fault episodes: `origin_shift::sink_task::update_sink_faults`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SinkFaults {
    /// A request failed, was refused (Modbus exception) or was not acknowledged / read back (the
    /// client sink's link; false for the others).
    pub write_failed: bool,
    /// Per axis (map order): the controller holds a value beyond the clamp.
    pub beyond_clamp: Vec<bool>,
    /// Per axis: a foreign value arrived while a write of ours was unconfirmed.
    pub uncertain: Vec<bool>,
}

impl SinkFaults {
    /// No fault on any of `axes` axes.
    pub fn none(axes: usize) -> Self {
        SinkFaults {
            write_failed: false,
            beyond_clamp: vec![false; axes],
            uncertain: vec![false; axes],
        }
    }
}

/// Limits of one axis at the last step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuardLimits {
    /// Clamp on the absolute value written, µm.
    pub max_correction_um: f64,
    /// Largest step between what the controller holds and what is written, µm per write.
    pub max_change_um_per_write: f64,
    /// Output resolution (register lsb, µm per count): values sent are whole multiples of it, and
    /// half of it is the tolerance for values that went through the encoding.
    pub lsb_um: f64,
}

impl GuardLimits {
    /// The one rule for "the controller holds a value within the clamp", for every sink's checks
    /// and for which held values the engine may start from: finite, and at most half a count
    /// beyond the clamp (a value written at the clamp reads back rounded).
    pub fn holds_within_clamp(&self, held_um: f64) -> bool {
        held_um.is_finite() && held_um.abs() <= self.max_correction_um + self.lsb_um * 0.5
    }
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
    /// The last value sent (a report of exactly it confirms it).
    sent_um: Option<f64>,
    /// After a refusal: the next evidence is the whole set.
    trust_next: bool,
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
                    sent_um: None,
                    trust_next: false,
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
            (Some((lo, hi)), true)
                if !a.trust_next && held_um >= lo - tol && held_um <= hi + tol =>
            {
                Some((lo.min(held_um), hi.max(held_um)))
            }
            // Nothing of ours pending, or a value none of ours could explain (controller restart,
            // operator, another writer): the controller's registers are the truth.
            _ => {
                a.unconfirmed = false;
                Some((held_um, held_um))
            }
        };
        a.trust_next = false;
    }

    /// A writer reports that the controller applies `held_um` (a served image's held register).
    pub fn observe_report(&mut self, axis: usize, held_um: f64) {
        let a = &mut self.axes[axis];
        a.read_um = Some(held_um);
        let tol = a.limits.lsb_um * 0.5;
        a.may_hold = match a.may_hold {
            Some((lo, hi)) if !a.trust_next => {
                if a.sent_um.is_some_and(|s| (s - held_um).abs() <= tol) {
                    // The controller applies what was sent last, and can read nothing else now.
                    a.unconfirmed = false;
                    Some((held_um, held_um))
                } else {
                    // An older value of ours (already in the set) or a foreign one: it stays
                    // possible, and so does everything else in the set.
                    Some((lo.min(held_um), hi.max(held_um)))
                }
            }
            _ => Some((held_um, held_um)),
        };
        a.trust_next = false;
    }

    /// The set holds only 0 (within half a count): a stop ramp-out is complete.
    pub fn holds_zero(&self, axis: usize) -> bool {
        let a = &self.axes[axis];
        let tol = a.limits.lsb_um * 0.5;
        a.may_hold
            .is_some_and(|(lo, hi)| lo.abs() < tol && hi.abs() < tol)
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
        for held_um in [lo, hi] {
            if !a.limits.holds_within_clamp(held_um) {
                return Verdict::BeyondClamp { held_um };
            }
        }
        // In whole counts, inward: the value sent encodes exactly, within clamp and cap.
        let lsb = if lsb_um.is_finite() && lsb_um > 0.0 {
            lsb_um
        } else {
            1e-9
        };
        const EPS: f64 = 1e-6;
        let max_c = (max / lsb + EPS).floor();
        let from = ((hi - cap) / lsb - EPS).ceil().max(-max_c);
        let to = ((lo + cap) / lsb + EPS).floor().min(max_c);
        // NaN limits (never from a valid config) refuse too.
        if from.partial_cmp(&to).is_none_or(std::cmp::Ordering::is_gt) {
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
        Verdict::Write((want / lsb).round().clamp(from, to) * lsb)
    }

    /// A write of `wrote_um` went out. `confirmed`: the controller acknowledged / read back exactly
    /// this value, so it is what it applies now.
    pub fn wrote(&mut self, axis: usize, wrote_um: f64, confirmed: bool) {
        let a = &mut self.axes[axis];
        a.sent_um = Some(wrote_um);
        if confirmed {
            a.may_hold = Some((wrote_um, wrote_um));
            a.unconfirmed = false;
        } else {
            let (lo, hi) = a.may_hold.unwrap_or((wrote_um, wrote_um));
            a.may_hold = Some((lo.min(wrote_um), hi.max(wrote_um)));
            a.unconfirmed = true;
        }
    }

    /// After a refusal ([`Verdict::Uncertain`]; [`Verdict::BeyondClamp`] of a report): take the
    /// next read or report as the truth.
    pub fn forget_unconfirmed(&mut self, axis: usize) {
        self.axes[axis].unconfirmed = false;
        self.axes[axis].trust_next = true;
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
            Verdict::Write(-59.6),
            "within half a count; whole counts within the cap"
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

    #[test]
    fn a_report_far_from_what_was_sent_widens_the_set_never_replaces_it() {
        let mut g = guard();
        g.observe_report(0, 10.0);
        assert_eq!(g.check(0, 20.0), Verdict::Write(10.5));
        g.wrote(0, 10.5, false);
        // The controller reports the value sent: confirmed.
        g.observe_report(0, 10.5);
        assert_eq!(g.may_hold(0), Some((10.5, 10.5)));
        // A rogue report of 3276.7 µm: beyond the clamp, never served from.
        g.observe_report(0, 3276.7);
        assert_eq!(g.check(0, 20.0), Verdict::BeyondClamp { held_um: 3276.7 });
        g.forget_unconfirmed(0);
        // The controller's own next report is the truth again.
        g.observe_report(0, 10.5);
        assert_eq!(g.check(0, 20.0), Verdict::Write(11.0));
        // A foreign in-clamp report two caps away: both stay possible, nothing fits.
        g.observe_report(0, 0.0);
        assert!(matches!(g.check(0, 20.0), Verdict::Uncertain { .. }));
    }

    #[test]
    fn values_are_whole_counts_within_a_cap_that_is_not_one() {
        let mut g = WriteGuard::new([GuardLimits {
            max_correction_um: 50.05,
            max_change_um_per_write: 0.25,
            lsb_um: 0.1,
        }]);
        g.observe_read(0, 10.0);
        let Verdict::Write(v) = g.check(0, 40.0) else {
            panic!()
        };
        assert!((v - 10.2).abs() < 1e-9, "{v}");
        g.observe_read(0, 49.9);
        let Verdict::Write(v) = g.check(0, 1e300) else {
            panic!()
        };
        assert!((v - 50.0).abs() < 1e-9, "{v}");
    }
}
