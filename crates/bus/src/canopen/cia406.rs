//! CiA 406 encoder position TPDO: object 6004h (position value, U32, little-endian), mapped by default
//! at bytes 0..4 of TPDO1 (COB-ID 0x180 + node, mapping 1A00h:01 = 0x60040020).
//!
//! Conversion (one place, used both ways): with `sign` = +1 for `direction = "positive"`, −1 for
//! `"negative"`, and `unwrapped` the count with multi-turn rollovers removed,
//! `position_mm = sign · unwrapped / counts_per_mm + offset_mm`.
//! Rollover: the raw value wraps at `total_range_counts` (6002h; default 2^32). A jump of more than half
//! the range between two frames is taken as a wrap, so travel between two frames must stay below half
//! the range (at 1 kHz TPDOs this is never binding). The first frame is read nearest to zero (unwrapped
//! count in [−range/2, range/2)), so small negative positions, which the encoder reports wrapped to
//! just below the range, decode as negative; put the machine's travel inside that window with
//! `offset_mm` (or the encoder preset 6003h).

use super::tpdo_cob_id;
use crate::can::Frame;
use crate::{ChannelId, ChannelTable, Health, Sample};
use embedded_can::Frame as _;

/// CiA 406 counting direction (object 6000h bit 0): how the encoder's counts relate to the axis'
/// positive direction. Not the direction of approach (`retrocomp_model::approach::Approach`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CountingDirection {
    /// Counts increase with the axis' positive direction.
    #[default]
    Positive,
    /// Counts decrease with the axis' positive direction (encoder mounted mirrored).
    Negative,
}

impl CountingDirection {
    pub fn sign(self) -> f64 {
        match self {
            CountingDirection::Positive => 1.0,
            CountingDirection::Negative => -1.0,
        }
    }
}

fn one() -> u8 {
    1
}

/// One encoder channel of the field TOML (`[[canopen.encoder]]`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct EncoderChannel {
    /// Channel name with unit suffix, e.g. `x_mm`.
    pub channel: String,
    pub node_id: u8,
    /// TPDO number 1..=4 carrying 6004h.
    #[serde(default = "one")]
    pub tpdo: u8,
    /// Byte offset of 6004h inside the PDO.
    #[serde(default)]
    pub byte_offset: u8,
    pub counts_per_mm: f64,
    #[serde(default)]
    pub direction: CountingDirection,
    #[serde(default)]
    pub offset_mm: f64,
    /// Raw value wraps at this count (6002h total measuring range). `None` = 2^32.
    #[serde(default)]
    pub total_range_counts: Option<u64>,
    /// Cyclic timer to set through SDO 6200h at bring-up, ms.
    #[serde(default)]
    pub cyclic_ms: Option<u16>,
    /// Physical limits; a position outside them is reported as out of range.
    #[serde(default)]
    pub min_mm: Option<f64>,
    #[serde(default)]
    pub max_mm: Option<f64>,
}

impl EncoderChannel {
    /// The channel a minimal `[[canopen.encoder]]` entry gives (`channel`, `node_id`,
    /// `counts_per_mm`, every other key at its TOML default: TPDO 1, byte 0, positive counting,
    /// no offset, 2^32 range, no limits); the serde defaults above and this agree (tested).
    pub fn new(channel: &str, node_id: u8, counts_per_mm: f64) -> Self {
        Self {
            channel: channel.into(),
            node_id,
            tpdo: 1,
            byte_offset: 0,
            counts_per_mm,
            direction: CountingDirection::Positive,
            offset_mm: 0.0,
            total_range_counts: None,
            cyclic_ms: None,
            min_mm: None,
            max_mm: None,
        }
    }

    pub fn cob_id(&self) -> u16 {
        tpdo_cob_id(self.tpdo, self.node_id)
    }

    pub fn range_counts(&self) -> u64 {
        self.total_range_counts.unwrap_or(1 << 32).clamp(2, 1 << 32)
    }

