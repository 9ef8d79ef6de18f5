//! The origin-shift sink's core, sans-IO: one write period is read → guard → write cycle.
//!
//! 0. With a `heartbeat_address`: write the heartbeat (+1 wrapping u16; the first period writes 1)
//!    FIRST, so a controller whose watchdog rule has ramped the correction out re-arms before the
//!    box reads what it now holds (no ramp step can fall between that read and the box's write).
//!    No value or strobe goes out more than `heartbeat_timeout_ms / 2` after the period's heartbeat:
//!    a box frozen mid-period (SIGSTOP, a stalled host) abandons the period and reads again.
//! 1. Read what the controller holds: every value register, and with a handshake the strobe and ack
//!    registers (adjacent registers in one FC03). Every period, so a controller restart, a foreign
//!    write or a lost connection is seen before the next value goes out.
//! 2. The strobe is resynchronised from the controller: the next flip is the opposite of the strobe
//!    register AS READ (never a value the box remembers from before a dropped connection). If the
//!    strobe differs from the ack, the controller has a latch pending: nothing is written this period.
//! 3. [`WriteGuard`] turns each wanted value into one within the clamp and the per-write cap of what
//!    the controller may be applying, or refuses the axis (beyond the clamp, uncertain).
//! 4. The accepted values go out through a [`WriteCycle`] (values, strobe, ack, read-back).
//!
//! Ramp-out ([`SinkCore::begin_ramp_out`], on SIGTERM/SIGINT with `on_stop = "ramp_out"`): from then
//! on every axis wants 0, so the guard moves each by at most the per-write cap per period; done
//! ([`SinkCore::is_ramped_out`]) once a period's read shows 0 on every axis with no latch pending.
//!
//! The shell (`client.rs` + the gateway's sink task) runs the [`Action`]s and feeds the replies back;
//! time is passed in (s). Failures are reported as fault flags the shell turns into fault episodes.
//! Units: µm.

use super::cycle::{Action, Outcome, Reply, WriteCycle};
use super::map::{RegisterMap, Words, WriteBlock, decode_value};
pub use crate::sinks::guard::SinkFaults;
use crate::sinks::guard::{AxisLimits, Verdict, WriteGuard};
use retrocomp_model::Axis;

/// What the sink core needs per axis (clamp and per-write cap), in the map's axis order.
pub use crate::sinks::guard::AxisLimits as SinkAxis;

#[derive(Clone, Debug)]
enum Phase {
    Idle,
    /// Writing the heartbeat (the period's first request).
    Heartbeat,
    /// Reading span `i` of `reads`.
    Reading(usize),
    Writing(WriteCycle),
}

/// One FC03 span: address, count.
type Span = (u16, u16);

#[derive(Clone, Debug)]
pub struct SinkCore {
    map: RegisterMap,
    axes: Vec<SinkAxis>,
    guard: WriteGuard,
    reads: Vec<Span>,
    /// Words read this period, by address (value registers, strobe, ack).
    words: Vec<(u16, u16)>,
    phase: Phase,
    wants: Vec<f64>,
    /// Axis index and value of the writes in the running cycle.
    planned: Vec<(usize, f64)>,
    /// This period's guarded values and their register blocks: buffers kept across periods (the
    /// blocks go into the write cycle and come back), so a period allocates nothing.
    values: Vec<(Axis, f64)>,
    blocks: Vec<WriteBlock>,
    reseeds: Vec<(Axis, f64)>,
    /// Each map axis' identity (map order), resolved at construction; None for a name that is not
    /// x, y or z (never wanted, never reseeded).
    ids: Vec<Option<Axis>>,
    faults: SinkFaults,
    /// Last heartbeat value written (0 before the first period).
    heartbeat: u16,
    /// When this period began (its heartbeat went out), s.
    period_start_s: f64,
    /// Longest time from a period's heartbeat to its last value/strobe write, s.
    max_period_age_s: Option<f64>,
    ramping_out: bool,
    /// This period's read showed 0 on every axis and no pending latch.
    at_zero: bool,
    pub writes_ok: u64,
    pub writes_failed: u64,
    pub last_error: Option<String>,
}

