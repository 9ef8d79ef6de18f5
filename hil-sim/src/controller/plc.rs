//! The legacy controller's PLC window for origin shifts (Ni 1996 Fig. 3; Fanuc "machine zero point
//! shift" through the PMC). A block of 16-bit holding registers; once per PLC scan the PLC reads the
//! per-axis shift words and adds them to the axis origins, so the slide moves by the shift.
//!
//! Sign: a register value of +n moves the slide by +n·lsb_um (target = nominal + shift). A gateway
//! writes correction = −error. int32 shifts use two registers in the configured word order. With the
//! optional handshake the PLC latches the words only when the strobe changes (toggle handshake: the
//! client writes the words, flips the strobe 0↔1 and waits for ack = strobe; the PLC latches once per
//! flip and copies the strobe into the ack), so a half-written pair is never applied and every flip is
//! exactly one latch. (An earlier version latched on the rising edge only, so every other write of a
//! toggling client was acknowledged without being applied: found by tests/real_peers/gateway_faults_hil.rs.)
//!
//! Optional heartbeat watchdog (`[plc.watchdog]`, the rule of docs/gateway.md): armed once the
//! heartbeat register has changed; when it then stays unchanged for `timeout_s` the PLC trips: it
//! stops latching the client's words and moves each applied shift towards 0 at `ramp_um_per_s`
//! (whole counts, rounded towards 0, so it never moves faster), writing what it applies back into the
//! shift registers each scan so a client that comes back reads what the PLC holds. A heartbeat
//! change re-arms it (checked first in the scan, before any latch). Every change of the applied
//! shift and every trip / re-arm / at-zero edge is an [`PlcEvent`] for the observers' log.

use crate::config::{DataType, PlcConfig, WordOrder};
use retrocomp_bus::modbus::{decode_raw, encode_raw};

/// What changed in a scan (for `plc_latches.csv`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlcEventKind {
    /// The client's words were latched and the applied shift changed.
    Latch,
    /// The watchdog moved the applied shift towards 0.
    Ramp,
    /// The heartbeat stopped for `timeout_s`: the watchdog took over.
    Trip,
    /// The tripped watchdog has brought every shift to 0.
    AtZero,
    /// The heartbeat changed again: the client's words are latched again.
    Rearm,
}

impl PlcEventKind {
    pub fn name(self) -> &'static str {
        match self {
            PlcEventKind::Latch => "latch",
            PlcEventKind::Ramp => "ramp",
            PlcEventKind::Trip => "trip",
            PlcEventKind::AtZero => "at_zero",
            PlcEventKind::Rearm => "rearm",
        }
    }
}

/// One event with the applied shifts after it (counts).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PlcEvent {
    pub kind: PlcEventKind,
    pub shift_counts: [i64; 3],
}

#[derive(Clone, Debug, Default)]
struct Watchdog {
    last_heartbeat: u16,
    armed: bool,
    unchanged_scans: u64,
    tripped: bool,
    /// The ramp's exact position per axis while tripped, µm.
    ramp_um: [f64; 3],
    at_zero_told: bool,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RegisterError {
    #[error("register {addr} (count {count}) is outside the PLC window 0..{size}")]
    OutOfWindow {
        addr: u16,
        count: usize,
        size: usize,
    },
    #[error("shift {counts} does not fit the {word:?} register")]
    Overflow { counts: i64, word: DataType },
}

#[derive(Clone, Debug)]
pub struct OriginShiftPlc {
    cfg: PlcConfig,
    regs: Vec<u16>,
    shift_counts: [i64; 3],
    latches: u64,
    watchdog: Watchdog,
    events: Vec<PlcEvent>,
}

impl OriginShiftPlc {
    pub fn new(cfg: PlcConfig) -> Self {
        let words = usize::from(cfg.word.words());
        let mut top = cfg.first_register as usize + 3 * words;
        if let Some(h) = &cfg.handshake {
            top = top
                .max(h.strobe_register as usize + 1)
                .max(h.ack_register as usize + 1);
        }
        if let Some(w) = &cfg.watchdog {
            top = top.max(w.heartbeat_register as usize + 1);
        }
        Self {
            cfg,
            regs: vec![0; top],
            shift_counts: [0; 3],
            latches: 0,
            watchdog: Watchdog::default(),
            events: Vec::new(),
        }
    }

