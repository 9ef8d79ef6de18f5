//! Register map of the controller's origin-shift (work-offset) registers, from TOML, and the encoding
//! of per-axis corrections into register words.
//!
//! Conventions:
//! - Addresses are 0-based holding-register addresses as they go on the wire (mbpoll's `-r` is 1-based).
//! - `lsb_um`: µm per register count (e.g. 0.1 µm).
//! - `sign`: register value = `sign × correction_um / lsb_um`. `sign = 1` when the controller ADDS the
//!   register to its axis origin (the register then holds the correction = −error); `sign = -1` when the
//!   PLC expects the error itself and subtracts it (Siemens: "positive compensation moves the axis
//!   negative").
//! - `kind = "int16" | "int32"` (the data type; a correction is signed). 32-bit values span two
//!   registers; `word_order = "high_first"` (ABCD) or `"low_first"` (CDAB). Types, word order and the
//!   word split are the workspace's one Modbus vocabulary (`bus::modbus::words`).
//!   Both words always go out in ONE FC16 request so the controller never sees half an update.
//! - Allow-list: the only writable addresses are the value registers, the strobe register and the
//!   heartbeat register configured here; [`RegisterMap::check_write`] refuses anything else.
//! - `heartbeat_address` (same key and rule as the server sink's map, `server_core.rs`): a u16 the box
//!   writes at the start of every write period, +1 wrapping (the first period writes 1), so the
//!   controller's watchdog rule can remove the correction when it stops changing (docs/gateway.md).
//!   `heartbeat_timeout_ms` is the timeout the controller's rule is configured with: the box never
//!   sends a value or strobe more than half of it after its period's heartbeat (so a box frozen
//!   mid-period cannot land a stale value after the controller has ramped out).

use serde::{Deserialize, Serialize};

pub use retrocomp_bus::modbus::{DataType, WordOrder};
use retrocomp_bus::modbus::{decode_raw, encode_raw};
use retrocomp_model::Axis;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisRegister {
    /// Axis name (`x`, `y`, `z`).
    pub axis: String,
    pub address: u16,
    /// The data type (TOML key `kind`, as shipped).
    #[serde(rename = "kind")]
    pub data_type: DataType,
    #[serde(default)]
    pub word_order: WordOrder,
    /// µm per count.
    pub lsb_um: f64,
    /// +1: register = correction; −1: register = −correction (= error).
    pub sign: i8,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Handshake {
    /// Register the box toggles (0/1) after writing the values.
    pub strobe_address: u16,
    /// Register the controller sets equal to the strobe once it has taken the values.
    pub ack_address: u16,
    /// Give up waiting for the ack after this long, ms.
    pub timeout_ms: u64,
    /// Ack poll interval, ms.
    #[serde(default = "default_poll_ms")]
    pub poll_ms: u64,
}

fn default_poll_ms() -> u64 {
    5
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterMap {
    #[serde(rename = "axis")]
    pub axes: Vec<AxisRegister>,
    #[serde(default)]
    pub handshake: Option<Handshake>,
    /// Read the values back after each write and compare.
    #[serde(default = "yes")]
    pub verify_readback: bool,
    /// u16 register the box increments (wrapping) at the start of every write period.
    #[serde(default)]
    pub heartbeat_address: Option<u16>,
    /// The controller's heartbeat timeout, ms (required with `heartbeat_address`).
    #[serde(default)]
    pub heartbeat_timeout_ms: Option<u64>,
}

fn yes() -> bool {
    true
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum MapError {
    #[error("origin_shift.axis[{index}] ({axis}): {what}")]
    Axis {
        index: usize,
        axis: String,
        what: String,
    },
    #[error("origin_shift: registers {a} and {b} overlap at address {address}")]
    Overlap { a: String, b: String, address: u32 },
    #[error("origin_shift: no axis named {0} in the register map")]
    UnknownAxis(String),
    #[error("origin_shift: correction for axis {axis} is {value_um} µm, not finite")]
    NotFinite { axis: String, value_um: f64 },
    #[error(
        "origin_shift: axis {axis}: {value_um} µm is {counts} counts of {lsb_um} µm, outside the {kind:?} range"
    )]
    OutOfRange {
        axis: String,
        value_um: f64,
        counts: f64,
        lsb_um: f64,
        kind: DataType,
    },
    #[error("origin_shift: write of {len} word(s) at {address} is outside the allow-list")]
    NotAllowed { address: u16, len: usize },
    #[error("origin_shift: expected {expected} words for axis {axis}, got {got}")]
    WordCount {
        axis: String,
        expected: usize,
        got: usize,
    },
}

/// Register words of one request or reply, inline up to 8 (every write of x, y, z: at most 6
/// words; a read of three int32 axes with the strobe and ack), so the sink's write period
/// allocates nothing; longer runs spill to the heap.
pub type Words = smallvec::SmallVec<[u16; 8]>;

/// One FC16 request: contiguous words starting at `address`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WriteBlock {
    pub address: u16,
    pub words: Words,
}