impl SinkCore {
    /// `axes` must name every axis of the map (its order is the map's).
    pub fn new(map: RegisterMap, axes: Vec<SinkAxis>) -> Self {
        let guard = WriteGuard::new(
            map.axes
                .iter()
                .map(|r| AxisLimits::of(&axes, &r.axis, r.lsb_um)),
        );
        let axes = map
            .axes
            .iter()
            .map(|r| {
                axes.iter()
                    .find(|a| a.axis == r.axis)
                    .cloned()
                    .unwrap_or(SinkAxis {
                        axis: r.axis.clone(),
                        max_correction_um: 0.0,
                        max_change_um_per_write: 0.0,
                    })
            })
            .collect::<Vec<_>>();
        let reads = read_spans(&map);
        let read_words = reads.iter().map(|r| r.1 as usize).sum();
        let n = axes.len();
        let max_period_age_s = match (map.heartbeat_address, map.heartbeat_timeout_ms) {
            (Some(_), Some(t)) => Some(t as f64 / 2e3),
            _ => None,
        };
        Self {
            heartbeat: 0,
            period_start_s: 0.0,
            max_period_age_s,
            ramping_out: false,
            at_zero: false,
            map,
            guard,
            reads,
            words: Vec::with_capacity(read_words),
            phase: Phase::Idle,
            wants: vec![0.0; n],
            planned: Vec::with_capacity(n),
            values: Vec::with_capacity(n),
            blocks: Vec::new(),
            reseeds: Vec::new(),
            faults: SinkFaults::none(n),
            ids: axes.iter().map(|a| Axis::from_name(&a.axis)).collect(),
            axes,
            writes_ok: 0,
            writes_failed: 0,
            last_error: None,
        }
    }

    pub fn map(&self) -> &RegisterMap {
        &self.map
    }

    pub fn axes(&self) -> &[SinkAxis] {
        &self.axes
    }

    pub fn faults(&self) -> &SinkFaults {
        &self.faults
    }

    /// What the controller's registers held at the last read, per axis (map order), µm.
    pub fn held_um(&self) -> impl Iterator<Item = (&str, Option<f64>)> {
        self.axes
            .iter()
            .enumerate()
            .map(|(i, a)| (a.axis.as_str(), self.guard.read_um(i)))
    }

    /// Values the controller changed behind the box's back (restart, operator, another writer)
    /// since the last call: the engine should continue from them (only in-clamp values are given).
    pub fn take_reseeds(&mut self) -> Vec<(Axis, f64)> {
        std::mem::take(&mut self.reseeds)
    }

    /// [`Self::begin_at`] at time 0 (for maps without a heartbeat, where the period's age is not
    /// checked).
    pub fn begin(&mut self, wants_um: &[(Axis, f64)]) -> Action {
        self.begin_at(wants_um, 0.0)
    }

    /// Start a write period at `now_s` for these wanted corrections (axis name, µm; axes not in the
    /// map are ignored, map axes not given keep the controller's value; every axis wants 0 once
    /// ramping out). Returns the first request: the heartbeat write, or the read.
    pub fn begin_at(&mut self, wants_um: &[(Axis, f64)], now_s: f64) -> Action {
        for (i, id) in self.ids.iter().enumerate() {
            self.wants[i] = if self.ramping_out {
                0.0
            } else {
                wants_um
                    .iter()
                    .find(|(a, _)| Some(*a) == *id)
                    .map_or(f64::NAN, |(_, v)| *v)
            };
        }
        self.words.clear();
        self.planned.clear();
        self.at_zero = false;
        self.period_start_s = now_s;
        if let Some(address) = self.map.heartbeat_address {
            self.heartbeat = self.heartbeat.wrapping_add(1);
            self.phase = Phase::Heartbeat;
            return Action::Write(WriteBlock {
                address,
                words: Words::from_slice(&[self.heartbeat]),
            });
        }
        self.read(0, now_s)
    }

