//! Modbus register map types and the sans-IO conversion between register words and physical values.
//!
//! Addresses are **0-based protocol addresses** (what goes on the wire; mbpoll's `-r` and the "4x0001"
//! convention are 1-based, so holding register 40001 is address 0). FC03 reads holding registers, FC04
//! input registers. Conversion: `value = raw · scale + offset`, in the channel's unit (`T_bed_C`).
//! 32-bit types span two registers; `word_order = "high_first"` (ABCD, Modbus big-endian, the
//! default) or `"low_first"` (CDAB, word-swapped); the types and the word split are the workspace's one
//! vocabulary in [`super::words`].

use crate::Health;

use super::words::{DataType, WordOrder};
use super::words::{join_u32, split_u32};

#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Deserialize, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum RegisterTable {
    /// Holding registers, FC03 (read), FC06/FC16 (write).
    Holding,
    /// Input registers, FC04.
    Input,
}

/// Combine 1 or 2 registers into the raw value. `None` if `words` has the wrong length.
pub fn decode_raw(words: &[u16], t: DataType, order: WordOrder) -> Option<f64> {
    if words.len() != usize::from(t.words()) {
        return None;
    }
    let u32_of = |w: &[u16]| join_u32([w[0], w[1]], order);
    Some(match t {
        DataType::Int16 => f64::from(words[0].cast_signed()),
        DataType::Uint16 => f64::from(words[0]),
        DataType::Int32 => f64::from(u32_of(words).cast_signed()),
        DataType::Uint32 => f64::from(u32_of(words)),
        DataType::Float32 => f64::from(f32::from_bits(u32_of(words))),
    })
}

/// Split a raw value into registers (rounded for integer types). `None` if not finite or not
/// representable in the type. Returns the words and how many of them are used.
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "every integer cast below follows `fits` (the rounded value is inside the type), the f32 \
              cast the |raw| ≤ f32::MAX check (rounding to the nearest f32 is the encoding)"
)]
pub fn encode_raw(raw: f64, t: DataType, order: WordOrder) -> Option<([u16; 2], usize)> {
    if !raw.is_finite() {
        return None;
    }
    let r = raw.round();
    let fits = |lo: f64, hi: f64| (lo..=hi).contains(&r);
    let bits: u32 = match t {
        DataType::Int16 if fits(f64::from(i16::MIN), f64::from(i16::MAX)) => {
            return Some(([(r as i16).cast_unsigned(), 0], 1));
        }
        DataType::Uint16 if fits(0.0, f64::from(u16::MAX)) => return Some(([r as u16, 0], 1)),
        DataType::Int32 if fits(f64::from(i32::MIN), f64::from(i32::MAX)) => {
            (r as i32).cast_unsigned()
        }
        DataType::Uint32 if fits(0.0, f64::from(u32::MAX)) => r as u32,
        DataType::Float32 if raw.abs() <= f64::from(f32::MAX) => (raw as f32).to_bits(),
        _ => return None,
    };
    Some((split_u32(bits, order), 2))
}

fn unit_scale() -> f64 {
    1.0
}

/// One Modbus channel of the field TOML (`[[modbus.source.channel]]`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterChannel {
    /// Channel name with unit suffix (`T_spindle_C`).
    pub channel: String,
    pub kind: RegisterTable,
    /// 0-based protocol address of the first register.
    pub address: u16,
    #[serde(rename = "type")]
    pub data_type: DataType,
    #[serde(default)]
    pub word_order: WordOrder,
    #[serde(default = "unit_scale")]
    pub scale: f64,
    #[serde(default)]
    pub offset: f64,
    #[serde(default)]
    pub min: Option<f64>,
    #[serde(default)]
    pub max: Option<f64>,
}

impl RegisterChannel {
    /// Physical value and health from this channel's registers.
    pub fn decode(&self, words: &[u16]) -> (f64, Health) {
        match decode_raw(words, self.data_type, self.word_order) {
            None => (f64::NAN, Health::DecodeError),
            Some(raw) => {
                let v = raw * self.scale + self.offset;
                let ok = v.is_finite()
                    && self.min.is_none_or(|m| v >= m)
                    && self.max.is_none_or(|m| v <= m);
                (v, if ok { Health::Ok } else { Health::OutOfRange })
            }
        }
    }

    /// Registers that represent `value` (the simulator's and the origin-shift writer's side).
    pub fn encode(&self, value: f64) -> Option<Vec<u16>> {
        if self.scale == 0.0 || !self.scale.is_finite() {
            return None;
        }
        let (w, n) = encode_raw(
            (value - self.offset) / self.scale,
            self.data_type,
            self.word_order,
        )?;
        Some(w[..n].to_vec())
    }

    /// Last address used (inclusive).
    pub fn last_address(&self) -> u32 {
        u32::from(self.address) + u32::from(self.data_type.words()) - 1
    }
}

/// One read request covering several channels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadBlock {
    pub kind: RegisterTable,
    pub start: u16,
    pub count: u16,
    /// Indices into the channel list.
    pub members: Vec<usize>,
}

/// FC03/FC04 read at most 125 registers (Modbus application protocol §6.3).
pub(crate) const MAX_READ_REGISTERS: u16 = 125;