/// FC16 carries at most 123 registers.
const MAX_FC16_WORDS: usize = 123;

impl RegisterMap {
    pub fn validate(&self) -> Result<(), MapError> {
        let mut spans: Vec<(u32, u32, String)> = Vec::new();
        for (index, r) in self.axes.iter().enumerate() {
            let err = |what: String| MapError::Axis {
                index,
                axis: r.axis.clone(),
                what,
            };
            if !(r.lsb_um.is_finite() && r.lsb_um > 0.0) {
                return Err(err(format!(
                    "lsb_um must be finite and > 0, got {}",
                    r.lsb_um
                )));
            }
            if self.axes[..index].iter().any(|o| o.axis == r.axis) {
                // Two registers for one axis: the guard would judge each against a different
                // controller value (the unused one's 0 read as the start: a 30 µm step).
                return Err(err("axis mapped twice: expected each axis once".into()));
            }
            if !matches!(r.data_type, DataType::Int16 | DataType::Int32) {
                // A correction is signed and counted in whole LSBs.
                return Err(err(format!(
                    "kind must be int16 or int32, got {:?}",
                    r.data_type
                )));
            }
            if r.sign != 1 && r.sign != -1 {
                return Err(err(format!("sign must be 1 or -1, got {}", r.sign)));
            }
            let start = u32::from(r.address);
            let end = start + u32::from(r.data_type.words());
            if end > 0x1_0000 {
                return Err(err(format!(
                    "register runs past address 65535 (start {start})"
                )));
            }
            spans.push((start, end, r.axis.clone()));
        }
        if let Some(h) = &self.handshake {
            spans.push((
                u32::from(h.strobe_address),
                u32::from(h.strobe_address) + 1,
                "strobe".into(),
            ));
            spans.push((
                u32::from(h.ack_address),
                u32::from(h.ack_address) + 1,
                "ack".into(),
            ));
        }
        if let Some(a) = self.heartbeat_address {
            spans.push((u32::from(a), u32::from(a) + 1, "heartbeat_address".into()));
        }
        for (i, a) in spans.iter().enumerate() {
            for b in &spans[i + 1..] {
                if a.0 < b.1 && b.0 < a.1 {
                    return Err(MapError::Overlap {
                        a: a.2.clone(),
                        b: b.2.clone(),
                        address: a.0.max(b.0),
                    });
                }
            }
        }
        Ok(())
    }

    pub fn axis(&self, name: &str) -> Result<&AxisRegister, MapError> {
        self.axes
            .iter()
            .find(|r| r.axis == name)
            .ok_or_else(|| MapError::UnknownAxis(name.into()))
    }

    /// The allow-list check: every word of the write must fall inside a value register or the strobe.
    pub fn check_write(&self, address: u16, len: usize) -> Result<(), MapError> {
        let allowed = |a: u32| {
            self.axes.iter().any(|r| {
                a >= u32::from(r.address)
                    && a < u32::from(r.address) + u32::from(r.data_type.words())
            }) || self
                .handshake
                .as_ref()
                .is_some_and(|h| a == u32::from(h.strobe_address))
                || self.heartbeat_address.is_some_and(|h| a == u32::from(h))
        };
        let Ok(len_u32) = u32::try_from(len) else {
            return Err(MapError::NotAllowed { address, len });
        };
        if len == 0 || !(0..len_u32).all(|k| allowed(u32::from(address) + k)) {
            return Err(MapError::NotAllowed { address, len });
        }
        Ok(())
    }

