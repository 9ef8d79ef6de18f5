//! Sensor health per channel: range, staleness, rate of change, stuck value. The fault vocabulary and
//! the log that reports each fault once when it starts and once when it clears live in
//! `retrocomp_bus::fault` (shared with the sinks and telemetry) and are re-exported here.
//!
//! Units are the channel's own (its name carries them). Time is seconds on the gateway's clock.
//! A rejected value is never used: the channel keeps its last good value and reports the fault.

use serde::{Deserialize, Serialize};

pub use crate::status::ChannelStatus;
pub use retrocomp_bus::fault::{FaultEvent, FaultKind, FaultLog};
use retrocomp_bus::{Health, Sample};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelLimits {
    /// Physical range (inclusive), channel units.
    pub min: f64,
    pub max: f64,
    /// No fresh good value for this long → stale, s.
    pub stale_after_s: f64,
    /// Largest plausible |rate of change|, channel units per s (None: not checked).
    #[serde(default)]
    pub max_rate_per_s: Option<f64>,
    /// A value that stays bit-identical this long is a stuck sensor, s (None: not checked).
    /// Real ADC readings carry noise; a frozen one means a dead converter or a stuck gateway.
    #[serde(default)]
    pub stuck_after_s: Option<f64>,
}

/// How far every input together may lag the cycle's clock before staleness is judged on the wall
/// clock again, s. Within it, "no new sample" is read as "our readers did not run" (a host pause),
/// not as "the sensor is silent". Safe: stale inputs only hold the last output for `stale_hold_s`
/// anyway, which is what frozen inputs give too.
pub(crate) const INPUT_LAG_ALLOW_S: f64 = 0.5;

/// A CAN `BusErrors` fault lasts this long after the last error frame, s: error frames come in
/// bursts, and one episode per burst is what an operator wants to read.
pub(crate) const BUS_ERROR_HOLD_S: f64 = 1.0;

#[derive(Clone, Debug)]
pub struct ChannelMonitor {
    limits: ChannelLimits,
    last_good: Option<(f64, f64)>,
    /// Time the current raw value was first seen (for the stuck check).
    same_since: Option<(f64, u64)>,
    /// Time of the last reading that reached the stuck check.
    last_reading_s: Option<f64>,
    sample_fault: Option<FaultKind>,
    /// Kinds of every sample rejected since the last [`ChannelMonitor::take_rejected`] (bit per
    /// kind), so a bad reading that a good one replaces before the next cycle is still logged.
    /// One bit per [`FaultKind::ALL`] entry (a compile-time check keeps them within the width).
    rejected: u32,
    stuck: bool,
}

impl ChannelMonitor {
    pub fn new(limits: ChannelLimits) -> Self {
        Self {
            limits,
            last_good: None,
            same_since: None,
            last_reading_s: None,
            sample_fault: None,
            rejected: 0,
            stuck: false,
        }
    }

    /// The kinds of the samples rejected since the last call (each at most once), then forgets
    /// them. The engine logs these even when the channel is healthy again by cycle time.
    pub fn take_rejected(&mut self) -> impl Iterator<Item = FaultKind> + use<> {
        let bits = std::mem::take(&mut self.rejected);
        FaultKind::ALL
            .into_iter()
            .enumerate()
            .filter(move |(i, _)| bits & (1 << i) != 0)
            .map(|(_, k)| k)
    }

    fn reject(&mut self, kind: FaultKind) {
        const _: () = assert!(FaultKind::ALL.len() <= u32::BITS as usize);
        self.sample_fault = Some(kind);
        if let Some(i) = FaultKind::ALL.iter().position(|k| *k == kind) {
            self.rejected |= 1 << i;
        }
    }

    pub fn limits(&self) -> &ChannelLimits {
        &self.limits
    }

    /// Judge a new sample. A bad one leaves the last good value untouched.
    pub fn observe(&mut self, s: &Sample) {
        let v = s.value;
        self.sample_fault = match s.health {
            Health::Ok => None,
            Health::DecodeError => Some(FaultKind::Decode),
            Health::OutOfRange => Some(FaultKind::OutOfRange),
            Health::Stale => Some(FaultKind::Stale),
        };
        if let Some(kind) = self.sample_fault {
            self.reject(kind);
            return;
        }
        if !v.is_finite() {
            self.reject(FaultKind::NotFinite);
            return;
        }
        if v < self.limits.min || v > self.limits.max {
            self.reject(FaultKind::OutOfRange);
            return;
        }
        if let (Some(max_rate), Some((t0, v0))) = (self.limits.max_rate_per_s, self.last_good) {
            let dt = s.t_s - t0;
            if dt > 0.0 && ((v - v0) / dt).abs() > max_rate {
                self.reject(FaultKind::RateOfChange);
                return;
            }
        }
        // Stuck means seen bit-identical for `stuck_after_s`. Across a gap in the readings (a mute
        // Modbus slave, a silent node: longer than `stale_after_s`) nobody saw the value, so the same
        // reading before and after it is no evidence: the window starts afresh. A sensor already
        // found stuck stays stuck until its value changes (the gap brought no new evidence either).
        let gap = self
            .last_reading_s
            .is_some_and(|t| s.t_s - t > self.limits.stale_after_s);
        self.last_reading_s = Some(s.t_s);
        match self.same_since {
            Some((_, bits)) if bits == v.to_bits() && (self.stuck || !gap) => {}
            _ => self.same_since = Some((s.t_s, v.to_bits())),
        }
        self.stuck = match (self.limits.stuck_after_s, self.same_since) {
            (Some(limit), Some((since, _))) => s.t_s - since >= limit,
            _ => false,
        };
        if !self.stuck {
            self.last_good = Some((s.t_s, v));
        }
    }