    pub fn config(&self) -> &PlcConfig {
        &self.cfg
    }

    /// Number of holding registers in the window (addresses 0..len).
    pub fn len(&self) -> usize {
        self.regs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.regs.is_empty()
    }

    pub fn read(&self, addr: u16, count: usize) -> Result<&[u16], RegisterError> {
        let a = addr as usize;
        self.regs
            .get(a..a + count)
            .ok_or(RegisterError::OutOfWindow {
                addr,
                count,
                size: self.regs.len(),
            })
    }

    pub fn write(&mut self, addr: u16, words: &[u16]) -> Result<(), RegisterError> {
        let a = addr as usize;
        let size = self.regs.len();
        let dst = self
            .regs
            .get_mut(a..a + words.len())
            .ok_or(RegisterError::OutOfWindow {
                addr,
                count: words.len(),
                size,
            })?;
        dst.copy_from_slice(words);
        Ok(())
    }

    /// Address of an axis' shift word(s).
    pub fn shift_register(&self, axis: usize) -> u16 {
        let words = usize::from(self.cfg.word.words());
        self.cfg.first_register + u16::try_from(axis * words).expect("3 axes of ≤ 4 words")
    }

    /// The register words encoding `counts` (what a client writes at [`Self::shift_register`]).
    pub fn encode(&self, counts: i64) -> Result<Vec<u16>, RegisterError> {
        encode_shift(self.cfg.word, self.cfg.word_order, counts)
    }

    /// One PLC scan: the watchdog first, then latch the shift words (subject to the handshake).
    pub fn scan(&mut self) {
        if self.watchdog_scan() {
            return;
        }
        let latch = match &self.cfg.handshake {
            None => true,
            Some(h) => {
                // Toggle handshake (the gateway's side: crates/gateway/src/sinks/origin_shift/cycle.rs): every change of
                // the strobe is one request; the PLC latches and mirrors the strobe into the ack.
                let strobe = self.regs[h.strobe_register as usize];
                let ack = self.regs[h.ack_register as usize];
                if strobe != ack {
                    self.regs[h.ack_register as usize] = strobe;
                    true
                } else {
                    false
                }
            }
        };
        if latch {
            let before = self.shift_counts;
            for axis in 0..3 {
                let a = self.shift_register(axis) as usize;
                self.shift_counts[axis] =
                    decode_shift(self.cfg.word, self.cfg.word_order, &self.regs[a..]);
            }
            self.latches += 1;
            if self.shift_counts != before {
                self.event(PlcEventKind::Latch);
            }
        }
    }

    fn event(&mut self, kind: PlcEventKind) {
        self.events.push(PlcEvent {
            kind,
            shift_counts: self.shift_counts,
        });
    }

    /// The watchdog's part of a scan; true while tripped (the scan latches nothing then).
    fn watchdog_scan(&mut self) -> bool {
        let Some(cfg) = self.cfg.watchdog.clone() else {
            return false;
        };
        let hb = self.regs[cfg.heartbeat_register as usize];
        let timeout_scans = retrocomp_analysis::numeric::trunc_u64(
            (cfg.timeout_s / self.cfg.scan_s - 1e-9).ceil().max(1.0),
        );
        let w = &mut self.watchdog;
        if hb != w.last_heartbeat {
            w.last_heartbeat = hb;
            w.armed = true;
            w.unchanged_scans = 0;
            if w.tripped {
                w.tripped = false;
                self.event(PlcEventKind::Rearm);
            }
            return false;
        }
        if !w.armed {
            return false;
        }
        w.unchanged_scans += 1;
        if !w.tripped {
            if w.unchanged_scans < timeout_scans {
                return false;
            }
            w.tripped = true;
            w.at_zero_told = false;
            w.ramp_um = self.shift_counts.map(|c| c as f64 * self.cfg.lsb_um);
            self.event(PlcEventKind::Trip);
        }
        let step_um = cfg.ramp_um_per_s * self.cfg.scan_s;
        let before = self.shift_counts;
        for axis in 0..3 {
            let r = &mut self.watchdog.ramp_um[axis];
            *r = if r.abs() <= step_um {
                0.0
            } else {
                *r - step_um * r.signum()
            };
            // Towards 0: the applied shift never runs ahead of the ramp.
            self.shift_counts[axis] = retrocomp_analysis::numeric::trunc_i64(*r / self.cfg.lsb_um);
        }
        // The shift registers hold what is applied: a client that comes back reads it.
        for axis in 0..3 {
            let a = self.shift_register(axis) as usize;
            let words = encode_shift(self.cfg.word, self.cfg.word_order, self.shift_counts[axis])
                .expect("a ramp towards 0 stays in the register's range");
            self.regs[a..a + words.len()].copy_from_slice(&words);
        }
        if self.shift_counts != before {
            self.event(PlcEventKind::Ramp);
        }
        if self.shift_counts == [0; 3] && !self.watchdog.at_zero_told {
            self.watchdog.at_zero_told = true;
            self.event(PlcEventKind::AtZero);
        }
        true
    }