/// Group channels into as few reads as possible: same kind, sorted by address, merged while the span
/// stays ≤ `max_count` registers and the hole between neighbours is ≤ `max_gap` registers (reading a
/// hole is cheaper than another round trip, but a device may reject unmapped addresses: gap 0 is safe).
pub(crate) fn plan_reads(
    channels: &[RegisterChannel],
    max_count: u16,
    max_gap: u16,
) -> Vec<ReadBlock> {
    let max_count = max_count.clamp(2, MAX_READ_REGISTERS);
    let mut idx: Vec<usize> = (0..channels.len()).collect();
    idx.sort_by_key(|&i| (channels[i].kind, channels[i].address));
    let mut blocks: Vec<ReadBlock> = Vec::new();
    for i in idx {
        let c = &channels[i];
        let end = c.last_address();
        if let Some(b) = blocks.last_mut() {
            let b_end = u32::from(b.start) + u32::from(b.count) - 1;
            let gap_ok = u32::from(c.address) <= b_end + 1 + u32::from(max_gap);
            let new_end = end.max(b_end);
            if b.kind == c.kind && gap_ok && new_end - u32::from(b.start) < u32::from(max_count) {
                b.count = u16::try_from(new_end - u32::from(b.start) + 1)
                    .expect("a block is shorter than max_count, a u16");
                b.members.push(i);
                continue;
            }
        }
        blocks.push(ReadBlock {
            kind: c.kind,
            start: c.address,
            count: c.data_type.words(),
            members: vec![i],
        });
    }
    blocks
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ch(addr: u16, t: DataType, order: WordOrder) -> RegisterChannel {
        RegisterChannel {
            channel: format!("T{addr}_C"),
            kind: RegisterTable::Input,
            address: addr,
            data_type: t,
            word_order: order,
            scale: 1.0,
            offset: 0.0,
            min: None,
            max: None,
        }
    }

    #[test]
    fn int16_tenths_of_degree() {
        // PT100 modules report int16 in 0.1 °C (rust-stack.md §6: S+S Thermasgard, Phoenix RAD-PT100-4).
        let c = RegisterChannel {
            scale: 0.1,
            ..ch(0, DataType::Int16, WordOrder::HighFirst)
        };
        assert_eq!(c.decode(&[0xFF38]), (-20.0, Health::Ok)); // -200 → -20.0 °C
        assert!((c.decode(&[235]).0 - 23.5).abs() < 1e-12);
        assert_eq!(c.encode(23.5).unwrap(), vec![235]);
    }

    #[test]
    fn word_orders_differ_only_in_word_swap() {
        // 123.456f32 = 0x42F6E979
        let abcd = ch(0, DataType::Float32, WordOrder::HighFirst);
        let cdab = ch(0, DataType::Float32, WordOrder::LowFirst);
        assert!((abcd.decode(&[0x42F6, 0xE979]).0 - 123.456).abs() < 1e-4);
        assert!((cdab.decode(&[0xE979, 0x42F6]).0 - 123.456).abs() < 1e-4);
        let i = ch(0, DataType::Int32, WordOrder::LowFirst);
        assert_eq!(i.decode(&[0xFFFE, 0xFFFF]).0, -2.0);
        assert_eq!(i.encode(-2.0).unwrap(), vec![0xFFFE, 0xFFFF]);
        assert_eq!(
            ch(0, DataType::Uint32, WordOrder::HighFirst)
                .decode(&[1, 0])
                .0,
            65536.0
        );
        assert_eq!(
            ch(0, DataType::Int16, WordOrder::HighFirst)
                .decode(&[1, 2])
                .1,
            Health::DecodeError
        );
    }

    #[test]
    fn encode_refuses_unrepresentable() {
        assert!(
            ch(0, DataType::Int16, WordOrder::HighFirst)
                .encode(40000.0)
                .is_none()
        );
        assert!(
            ch(0, DataType::Uint16, WordOrder::HighFirst)
                .encode(-1.0)
                .is_none()
        );
        assert!(
            ch(0, DataType::Int32, WordOrder::HighFirst)
                .encode(f64::NAN)
                .is_none()
        );
        assert!(
            ch(0, DataType::Float32, WordOrder::HighFirst)
                .encode(1e39)
                .is_none()
        );
    }

    #[test]
    fn plan_merges_contiguous_and_splits_kinds_and_gaps() {
        let mut chans: Vec<_> = (0..16)
            .map(|i| ch(i, DataType::Int16, WordOrder::HighFirst))
            .collect();
        chans.push(ch(100, DataType::Float32, WordOrder::HighFirst));
        let mut h = ch(0, DataType::Int32, WordOrder::HighFirst);
        h.kind = RegisterTable::Holding;
        chans.push(h);
        let p = plan_reads(&chans, 125, 0);
        assert_eq!(p.len(), 3, "{p:?}");
        assert_eq!(
            (p[0].kind, p[0].start, p[0].count),
            (RegisterTable::Holding, 0, 2)
        );
        assert_eq!((p[1].start, p[1].count, p[1].members.len()), (0, 16, 16));
        assert_eq!((p[2].start, p[2].count), (100, 2));
        let p = plan_reads(&chans, 8, 0);
        assert_eq!(
            p.iter().filter(|b| b.kind == RegisterTable::Input).count(),
            3
        );
        assert!(p.iter().all(|b| b.count <= 8));
    }
}
