//! CiA 404 analog input values in a TPDO: AI process value as INT16 (7130h), INT32 (9130h) or REAL32
//! (6130h), little-endian at a configured byte offset. Integer values carry `decimal_digits` (6132h):
//! `value = raw / 10^decimal_digits` (e.g. 3 → raw 21345 is 21.345); REAL32 is already the value.
//! Units are the channel's (its name says them: `T_spindle_C`).

use super::tpdo_cob_id;
#[cfg(test)]
use crate::ChannelTable;
use crate::can::Frame;
use crate::{ChannelId, Health, Sample};
use embedded_can::Frame as _;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AnalogType {
    Int16,
    Int32,
    Real32,
}

impl AnalogType {
    pub fn size(self) -> usize {
        match self {
            AnalogType::Int16 => 2,
            AnalogType::Int32 | AnalogType::Real32 => 4,
        }
    }
}

fn one() -> u8 {
    1
}

/// One analog channel of the field TOML (`[[canopen.analog]]`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct AnalogChannel {
    pub channel: String,
    pub node_id: u8,
    #[serde(default = "one")]
    pub tpdo: u8,
    #[serde(default)]
    pub byte_offset: u8,
    #[serde(rename = "type")]
    pub data_type: AnalogType,
    #[serde(default)]
    pub decimal_digits: u8,
    #[serde(default)]
    pub min: Option<f64>,
    #[serde(default)]
    pub max: Option<f64>,
}

impl AnalogChannel {
    /// The channel a minimal `[[canopen.analog]]` entry gives (`channel`, `node_id`, `type`, every
    /// other key at its TOML default: TPDO 1, byte 0, no decimal digits, no limits).
    pub fn new(channel: &str, node_id: u8, data_type: AnalogType) -> Self {
        Self {
            channel: channel.into(),
            node_id,
            tpdo: 1,
            byte_offset: 0,
            data_type,
            decimal_digits: 0,
            min: None,
            max: None,
        }
    }

    pub fn cob_id(&self) -> u16 {
        tpdo_cob_id(self.tpdo, self.node_id)
    }

    fn divisor(&self) -> f64 {
        10f64.powi(i32::from(self.decimal_digits.min(9)))
    }