    /// True while the watchdog has taken the shifts over.
    pub fn watchdog_tripped(&self) -> bool {
        self.watchdog.tripped
    }

    /// The events since the last call.
    pub fn take_events(&mut self) -> Vec<PlcEvent> {
        std::mem::take(&mut self.events)
    }

    /// Applied (latched) shift of an axis.
    pub fn shift_um(&self, axis: usize) -> f64 {
        self.shift_counts[axis] as f64 * self.cfg.lsb_um
    }

    pub fn shift_counts(&self) -> [i64; 3] {
        self.shift_counts
    }

    /// How many scans latched new values.
    pub fn latches(&self) -> u64 {
        self.latches
    }
}

/// The register words of a shift of `counts`, in the window's type and word order.
pub(crate) fn encode_shift(
    word: DataType,
    order: WordOrder,
    counts: i64,
) -> Result<Vec<u16>, RegisterError> {
    let (w, n) =
        encode_raw(counts as f64, word, order).ok_or(RegisterError::Overflow { counts, word })?;
    Ok(w[..n].to_vec())
}

/// The shift counts held in `regs` (at least the type's word count).
pub(crate) fn decode_shift(word: DataType, order: WordOrder, regs: &[u16]) -> i64 {
    let n = usize::from(word.words());
    decode_raw(&regs[..n], word, order).map_or(0, retrocomp_analysis::numeric::round_i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::HandshakeConfig;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn int32_words_round_trip_in_both_orders(v in any::<i32>(), lohi in any::<bool>()) {
            let order = if lohi { WordOrder::LowFirst } else { WordOrder::HighFirst };
            let w = encode_shift(DataType::Int32, order, i64::from(v)).unwrap();
            prop_assert_eq!(decode_shift(DataType::Int32, order, &w), i64::from(v));
        }

        #[test]
        fn int16_round_trips_and_refuses_overflow(v in -70000i64..70000) {
            match encode_shift(DataType::Int16, WordOrder::HighFirst, v) {
                Ok(w) => prop_assert_eq!(decode_shift(DataType::Int16, WordOrder::HighFirst, &w), v),
                Err(_) => prop_assert!(!(-32768..=32767).contains(&v)),
            }
        }
    }

    #[test]
    fn high_first_layout_is_abcd() {
        assert_eq!(
            encode_shift(DataType::Int32, WordOrder::HighFirst, -2).unwrap(),
            vec![0xFFFF, 0xFFFE]
        );
        assert_eq!(
            encode_shift(DataType::Int32, WordOrder::LowFirst, 0x0001_0002).unwrap(),
            vec![2, 1]
        );
    }

    #[test]
    fn handshake_latches_once_per_strobe_flip_and_acknowledges() {
        let cfg = PlcConfig {
            word: DataType::Int32,
            first_register: 10,
            handshake: Some(HandshakeConfig {
                strobe_register: 0,
                ack_register: 1,
            }),
            lsb_um: 0.5,
            ..Default::default()
        };
        let mut plc = OriginShiftPlc::new(cfg);
        let y = plc.shift_register(1);
        assert_eq!(y, 12);
        plc.write(y, &plc.encode(-40).unwrap()).unwrap();
        plc.scan();
        assert_eq!(plc.shift_um(1), 0.0, "no strobe, no latch");
        plc.write(0, &[1]).unwrap();
        plc.scan();
        assert_eq!(plc.shift_um(1), -20.0);
        assert_eq!(plc.read(1, 1).unwrap(), &[1], "ack mirrors the strobe");
        plc.write(y, &plc.encode(100).unwrap()).unwrap();
        plc.scan();
        assert_eq!(
            plc.shift_um(1),
            -20.0,
            "strobe unchanged since the last latch: no second latch"
        );
        plc.write(0, &[0]).unwrap();
        plc.scan();
        assert_eq!(plc.shift_um(1), 50.0, "the flip back to 0 is a request too");
        assert_eq!(plc.read(1, 1).unwrap(), &[0], "ack mirrors the strobe");
        plc.scan();
        assert_eq!(plc.latches(), 2, "one latch per flip, none per scan");
        assert!(matches!(
            plc.write(16, &[0, 0]),
            Err(RegisterError::OutOfWindow { .. })
        ));
    }

    #[test]
    fn the_watchdog_ramps_out_at_its_rate_and_rearms_on_a_heartbeat_change() {
        use crate::config::WatchdogConfig;
        // 10 ms scans, 0.5 µm counts, trip after 50 ms, ramp 20 µm/s = 0.2 µm per scan.
        let cfg = PlcConfig {
            word: DataType::Int32,
            lsb_um: 0.5,
            watchdog: Some(WatchdogConfig {
                heartbeat_register: 6,
                timeout_s: 0.05,
                ramp_um_per_s: 20.0,
            }),
            ..Default::default()
        };
        let mut plc = OriginShiftPlc::new(cfg);
        assert_eq!(plc.len(), 7);
        for _ in 0..20 {
            plc.scan();
        }
        assert!(
            !plc.watchdog_tripped(),
            "not armed before the first heartbeat"
        );
        plc.write(0, &plc.encode(20).unwrap()).unwrap(); // x = 10 µm
        plc.write(4, &plc.encode(-3).unwrap()).unwrap(); // z = -1.5 µm
        plc.write(6, &[1]).unwrap();
        plc.scan();
        assert_eq!(plc.shift_um(0), 10.0);
        assert_eq!(plc.take_events()[0].kind, PlcEventKind::Latch);
        for _ in 0..4 {
            plc.scan();
        }
        assert!(!plc.watchdog_tripped(), "4 unchanged scans < 50 ms");
        plc.scan();
        assert!(plc.watchdog_tripped());
        // A client write while tripped is not latched and is overwritten.
        plc.write(0, &plc.encode(80).unwrap()).unwrap();
        let mut scans = 1;
        let mut last = plc.shift_um(0);
        while plc.shift_counts() != [0; 3] {
            plc.scan();
            scans += 1;
            let now = plc.shift_um(0);
            assert!(now <= last && last - now <= 0.5, "{last} → {now}");
            assert_eq!(
                decode_shift(
                    DataType::Int32,
                    WordOrder::HighFirst,
                    plc.read(0, 2).unwrap()
                ) as f64
                    * 0.5,
                now,
                "registers hold what is applied"
            );
            last = now;
            assert!(scans < 100);
        }
        // 10 µm at 0.2 µm per scan: below one count (0.5 µm) after 48 scans.
        assert!((47..=49).contains(&scans), "{scans} scans");
        let kinds: Vec<PlcEventKind> = plc.take_events().iter().map(|e| e.kind).collect();
        assert_eq!(kinds.first(), Some(&PlcEventKind::Trip));
        assert_eq!(kinds.last(), Some(&PlcEventKind::AtZero));
        let ramps = kinds.iter().filter(|k| **k == PlcEventKind::Ramp).count();
        assert!(
            (20..=23).contains(&ramps),
            "x alone steps 20 counts: {ramps}"
        );
        // The heartbeat changes: re-armed in that scan, and the words (now the PLC's 0) latched.
        plc.write(6, &[2]).unwrap();
        plc.write(0, &plc.encode(1).unwrap()).unwrap();
        plc.scan();
        assert!(!plc.watchdog_tripped());
        assert_eq!(plc.take_events()[0].kind, PlcEventKind::Rearm);
        plc.scan();
        assert_eq!(plc.shift_um(0), 0.5);
    }

    #[test]
    fn without_handshake_every_scan_latches() {
        let mut plc = OriginShiftPlc::new(PlcConfig::default());
        plc.write(2, &plc.encode(-7).unwrap()).unwrap();
        plc.scan();
        assert_eq!(plc.shift_um(2), -7.0);
        assert_eq!(plc.len(), 3);
    }
}