    /// Encode per-axis corrections (µm) into FC16 blocks: contiguous registers are merged into one
    /// request (so several axes also change together), never splitting a 32-bit value.
    pub fn encode(&self, corrections_um: &[(Axis, f64)]) -> Result<Vec<WriteBlock>, MapError> {
        let mut out = Vec::new();
        self.encode_into(corrections_um, &mut out)?;
        Ok(out)
    }

    /// [`Self::encode`] into `out`, reusing its blocks and their word buffers: allocates nothing
    /// once `out` has held as many blocks and words (the per-write path of a sink). On error `out`
    /// holds no usable blocks.
    pub fn encode_into(
        &self,
        corrections_um: &[(Axis, f64)],
        out: &mut Vec<WriteBlock>,
    ) -> Result<(), MapError> {
        let r = self.fill_blocks(corrections_um, out);
        if r.is_err() {
            out.clear();
        }
        r
    }

    fn fill_blocks(
        &self,
        corrections_um: &[(Axis, f64)],
        out: &mut Vec<WriteBlock>,
    ) -> Result<(), MapError> {
        let mut used: usize = 0;
        let mut last: Option<u16> = None;
        loop {
            // The next register by address: a map has a handful of axes, so picking the next one
            // beats sorting into a buffer (and allocates nothing).
            let mut next: Option<(&AxisRegister, f64)> = None;
            for (axis, value_um) in corrections_um {
                let r = self.axis(axis.name())?;
                if last.is_some_and(|l| r.address <= l) {
                    continue;
                }
                if next.is_none_or(|(n, _)| r.address < n.address) {
                    next = Some((r, *value_um));
                }
            }
            let Some((r, value_um)) = next else { break };
            last = Some(r.address);
            let (words, n) = encode_words(r, value_um)?;
            let words = &words[..n];
            match used.checked_sub(1).map(|i| &mut out[i]) {
                Some(b)
                    if b.address as usize + b.words.len() == r.address as usize
                        && b.words.len() + n <= MAX_FC16_WORDS =>
                {
                    b.words.extend_from_slice(words);
                }
                _ => {
                    if let Some(b) = out.get_mut(used) {
                        b.address = r.address;
                        b.words.clear();
                        b.words.extend_from_slice(words);
                    } else {
                        out.push(WriteBlock {
                            address: r.address,
                            words: Words::from_slice(words),
                        });
                    }
                    used += 1;
                }
            }
        }
        out.truncate(used);
        for b in out.iter() {
            self.check_write(b.address, b.words.len())?;
        }
        Ok(())
    }

    /// Decode the words read from an axis' register back into its correction, µm.
    pub fn decode(&self, axis: &str, words: &[u16]) -> Result<f64, MapError> {
        let r = self.axis(axis)?;
        decode_value(r, words)
    }
}

/// Register words for one axis' correction.
pub fn encode_value(r: &AxisRegister, value_um: f64) -> Result<Vec<u16>, MapError> {
    let (words, n) = encode_words(r, value_um)?;
    Ok(words[..n].to_vec())
}

/// [`encode_value`] without allocating: the words (1 or 2 used) and how many.
fn encode_words(r: &AxisRegister, value_um: f64) -> Result<([u16; 2], usize), MapError> {
    if !value_um.is_finite() {
        return Err(MapError::NotFinite {
            axis: r.axis.clone(),
            value_um,
        });
    }
    let counts = (f64::from(r.sign) * value_um / r.lsb_um).round();
    let (words, n) =
        encode_raw(counts, r.data_type, r.word_order).ok_or_else(|| MapError::OutOfRange {
            axis: r.axis.clone(),
            value_um,
            counts,
            lsb_um: r.lsb_um,
            kind: r.data_type,
        })?;
    Ok((words, n))
}