    /// The physical value in a PDO payload; `None` if the payload is too short.
    pub fn value_in(&self, data: &[u8]) -> Option<f64> {
        let off = usize::from(self.byte_offset);
        let b = data.get(off..off + self.data_type.size())?;
        Some(match self.data_type {
            AnalogType::Int16 => f64::from(i16::from_le_bytes([b[0], b[1]])) / self.divisor(),
            AnalogType::Int32 => {
                f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])) / self.divisor()
            }
            AnalogType::Real32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        })
    }

    /// Write `value` into a PDO payload (the simulator's side). False if it does not fit the payload or
    /// is not representable in the type (not finite, or beyond the integer range); the payload is then
    /// unchanged.
    pub fn put_value(&self, value: f64, data: &mut [u8]) -> bool {
        let off = usize::from(self.byte_offset);
        let Some(b) = data.get_mut(off..off + self.data_type.size()) else {
            return false;
        };
        if !value.is_finite() {
            return false;
        }
        match self.data_type {
            AnalogType::Int16 => {
                let r = (value * self.divisor()).round();
                if r < f64::from(i16::MIN) || r > f64::from(i16::MAX) {
                    return false;
                }
                #[allow(
                    clippy::cast_possible_truncation,
                    reason = "r is inside i16 (checked above)"
                )]
                let r = r as i16;
                b.copy_from_slice(&r.to_le_bytes());
            }
            AnalogType::Int32 => {
                let r = (value * self.divisor()).round();
                if r < f64::from(i32::MIN) || r > f64::from(i32::MAX) {
                    return false;
                }
                #[allow(
                    clippy::cast_possible_truncation,
                    reason = "r is inside i32 (checked above)"
                )]
                let r = r as i32;
                b.copy_from_slice(&r.to_le_bytes());
            }
            AnalogType::Real32 => {
                #[allow(
                    clippy::cast_possible_truncation,
                    reason = "REAL32 is an f32: the nearest f32 is the encoding (a value beyond f32 becomes ±inf, which a reader refuses)"
                )]
                let v = value as f32;
                b.copy_from_slice(&v.to_le_bytes());
            }
        }
        true
    }

    /// A frame carrying only this value (payload = offset + size bytes).
    pub fn encode(&self, value: f64) -> Option<Frame> {
        let mut d = [0u8; 8];
        let n = usize::from(self.byte_offset) + self.data_type.size();
        if n > 8 || !self.put_value(value, &mut d) {
            return None;
        }
        Frame::standard(self.cob_id(), &d[..n])
    }

    /// The sample of `channel` (this channel's id in the gateway's table) that `f` carries;
    /// `None` if the frame is not this channel's PDO.
    pub fn decode(&self, channel: ChannelId, f: &Frame, t_s: f64) -> Option<Sample> {
        if f.is_extended() || f.is_remote_frame() || f.raw_id() != u32::from(self.cob_id()) {
            return None;
        }
        let (value, health) = match self.value_in(f.data()) {
            None => (f64::NAN, Health::DecodeError),
            Some(v)
                if !v.is_finite()
                    || self.min.is_some_and(|m| v < m)
                    || self.max.is_some_and(|m| v > m) =>
            {
                (v, Health::OutOfRange)
            }
            Some(v) => (v, Health::Ok),
        };
        Some(Sample {
            channel,
            t_s,
            value,
            health,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(t: AnalogType, digits: u8, off: u8) -> AnalogChannel {
        AnalogChannel {
            channel: "T_spindle_C".into(),
            node_id: 0x10,
            tpdo: 2,
            byte_offset: off,
            data_type: t,
            decimal_digits: digits,
            min: Some(-50.0),
            max: Some(150.0),
        }
    }

    /// The id these tests decode as (the channel's name plays no part in decoding).
    fn id() -> ChannelId {
        ChannelTable::default().resolve("T_test_C")
    }

    #[test]
    fn decimal_digits_scale_integers() {
        // 6132h = 3 → raw / 1000 (rust-stack.md §6, esd CAN-CBX-THERMO §8.10).
        let c = ch(AnalogType::Int32, 3, 0);
        let f = Frame::standard(0x290, &21345i32.to_le_bytes()).unwrap();
        let s = c.decode(id(), &f, 0.5).unwrap();
        assert_eq!((s.value, s.health), (21.345, Health::Ok));
        let c = ch(AnalogType::Int16, 1, 2);
        let f = Frame::standard(0x290, &[0xAA, 0xAA, 0x0B, 0xFF]).unwrap(); // -245 → -24.5
        assert_eq!(c.decode(id(), &f, 0.0).unwrap().value, -24.5);
    }

    #[test]
    fn encode_round_trips_and_refuses_unrepresentable() {
        for (t, d) in [
            (AnalogType::Int16, 2),
            (AnalogType::Int32, 3),
            (AnalogType::Real32, 0),
        ] {
            let c = ch(t, d, 4);
            let f = c.encode(23.25).unwrap();
            assert!((c.decode(id(), &f, 0.0).unwrap().value - 23.25).abs() < 1e-6);
        }
        assert!(
            ch(AnalogType::Int16, 3, 0).encode(40.0).is_none(),
            "40000 > i16::MAX"
        );
        assert!(
            ch(AnalogType::Real32, 0, 6).encode(1.0).is_none(),
            "6 + 4 > 8 bytes"
        );
        let hot = ch(AnalogType::Real32, 0, 0).encode(300.0).unwrap();
        assert_eq!(
            ch(AnalogType::Real32, 0, 0)
                .decode(id(), &hot, 0.0)
                .unwrap()
                .health,
            Health::OutOfRange
        );
    }
}