    /// Raw 6004h value the encoder reports at `position_mm` (inverse of the decode conversion, wrapped
    /// into the range). `None` if the position is not finite.
    pub fn raw_counts_for(&self, position_mm: f64) -> Option<u32> {
        let counts =
            ((position_mm - self.offset_mm) * self.direction.sign() * self.counts_per_mm).round();
        if !counts.is_finite() || counts.abs() > 9.0e18 {
            return None;
        }
        let r = i128::from(self.range_counts());
        #[allow(
            clippy::cast_possible_truncation,
            reason = "counts is a finite integer with |counts| ≤ 9·10¹⁸ (checked above): exact in i128"
        )]
        let counts = counts as i128;
        u32::try_from(counts.rem_euclid(r)).ok()
    }

    /// The TPDO the encoder sends for a raw count (the simulator's side). Bytes before `byte_offset`
    /// are zero.
    pub fn encode_raw(&self, raw: u32) -> Frame {
        let off = usize::from(self.byte_offset.min(4));
        let mut d = [0u8; 8];
        d[off..off + 4].copy_from_slice(&raw.to_le_bytes());
        Frame::standard(self.cob_id(), &d[..off + 4]).expect("TPDO id and length are valid")
    }

    /// The TPDO for a position in mm; `None` if not finite.
    pub fn encode_position(&self, position_mm: f64) -> Option<Frame> {
        self.raw_counts_for(position_mm).map(|r| self.encode_raw(r))
    }
}

/// Decoding state of one encoder: remembers the last raw value to unwrap rollovers.
#[derive(Debug, Clone)]
pub struct PositionDecoder {
    pub cfg: EncoderChannel,
    /// `cfg.channel`, resolved at construction.
    channel: ChannelId,
    last_raw: Option<u64>,
    turns: i64,
    last_good_mm: f64,
    /// Frames decoded, rollovers seen, frames rejected.
    pub frames: u64,
    pub rollovers: u64,
    pub decode_errors: u64,
}

impl PositionDecoder {
    /// The decoder of `cfg`, its channel resolved in `channels`.
    pub fn new(cfg: EncoderChannel, channels: &mut ChannelTable) -> Self {
        PositionDecoder {
            channel: channels.resolve(&cfg.channel),
            cfg,
            last_raw: None,
            turns: 0,
            last_good_mm: f64::NAN,
            frames: 0,
            rollovers: 0,
            decode_errors: 0,
        }
    }

    /// Forget the rollover history (after the node was reset or the preset written).
    pub fn reset(&mut self) {
        self.last_raw = None;
        self.turns = 0;
    }

    /// `None` if the frame is not this encoder's TPDO; else a sample. A short frame or a raw value
    /// outside the total range gives `DecodeError` with the last good value (NaN before the first).
    pub fn decode(&mut self, f: &Frame, t_s: f64) -> Option<Sample> {
        if f.is_extended() || f.is_remote_frame() || f.raw_id() != u32::from(self.cfg.cob_id()) {
            return None;
        }
        let off = usize::from(self.cfg.byte_offset);
        let d = f.data();
        let range = self.cfg.range_counts();
        let raw = d
            .get(off..off + 4)
            .map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            .filter(|&r| r < range);
        let Some(raw) = raw else {
            self.decode_errors += 1;
            return Some(self.sample(t_s, self.last_good_mm, Health::DecodeError));
        };
        if self.last_raw.is_none() && raw >= range / 2 {
            self.turns = -1;
        }
        if let Some(last) = self.last_raw {
            // raw, last < range ≤ 2³² (a CiA 406 position is at most 32 bits): exact as i64.
            let delta = raw.cast_signed() - last.cast_signed();
            let half = (range / 2).cast_signed();
            if delta > half {
                self.turns -= 1;
                self.rollovers += 1;
            } else if delta < -half {
                self.turns += 1;
                self.rollovers += 1;
            }
        }
        self.last_raw = Some(raw);
        self.frames += 1;
        let unwrapped = raw as f64 + self.turns as f64 * range as f64;
        let mm =
            self.cfg.direction.sign() * unwrapped / self.cfg.counts_per_mm + self.cfg.offset_mm;
        let in_range = mm.is_finite()
            && self.cfg.min_mm.is_none_or(|m| mm >= m)
            && self.cfg.max_mm.is_none_or(|m| mm <= m);
        if in_range {
            self.last_good_mm = mm;
            Some(self.sample(t_s, mm, Health::Ok))
        } else {
            Some(self.sample(t_s, mm, Health::OutOfRange))
        }
    }