    /// The last heartbeat value written (0 before the first period).
    pub fn heartbeat(&self) -> u16 {
        self.heartbeat
    }

    /// From now on every axis wants 0 (the stop ramp-out).
    pub fn begin_ramp_out(&mut self) {
        self.ramping_out = true;
    }

    pub fn is_ramping_out(&self) -> bool {
        self.ramping_out
    }

    /// Ramping out and the last period's read showed 0 on every axis with no latch pending.
    pub fn is_ramped_out(&self) -> bool {
        self.ramping_out && self.at_zero
    }

    /// True when a value or strobe write would go out too long after the period's heartbeat: the
    /// controller's watchdog may have ramped out since the read this period's values are based on.
    fn too_late(&self, now_s: f64) -> bool {
        self.max_period_age_s
            .is_some_and(|max| now_s - self.period_start_s > max)
    }

    /// Abandon the period before a late write (the values already sent stay unconfirmed).
    fn abandon_late(&mut self, now_s: f64) -> Action {
        let o = Outcome::RequestFailed {
            step: "late",
            address: self.map.heartbeat_address.unwrap_or(0),
            reason: format!(
                "{:.0} ms after the period's heartbeat (limit {:.0} ms, half the controller's heartbeat timeout): not writing on a stale read",
                (now_s - self.period_start_s) * 1e3,
                self.max_period_age_s.unwrap_or(0.0) * 1e3
            ),
        };
        self.phase = Phase::Idle;
        self.finish_cycle(&o);
        Action::Done(o)
    }

    /// The connection failed before any request of this period went out.
    pub fn not_connected(&mut self, reason: &str) {
        self.phase = Phase::Idle;
        self.failed(reason.to_string());
    }

    fn read(&mut self, i: usize, now_s: f64) -> Action {
        let (address, count) = self.reads[i];
        self.phase = Phase::Reading(i);
        Action::Read {
            address,
            count,
            not_before_s: now_s,
        }
    }

    fn failed(&mut self, reason: String) {
        self.writes_failed += 1;
        self.faults.write_failed = true;
        self.last_error = Some(reason);
    }

    fn word(&self, address: u16) -> Option<u16> {
        self.words
            .iter()
            .find(|(a, _)| *a == address)
            .map(|(_, w)| *w)
    }

    /// Feed the reply to the last request; get the next one, or `Action::Done` at the end of the
    /// period (the outcome of the write cycle, or `Ok` when nothing needed writing).
    pub fn handle_reply(&mut self, reply: Reply, now_s: f64) -> Action {
        match std::mem::replace(&mut self.phase, Phase::Idle) {
            Phase::Idle => Action::Done(Outcome::Ok),
            Phase::Heartbeat => match reply {
                Reply::Written => self.read(0, now_s),
                other => {
                    let reason = match other {
                        Reply::Failed(r) => r,
                        r => format!("unexpected reply {r:?}"),
                    };
                    let o = Outcome::RequestFailed {
                        step: "heartbeat",
                        address: self.map.heartbeat_address.unwrap_or(0),
                        reason,
                    };
                    self.failed(format!("{o:?}"));
                    Action::Done(o)
                }
            },
            Phase::Reading(i) => {
                let (address, count) = self.reads[i];
                match reply {
                    Reply::Read(w) if w.len() == usize::from(count) => {
                        // k < count (≤ 125 per Modbus read): `address + k` as the map laid it out.
                        self.words.extend(
                            w.iter()
                                .zip(0u16..)
                                .map(|(v, k)| (address.wrapping_add(k), *v)),
                        );
                    }
                    other => {
                        let reason = match other {
                            Reply::Failed(r) => r,
                            r => format!("unexpected reply {r:?}"),
                        };
                        let o = Outcome::RequestFailed {
                            step: "read",
                            address,
                            reason: reason.clone(),
                        };
                        self.failed(format!("{o:?}"));
                        return Action::Done(o);
                    }
                }
                if i + 1 < self.reads.len() {
                    return self.read(i + 1, now_s);
                }
                self.plan(now_s)
            }
            Phase::Writing(mut cycle) => {
                let next = cycle.handle_reply(reply, now_s);
                if matches!(next, Action::Write(_)) && self.too_late(now_s) {
                    self.blocks = cycle.into_blocks();
                    return self.abandon_late(now_s);
                }
                if let Action::Done(o) = &next {
                    self.blocks = cycle.into_blocks();
                    self.finish_cycle(o);
                } else {
                    self.phase = Phase::Writing(cycle);
                }
                next
            }
        }
    }

