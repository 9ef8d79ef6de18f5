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
//! toggling client was acknowledged without being applied: found by tests/gateway_faults_hil.rs.)

use crate::config::{PlcConfig, WordOrder, WordType};

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum RegisterError {
    #[error("register {addr} (count {count}) is outside the PLC window 0..{size}")]
    OutOfWindow {
        addr: u16,
        count: usize,
        size: usize,
    },
    #[error("shift {counts} does not fit the {word:?} register")]
    Overflow { counts: i64, word: WordType },
}

#[derive(Clone, Debug)]
pub struct OriginShiftPlc {
    cfg: PlcConfig,
    regs: Vec<u16>,
    shift_counts: [i64; 3],
    latches: u64,
}

impl OriginShiftPlc {
    pub fn new(cfg: PlcConfig) -> Self {
        let words = if cfg.word == WordType::Int32 { 2 } else { 1 };
        let mut top = cfg.first_register as usize + 3 * words;
        if let Some(h) = &cfg.handshake {
            top = top
                .max(h.strobe_register as usize + 1)
                .max(h.ack_register as usize + 1);
        }
        Self {
            cfg,
            regs: vec![0; top],
            shift_counts: [0; 3],
            latches: 0,
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
        let words = if self.cfg.word == WordType::Int32 {
            2
        } else {
            1
        };
        self.cfg.first_register + (axis * words) as u16
    }

    /// The register words encoding `counts` (what a client writes at [`Self::shift_register`]).
    pub fn encode(&self, counts: i64) -> Result<Vec<u16>, RegisterError> {
        encode_shift(self.cfg.word, self.cfg.word_order, counts)
    }

    /// One PLC scan: latch the shift words (subject to the handshake).
    pub fn scan(&mut self) {
        let latch = match &self.cfg.handshake {
            None => true,
            Some(h) => {
                // Toggle handshake (the gateway's side: src/origin_shift/cycle.rs): every change of
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
            for axis in 0..3 {
                let a = self.shift_register(axis) as usize;
                self.shift_counts[axis] =
                    decode_shift(self.cfg.word, self.cfg.word_order, &self.regs[a..]);
            }
            self.latches += 1;
        }
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

pub fn encode_shift(
    word: WordType,
    order: WordOrder,
    counts: i64,
) -> Result<Vec<u16>, RegisterError> {
    match word {
        WordType::Int16 => {
            let v = i16::try_from(counts).map_err(|_| RegisterError::Overflow { counts, word })?;
            Ok(vec![v as u16])
        }
        WordType::Int32 => {
            let v =
                i32::try_from(counts).map_err(|_| RegisterError::Overflow { counts, word })? as u32;
            let (hi, lo) = ((v >> 16) as u16, v as u16);
            Ok(match order {
                WordOrder::HiLo => vec![hi, lo],
                WordOrder::LoHi => vec![lo, hi],
            })
        }
    }
}

pub fn decode_shift(word: WordType, order: WordOrder, regs: &[u16]) -> i64 {
    match word {
        WordType::Int16 => regs[0] as i16 as i64,
        WordType::Int32 => {
            let (hi, lo) = match order {
                WordOrder::HiLo => (regs[0], regs[1]),
                WordOrder::LoHi => (regs[1], regs[0]),
            };
            (((hi as u32) << 16) | lo as u32) as i32 as i64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::HandshakeConfig;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn int32_words_round_trip_in_both_orders(v in any::<i32>(), lohi in any::<bool>()) {
            let order = if lohi { WordOrder::LoHi } else { WordOrder::HiLo };
            let w = encode_shift(WordType::Int32, order, v as i64).unwrap();
            prop_assert_eq!(decode_shift(WordType::Int32, order, &w), v as i64);
        }

        #[test]
        fn int16_round_trips_and_refuses_overflow(v in -70000i64..70000) {
            match encode_shift(WordType::Int16, WordOrder::HiLo, v) {
                Ok(w) => prop_assert_eq!(decode_shift(WordType::Int16, WordOrder::HiLo, &w), v),
                Err(_) => prop_assert!(!(-32768..=32767).contains(&v)),
            }
        }
    }

    #[test]
    fn hi_lo_layout_is_abcd() {
        assert_eq!(
            encode_shift(WordType::Int32, WordOrder::HiLo, -2).unwrap(),
            vec![0xFFFF, 0xFFFE]
        );
        assert_eq!(
            encode_shift(WordType::Int32, WordOrder::LoHi, 0x0001_0002).unwrap(),
            vec![2, 1]
        );
    }

    #[test]
    fn handshake_latches_once_per_strobe_flip_and_acknowledges() {
        let cfg = PlcConfig {
            word: WordType::Int32,
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
    fn without_handshake_every_scan_latches() {
        let mut plc = OriginShiftPlc::new(PlcConfig::default());
        plc.write(2, &plc.encode(-7).unwrap()).unwrap();
        plc.scan();
        assert_eq!(plc.shift_um(2), -7.0);
        assert_eq!(plc.len(), 3);
    }
}