    fn sample(&self, t_s: f64, value: f64, health: Health) -> Sample {
        Sample {
            channel: self.channel,
            t_s,
            value,
            health,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn x_encoder() -> EncoderChannel {
        EncoderChannel::new("x_mm", 1, 1000.0)
    }

    #[test]
    fn new_is_a_minimal_toml_entry() {
        let parsed: EncoderChannel =
            toml::from_str("channel = \"x_mm\"\nnode_id = 1\ncounts_per_mm = 1000.0\n").unwrap();
        assert_eq!(parsed, x_encoder());
    }

    #[test]
    fn decodes_le_u32_on_0x181() {
        let mut d = PositionDecoder::new(x_encoder(), &mut ChannelTable::default());
        let f = Frame::standard(0x181, &[0x39, 0x30, 0, 0]).unwrap(); // 12345 counts
        let s = d.decode(&f, 1.0).unwrap();
        assert_eq!((s.value, s.health), (12.345, Health::Ok));
        assert!(
            d.decode(&Frame::standard(0x182, &[0; 4]).unwrap(), 1.0)
                .is_none()
        );
        let short = d
            .decode(&Frame::standard(0x181, &[1, 2]).unwrap(), 2.0)
            .unwrap();
        assert_eq!((short.health, short.value), (Health::DecodeError, 12.345));
    }

    #[test]
    fn direction_offset_and_encode_are_inverse() {
        let cfg = EncoderChannel {
            direction: CountingDirection::Negative,
            offset_mm: 500.0,
            counts_per_mm: 2048.0 / 5.0, // 2048 counts/rev on a 5 mm pitch screw
            total_range_counts: Some(2048 * 4096),
            ..x_encoder()
        };
        let mut d = PositionDecoder::new(cfg.clone(), &mut ChannelTable::default());
        for mm in [500.0, 499.9975, 123.4, -200.0] {
            let s = d.decode(&cfg.encode_position(mm).unwrap(), 0.0).unwrap();
            assert!(
                (s.value - mm).abs() <= 0.5 / cfg.counts_per_mm,
                "{mm} → {}",
                s.value
            );
        }
        // Moving +1 mm decreases the raw count for a negative-direction encoder.
        let a = cfg.raw_counts_for(10.0).unwrap();
        let b = cfg.raw_counts_for(11.0).unwrap();
        assert_eq!(i64::from(a) - i64::from(b), 410);
    }

    #[test]
    fn multi_turn_rollover_both_ways() {
        let cfg = EncoderChannel {
            total_range_counts: Some(1 << 24),
            ..x_encoder()
        };
        let mut d = PositionDecoder::new(cfg.clone(), &mut ChannelTable::default());
        let top = (1u32 << 24) - 10;
        // First frame just below the top of the range: read nearest to zero, i.e. −10 counts.
        assert!((d.decode(&cfg.encode_raw(top), 0.0).unwrap().value + 0.010).abs() < 1e-9);
        // wraps past the top: +20 counts → +10
        let s = d.decode(&cfg.encode_raw(10), 0.1).unwrap();
        assert!((s.value - 0.010).abs() < 1e-9, "{}", s.value);
        // and back down
        let s = d.decode(&cfg.encode_raw(top), 0.2).unwrap();
        assert!((s.value + 0.010).abs() < 1e-9);
        assert_eq!(d.rollovers, 2);
        // Far travel: 3 times round the range upwards in steps below half the range.
        let mut far = PositionDecoder::new(cfg.clone(), &mut ChannelTable::default());
        let step_mm = ((1u64 << 24) / 3) as f64 / 1000.0;
        let mut last = 0.0;
        for k in 0..=9 {
            let f = cfg.encode_position(f64::from(k) * step_mm).unwrap();
            last = far.decode(&f, 0.0).unwrap().value;
        }
        assert!((last - 9.0 * step_mm).abs() < 1e-9, "{last}");
        // a raw value beyond the configured range is a decode error, not a position
        let bad = d.decode(&cfg.encode_raw(1 << 24), 0.3).unwrap();
        assert_eq!(bad.health, Health::DecodeError);
    }

    #[test]
    fn limits_flag_out_of_range() {
        let cfg = EncoderChannel {
            min_mm: Some(0.0),
            max_mm: Some(800.0),
            ..x_encoder()
        };
        let mut d = PositionDecoder::new(cfg.clone(), &mut ChannelTable::default());
        let s = d.decode(&cfg.encode_position(800.5).unwrap(), 0.0).unwrap();
        assert_eq!(s.health, Health::OutOfRange);
    }
}