    /// Status at `now_s` (staleness is judged here, so call it every cycle).
    pub fn status(&self, now_s: f64) -> ChannelStatus {
        self.status_judged(now_s, now_s)
    }

    /// Status at `now_s` with staleness judged on the inputs' own clock: `inputs_s` is the newest
    /// sample time the gateway has received from any source (≤ `now_s`). A value is stale when the
    /// sources' clock shows this channel silent for `stale_after_s` (`inputs_s − t_last`), or when
    /// even allowing `INPUT_LAG_ALLOW_S` for every input being late (the gateway's readers
    /// starved by the host) it is older than `stale_after_s` on the wall clock. So a cycle that ran
    /// late, or samples still sitting in a socket buffer, do not make a channel stale; a silent
    /// channel among talking ones does, and a total silence does after the allowance.
    pub fn status_judged(&self, now_s: f64, inputs_s: f64) -> ChannelStatus {
        let mut st = ChannelStatus::unknown();
        self.status_judged_into(now_s, inputs_s, &mut st);
        st
    }

    /// [`Self::status_judged`] into `st`, reusing its fault list (the engine's per-cycle path:
    /// nothing is allocated while the same faults stay active).
    pub fn status_judged_into(&self, now_s: f64, inputs_s: f64, st: &mut ChannelStatus) {
        let faults = &mut st.faults;
        faults.clear();
        if let Some(f) = self.sample_fault {
            faults.push(f);
        }
        if self.stuck {
            faults.push(FaultKind::Stuck);
        }
        let judge_s = inputs_s.min(now_s).max(now_s - INPUT_LAG_ALLOW_S);
        let fresh = self
            .last_good
            .is_some_and(|(t, _)| judge_s - t <= self.limits.stale_after_s);
        if !fresh && !faults.contains(&FaultKind::Stale) {
            faults.push(FaultKind::Stale);
        }
        faults.sort();
        let health = match faults.first() {
            None => Health::Ok,
            Some(FaultKind::Decode) => Health::DecodeError,
            Some(FaultKind::Stale) if faults.len() == 1 => Health::Stale,
            Some(_) => Health::OutOfRange,
        };
        st.value = self.last_good.map(|(_, v)| v);
        st.reading_t_s = self.last_good.map(|(t, _)| t);
        st.health = health;
        st.substituted = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rejected_reading_replaced_before_the_cycle_is_still_reported_once() {
        let mut m = ChannelMonitor::new(ChannelLimits {
            min: 0.0,
            max: 100.0,
            stale_after_s: 1.0,
            max_rate_per_s: None,
            stuck_after_s: None,
        });
        let sample = |t_s: f64, value: f64| Sample {
            channel: retrocomp_bus::ChannelTable::default().resolve("T_C"),
            t_s,
            value,
            health: Health::Ok,
        };
        m.observe(&sample(0.0, 20.0));
        m.observe(&sample(0.001, f64::NAN));
        m.observe(&sample(0.002, 900.0));
        m.observe(&sample(0.003, 20.1));
        let st = m.status(0.004);
        assert_eq!(st.health, Health::Ok, "the good reading replaced them");
        assert_eq!(st.value, Some(20.1), "the bad readings were never used");
        let seen: Vec<FaultKind> = m.take_rejected().collect();
        assert_eq!(seen, [FaultKind::OutOfRange, FaultKind::NotFinite]);
        assert_eq!(m.take_rejected().count(), 0, "reported once");
    }

    #[test]
    fn staleness_is_judged_on_the_inputs_clock_with_a_bounded_allowance() {
        let mut m = ChannelMonitor::new(ChannelLimits {
            min: -1e6,
            max: 1e6,
            stale_after_s: 0.1,
            max_rate_per_s: None,
            stuck_after_s: None,
        });
        m.observe(&sample(10.0, 1.0));
        // A late cycle (now 10.3) while every input lags with it (newest sample 10.05): the readers
        // did not run, the sensor was not silent — fresh.
        assert_eq!(m.status_judged(10.3, 10.05).health, Health::Ok);
        // On the wall clock alone the same moment is stale (what `status` does).
        assert_eq!(m.status(10.3).faults, vec![FaultKind::Stale]);
        // Other channels talked up to 10.2 while this one stayed silent: stale.
        assert_eq!(m.status_judged(10.3, 10.2).faults, vec![FaultKind::Stale]);
        // Everything silent for longer than the allowance: stale on the wall clock again.
        let late = 10.0 + 0.1 + INPUT_LAG_ALLOW_S + 0.01;
        assert_eq!(m.status_judged(late, 10.0).faults, vec![FaultKind::Stale]);
        assert_eq!(
            m.status_judged(10.0 + INPUT_LAG_ALLOW_S, 10.0).health,
            Health::Ok
        );
    }

    fn limits() -> ChannelLimits {
        ChannelLimits {
            min: -20.0,
            max: 80.0,
            stale_after_s: 2.0,
            max_rate_per_s: Some(1.0),
            stuck_after_s: Some(30.0),
        }
    }

    fn sample(t_s: f64, value: f64) -> Sample {
        Sample {
            channel: retrocomp_bus::ChannelTable::default().resolve("T_spindle_C"),
            t_s,
            value,
            health: Health::Ok,
        }
    }

    #[test]
    fn range_rate_nan_stale_and_stuck_are_caught_and_keep_last_good() {
        let mut m = ChannelMonitor::new(limits());
        m.observe(&sample(0.0, 21.0));
        assert_eq!(m.status(0.0).health, Health::Ok);
        m.observe(&sample(1.0, 150.0));
        assert_eq!(m.status(1.0).faults, vec![FaultKind::OutOfRange]);
        m.observe(&sample(1.5, 25.0)); // +4 °C in 1.5 s > 1 °C/s
        assert_eq!(m.status(1.5).faults, vec![FaultKind::RateOfChange]);
        m.observe(&sample(1.6, f64::NAN));
        let st = m.status(1.6);
        assert_eq!(st.faults, vec![FaultKind::NotFinite]);
        assert_eq!(
            st.value,
            Some(21.0),
            "bad values never replace the last good one"
        );
        assert_eq!(
            m.status(2.5).faults,
            vec![FaultKind::Stale, FaultKind::NotFinite]
        );
        // Stuck: the same bits for 30 s.
        let mut m = ChannelMonitor::new(limits());
        for k in 0..=31 {
            m.observe(&sample(f64::from(k), 22.5));
        }
        assert_eq!(m.status(31.0).faults.first(), Some(&FaultKind::Stuck));
        m.observe(&sample(32.0, 22.6));
        assert!(m.status(32.0).faults.is_empty());
    }

    #[test]
    fn the_same_reading_before_and_after_a_comms_gap_is_not_stuck() {
        // A Modbus RTU slave mute for 3 s: the poller sends `Stale` samples, then the first reading
        // after it equals the last one before (0.1 °C steps: likely on a slow temperature). Nobody saw
        // the value during the gap, so the stuck window starts afresh.
        let mut m = ChannelMonitor::new(ChannelLimits {
            min: 0.0,
            max: 100.0,
            stale_after_s: 0.5,
            max_rate_per_s: None,
            stuck_after_s: Some(1.0),
        });
        for k in 0..=10 {
            m.observe(&sample(
                f64::from(k) * 0.1,
                if k % 2 == 0 { 22.4 } else { 22.5 },
            ));
        }
        for k in 11..40 {
            m.observe(&Sample {
                health: Health::Stale,
                ..sample(f64::from(k) * 0.1, 22.4)
            });
        }
        assert_eq!(m.status(3.9).faults, vec![FaultKind::Stale]);
        m.observe(&sample(4.0, 22.4));
        let st = m.status(4.0);
        assert!(st.faults.is_empty(), "spurious fault after the gap: {st:?}");
        // A silent source (no samples at all, e.g. a CAN node) is a gap too.
        m.observe(&sample(4.1, 22.5));
        m.observe(&sample(6.0, 22.5));
        assert!(m.status(6.0).faults.is_empty());
        // A real stuck reading is still caught, and stays stuck across a later gap.
        for k in 61..=72 {
            m.observe(&sample(f64::from(k) * 0.1, 22.5));
        }
        assert_eq!(m.status(7.2).faults, vec![FaultKind::Stuck]);
        m.observe(&sample(10.0, 22.5));
        // (Stale too: a stuck reading never refreshes the last good value.)
        assert_eq!(
            m.status(10.0).faults,
            vec![FaultKind::Stale, FaultKind::Stuck],
            "no new evidence: still stuck"
        );
    }

    #[test]
    fn fault_logged_once_at_start_and_once_at_clear() {
        let mut log = FaultLog::default();
        let mut starts = 0;
        let mut clears = 0;
        for k in 0..100 {
            let faults: &[FaultKind] = if (20..60).contains(&k) {
                &[FaultKind::Stale]
            } else {
                &[]
            };
            let source = retrocomp_bus::fault::FaultSource::named("T_spindle_C");
            for e in log.update(&source, faults, f64::from(k)) {
                if e.started { starts += 1 } else { clears += 1 }
            }
        }
        assert_eq!((starts, clears), (1, 1));
        assert_eq!(log.active().count(), 0);
    }
}