pub fn decode_value(r: &AxisRegister, words: &[u16]) -> Result<f64, MapError> {
    let expected = usize::from(r.data_type.words());
    let counts =
        decode_raw(words, r.data_type, r.word_order).ok_or_else(|| MapError::WordCount {
            axis: r.axis.clone(),
            expected,
            got: words.len(),
        })?;
    Ok(f64::from(r.sign) * counts * r.lsb_um)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> RegisterMap {
        toml::from_str(
            r#"
            verify_readback = true
            [[axis]]
            axis = "x"
            address = 100
            kind = "int32"
            word_order = "low_first"
            lsb_um = 0.1
            sign = 1
            [[axis]]
            axis = "z"
            address = 102
            kind = "int32"
            lsb_um = 0.1
            sign = -1
            [handshake]
            strobe_address = 110
            ack_address = 111
            timeout_ms = 200
            "#,
        )
        .unwrap()
    }

    #[test]
    fn encode_into_reuses_the_blocks_and_matches_encode() {
        let m = map();
        let mut out = Vec::new();
        m.encode_into(&[(Axis::X, 1.0), (Axis::Z, 2.0)], &mut out)
            .unwrap();
        let words_at = out[0].words.as_ptr();
        let wants = [(Axis::Z, -7.5), (Axis::X, 3.2)];
        m.encode_into(&wants, &mut out).unwrap();
        assert_eq!(out, m.encode(&wants).unwrap());
        assert_eq!(
            out[0].words.as_ptr(),
            words_at,
            "the word buffer was reused"
        );
        // Only z: one block at its own address; an unknown axis refuses and leaves nothing.
        m.encode_into(&[(Axis::Z, 1.0)], &mut out).unwrap();
        assert_eq!((out.len(), out[0].address), (1, 102));
        assert!(m.encode_into(&[(Axis::Y, 1.0)], &mut out).is_err());
        assert!(out.is_empty());
    }

    #[test]
    fn int32_words_in_configured_order_and_one_block() {
        let m = map();
        m.validate().unwrap();
        // −12.3 µm at 0.1 µm → −123 = 0xFFFF_FF85; CDAB puts the low word first.
        let blocks = m.encode(&[(Axis::Z, 70_000.0), (Axis::X, -12.3)]).unwrap();
        assert_eq!(
            blocks.len(),
            1,
            "x (100-101) and z (102-103) are contiguous: one FC16"
        );
        assert_eq!(blocks[0].address, 100);
        // z: sign −1 → −700000 counts = 0xFFF5_51A0, ABCD.
        assert_eq!(blocks[0].words[..], [0xFF85, 0xFFFF, 0xFFF5, 0x51A0]);
        assert!((m.decode("x", &blocks[0].words[0..2]).unwrap() + 12.3).abs() < 1e-9);
        assert!((m.decode("z", &blocks[0].words[2..4]).unwrap() - 70_000.0).abs() < 1e-6);
    }

    #[test]
    fn range_nan_and_allow_list() {
        let mut m = map();
        m.axes[0].data_type = DataType::Int16;
        // int16 at 0.1 µm holds ±3276.7 µm.
        assert!(m.encode(&[(Axis::X, 3276.7)]).is_ok());
        assert!(matches!(
            m.encode(&[(Axis::X, 3276.8)]),
            Err(MapError::OutOfRange { .. })
        ));
        assert!(matches!(
            m.encode(&[(Axis::X, f64::NAN)]),
            Err(MapError::NotFinite { .. })
        ));
        assert!(m.check_write(110, 1).is_ok(), "strobe is writable");
        assert!(
            m.check_write(111, 1).is_err(),
            "ack is read-only for the box"
        );
        assert!(
            m.check_write(101, 2).is_err(),
            "101 is not configured once x is int16"
        );
        assert!(matches!(
            m.encode(&[(Axis::Y, 1.0)]),
            Err(MapError::UnknownAxis(_))
        ));
    }

    #[test]
    fn overlap_is_rejected() {
        let mut m = map();
        m.axes[1].address = 101;
        assert!(matches!(m.validate(), Err(MapError::Overlap { .. })));
    }

    #[test]
    fn the_heartbeat_is_writable_and_must_not_overlap() {
        let mut m = map();
        assert!(m.check_write(112, 1).is_err(), "no heartbeat configured");
        m.heartbeat_address = Some(112);
        m.validate().unwrap();
        assert!(m.check_write(112, 1).is_ok());
        m.heartbeat_address = Some(103);
        match m.validate() {
            Err(MapError::Overlap { a, b, address }) => {
                assert_eq!(
                    (a.as_str(), b.as_str(), address),
                    ("z", "heartbeat_address", 103)
                );
            }
            other => panic!("{other:?}"),
        }
        m.heartbeat_address = Some(110);
        assert!(
            matches!(m.validate(), Err(MapError::Overlap { b, .. }) if b == "heartbeat_address"),
            "on the strobe"
        );
    }
}