    /// Everything read: judge the controller's values, then start the write cycle.
    fn plan(&mut self, now_s: f64) -> Action {
        for i in 0..self.axes.len() {
            let r = &self.map.axes[i];
            let mut words = Words::new();
            for k in 0..r.data_type.words() {
                words.extend(self.word(r.address + k));
            }
            if words.len() != r.data_type.words() as usize {
                continue;
            }
            let Ok(held) = decode_value(r, &words) else {
                continue;
            };
            let before = self.guard.may_hold(i);
            self.guard.observe_read(i, held);
            // A value outside what we may have left there: someone else changed it (controller
            // restart, operator, another writer). The engine continues from it if it is in range.
            let max = self.axes[i].max_correction_um;
            if before.is_some_and(|(lo, hi)| held < lo - r.lsb_um || held > hi + r.lsb_um)
                && held.abs() <= max + r.lsb_um * 0.5
                && let Some(axis) = self.ids[i]
            {
                self.reseeds.push((axis, held.clamp(-max, max)));
            }
        }
        let mut strobe = None;
        if let Some(h) = &self.map.handshake {
            let (s, a) = (self.word(h.strobe_address), self.word(h.ack_address));
            if s != a {
                self.failed(format!(
                    "controller has a latch pending (strobe {s:?}, ack {a:?}): not writing"
                ));
                return Action::Done(Outcome::AckTimeout {
                    strobe: s.unwrap_or(0),
                    last_ack: a,
                });
            }
            strobe = Some(WriteCycle::next_strobe(s.unwrap_or(0)));
        }
        self.at_zero = (0..self.axes.len()).all(|i| {
            self.guard
                .read_um(i)
                .is_some_and(|v| v.abs() < self.map.axes[i].lsb_um * 0.5)
        });
        self.values.clear();
        for i in 0..self.axes.len() {
            let verdict = self.guard.check(i, self.wants[i]);
            self.faults.beyond_clamp[i] = matches!(verdict, Verdict::BeyondClamp { .. });
            self.faults.uncertain[i] = matches!(verdict, Verdict::Uncertain { .. });
            match verdict {
                Verdict::Write(v) => {
                    self.planned.push((i, v));
                    if let Some(axis) = self.ids[i] {
                        self.values.push((axis, v));
                    }
                }
                Verdict::Uncertain { .. } => self.guard.forget_unconfirmed(i),
                Verdict::Unknown | Verdict::BeyondClamp { .. } => {}
            }
        }
        if self.values.is_empty() {
            return Action::Done(Outcome::Ok);
        }
        let mut blocks = std::mem::take(&mut self.blocks);
        if let Err(e) = self.map.encode_into(&self.values, &mut blocks) {
            self.blocks = blocks;
            self.planned.clear();
            self.failed(e.to_string());
            return Action::Done(Outcome::RequestFailed {
                step: "encode",
                address: 0,
                reason: e.to_string(),
            });
        }
        if self.too_late(now_s) {
            self.blocks = blocks;
            self.planned.clear(); // nothing of this period went out
            return self.abandon_late(now_s);
        }
        let (cycle, first) = WriteCycle::start_at(&self.map, blocks, strobe.unwrap_or(0), now_s);
        if let Action::Done(o) = &first {
            self.blocks = cycle.into_blocks();
            self.finish_cycle(o);
        } else {
            self.phase = Phase::Writing(cycle);
        }
        first
    }

    fn finish_cycle(&mut self, o: &Outcome) {
        let confirmed = *o == Outcome::Ok;
        for &(i, v) in &self.planned {
            self.guard.wrote(i, v, confirmed);
        }
        self.planned.clear();
        if confirmed {
            self.writes_ok += 1;
            self.faults.write_failed = false;
            self.last_error = None;
        } else {
            self.failed(format!("{o:?}"));
        }
    }
}

/// FC03 spans covering every value register and the handshake registers; adjacent registers share
/// one request (at most 125 words, the FC03 limit).
fn read_spans(map: &RegisterMap) -> Vec<Span> {
    let mut regs: Vec<(u16, u16)> = map
        .axes
        .iter()
        .map(|r| (r.address, r.data_type.words()))
        .collect();
    if let Some(h) = &map.handshake {
        regs.push((h.strobe_address, 1));
        regs.push((h.ack_address, 1));
    }
    regs.sort_unstable();
    let mut spans: Vec<Span> = Vec::new();
    for (a, n) in regs {
        match spans.last_mut() {
            Some((sa, sn)) if u32::from(*sa) + u32::from(*sn) == u32::from(a) && *sn + n <= 125 => {
                *sn += n;
            }
            _ => spans.push((a, n)),
        }
    }
    spans
}

#[cfg(test)]
#[path = "sink_watchdog_tests.rs"]
mod watchdog_tests;

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> RegisterMap {
        toml::from_str(
            "[[axis]]\naxis = \"x\"\naddress = 0\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
             [[axis]]\naxis = \"y\"\naddress = 2\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
             [handshake]\nstrobe_address = 4\nack_address = 5\ntimeout_ms = 100\npoll_ms = 10\n",
        )
        .unwrap()
    }

    fn core() -> SinkCore {
        let ax = |a: &str| SinkAxis {
            axis: a.into(),
            max_correction_um: 60.0,
            max_change_um_per_write: 0.5,
        };
        SinkCore::new(map(), vec![ax("x"), ax("y")])
    }

    fn wants(x: f64, y: f64) -> Vec<(Axis, f64)> {
        vec![(Axis::X, x), (Axis::Y, y)]
    }

    #[test]
    fn one_read_covers_adjacent_registers_and_the_strobe_follows_the_controller() {
        let mut c = core();
        assert_eq!(
            c.begin(&wants(5.0, -5.0)),
            Action::Read {
                address: 0,
                count: 6,
                not_before_s: 0.0
            }
        );
        // x holds 1.0 µm (10 counts), y 0; strobe = ack = 1: the next flip is to 0.
        let a = c.handle_reply(Reply::Read(vec![0, 10, 0, 0, 1, 1].into()), 0.0);
        let Action::Write(b) = a else { panic!("{a:?}") };
        assert_eq!(b.address, 0);
        assert_eq!(b.words[..], [0, 15, 0xFFFF, 0xFFFB], "1.5 and -0.5 µm");
        assert_eq!(
            c.handle_reply(Reply::Written, 0.0),
            Action::Write(WriteBlock {
                address: 4,
                words: vec![0].into()
            })
        );
    }

    #[test]
    fn a_controller_beyond_the_clamp_is_not_written_and_is_a_fault() {
        let mut c = core();
        c.begin(&wants(0.0, 0.0));
        // x holds 100 µm (1000 counts): beyond the 60 µm clamp; y is written.
        let a = c.handle_reply(Reply::Read(vec![0, 1000, 0, 0, 0, 0].into()), 0.0);
        let Action::Write(b) = a else { panic!("{a:?}") };
        assert_eq!(b.address, 2, "only y");
        assert_eq!(c.faults().beyond_clamp, vec![true, false]);
        assert_eq!(c.held_um().next(), Some(("x", Some(100.0))));
    }

    #[test]
    fn a_pending_latch_means_no_write() {
        let mut c = core();
        c.begin(&wants(0.0, 0.0));
        let a = c.handle_reply(Reply::Read(vec![0, 0, 0, 0, 1, 0].into()), 0.0);
        assert!(
            matches!(a, Action::Done(Outcome::AckTimeout { .. })),
            "{a:?}"
        );
        assert!(c.faults().write_failed);
    }
}
