//! Sans-IO publisher: from the world's state to bus payloads (CAN frames, input-register words,
//! serial lines) on each output's own schedule. The async shell ([`super::serve`]) only moves bytes.

use super::{EncoderSource, IoConfig};
use crate::world::World;
use retrocomp_bus::can::Frame;
use retrocomp_bus::canopen::{
    AnalogChannel, AnalogType, EncoderChannel, NodeState, encode_heartbeat,
};

/// PT100 register for a missing (dropped-out) sensor: "sensor break", as PT100 modules report it.
pub const PT100_BREAK: u16 = 0x8000;
/// PT100 register for a NaN or over-range value.
pub const PT100_OVERRANGE: u16 = 0x7FFF;

/// Everything due at one step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Outputs {
    pub frames: Vec<Frame>,
    /// (first input register, words).
    pub input_regs: Vec<(u16, Vec<u16>)>,
    pub lines: Vec<String>,
}

#[derive(Debug)]
pub struct Publisher {
    cfg: IoConfig,
    encoders: Vec<EncoderChannel>,
    next_enc_s: f64,
    next_temp_s: f64,
    next_hb_s: f64,
    next_line_s: f64,
}

/// int16 in 0.1 °C (PT100 module layout).
#[allow(
    clippy::cast_possible_truncation,
    reason = "range-checked to i16 before the cast"
)]
pub(crate) fn pt100_word(value_C: Option<f64>) -> u16 {
    match value_C {
        None => PT100_BREAK,
        Some(v) => {
            let r = (v * 10.0).round();
            if r.is_finite() && r > -32768.0 && r < 32767.0 {
                (r as i16).cast_unsigned()
            } else {
                PT100_OVERRANGE
            }
        }
    }
}

/// An int32 register pair, high word first, in units of `lsb`; `i32::MIN` = no valid reading.
#[allow(
    clippy::cast_possible_truncation,
    reason = "clamped to i32 before the cast"
)]
pub(crate) fn int32_words(value: Option<f64>, lsb: f64) -> [u16; 2] {
    let raw = match value {
        Some(v) if v.is_finite() => (v / lsb)
            .round()
            .clamp(f64::from(i32::MIN) + 1.0, f64::from(i32::MAX))
            as i32,
        _ => i32::MIN,
    }
    .cast_unsigned();
    retrocomp_bus::modbus::split_u32(raw, retrocomp_bus::modbus::WordOrder::HighFirst)
}

/// A weighing-indicator line (A&D/CAS style) for a force in N; `None` on dropout.
pub(crate) fn weighing_line(force_N: Option<f64>) -> Option<String> {
    let f = force_N?;
    Some(if f.is_finite() && f.abs() < 99999.9 {
        format!("ST,GS,{f:+08.1}N\r\n")
    } else {
        "OL,GS,+99999.9N\r\n".to_string()
    })
}

impl Publisher {
    pub fn new(cfg: IoConfig, world: &World) -> Self {
        let counts_per_mm = 1000.0 / world.config().servo.count_um;
        let encoders = cfg
            .can
            .as_ref()
            .map(|c| {
                (0..3)
                    .map(|k| {
                        let channel = format!("{}_mm", ["x", "y", "z"][k]);
                        EncoderChannel::new(&channel, c.encoder_nodes[k], counts_per_mm)
                    })
                    .collect()
            })
            .unwrap_or_default();
        Self {
            cfg,
            encoders,
            next_enc_s: 0.0,
            next_temp_s: 0.0,
            next_hb_s: 0.0,
            next_line_s: 0.0,
        }
    }

    /// The CiA 406 channel of an axis (so a test or gateway config decodes with the same settings).
    pub fn encoder_channel(&self, axis: usize) -> Option<&EncoderChannel> {
        self.encoders.get(axis)
    }

    /// CiA 404 channel of temperature sensor `i` (INT16, 1 decimal, four per TPDO).
    pub fn temperature_channel(node: u8, i: usize, name: &str) -> AnalogChannel {
        AnalogChannel {
            channel: name.to_string(),
            node_id: node,
            tpdo: u8::try_from(1 + i / 4).expect("at most MAX_TEMPS_PER_NODE (Config::validate)"),
            byte_offset: u8::try_from(2 * (i % 4)).expect("below 8"),
            data_type: AnalogType::Int16,
            decimal_digits: 1,
            min: None,
            max: None,
        }
    }

    /// Outputs due after the world's latest step.
    pub fn poll(&mut self, world: &mut World) -> Outputs {
        let t = world.t_s() + 1e-9;
        let mut out = Outputs::default();
        if let Some(can) = &self.cfg.can {
            if t >= self.next_enc_s {
                self.next_enc_s += can.encoder_period_s;
                let count_um = world.config().servo.count_um;
                for (k, ch) in self.encoders.iter().enumerate() {
                    let counts = match can.encoder_source {
                        EncoderSource::Motor => world.encoder_counts(k),
                        EncoderSource::Slide => retrocomp_analysis::numeric::round_i64(
                            world.slide_mm(k) * 1000.0 / count_um,
                        ),
                    };
                    if let Some(c) = world.encoder_fault(k, counts) {
                        // The encoder's 32-bit counter wraps.
                        let raw = u32::try_from(c.rem_euclid(1 << 32)).expect("in 0 … 2³²");
                        out.frames.push(ch.encode_raw(raw));
                    }
                }
            }
            if let Some(node) = can.temp_node
                && t >= self.next_temp_s
            {
                self.next_temp_s += can.temp_period_s;
                let temps = &world.readings().temps;
                for (pdo, chunk) in temps.chunks(4).enumerate() {
                    // A dropped-out sensor silences its TPDO (the gateway sees it go stale).
                    if chunk.iter().any(|c| c.value.is_none()) {
                        continue;
                    }
                    let mut data = [0u8; 8];
                    for (j, c) in chunk.iter().enumerate() {
                        let ch = Self::temperature_channel(node, pdo * 4 + j, &c.name);
                        let v = c.value.unwrap_or(f64::NAN);
                        if !ch.put_value(v, &mut data) {
                            data[2 * j..2 * j + 2].copy_from_slice(&PT100_OVERRANGE.to_le_bytes());
                        }
                    }
                    let ch = Self::temperature_channel(node, pdo * 4, "");
                    out.frames.push(
                        Frame::standard(ch.cob_id(), &data[..2 * chunk.len()]).expect("valid TPDO"),
                    );
                }
            }
            if let Some(p) = can.heartbeat_period_s
                && t >= self.next_hb_s
            {
                self.next_hb_s += p;
                for n in can.encoder_nodes.iter().chain(can.temp_node.iter()) {
                    out.frames
                        .push(encode_heartbeat(*n, NodeState::Operational));
                }
            }
        }
        if world.sampled()
            && let Some(mb) = &self.cfg.modbus
        {
            let r = world.readings();
            if !r.temps.is_empty() {
                out.input_regs.push((
                    mb.temps_first_input,
                    r.temps.iter().map(|c| pt100_word(c.value)).collect(),
                ));
            }
            if let (Some(addr), Some(f)) = (mb.force_first_input, &r.force) {
                out.input_regs
                    .push((addr, int32_words(f.value, mb.force_lsb_N).to_vec()));
            }
            if let Some(addr) = mb.strain_first_input
                && !r.strains.is_empty()
            {
                let words = r
                    .strains
                    .iter()
                    .flat_map(|c| int32_words(c.value, mb.strain_lsb_ue))
                    .collect();
                out.input_regs.push((addr, words));
            }
            if let Some(addr) = mb.positions_first_input {
                let words = (0..3)
                    .flat_map(|k| int32_words(Some(world.motor_mm(k) * 1000.0), mb.position_lsb_um))
                    .collect();
                out.input_regs.push((addr, words));
            }
        }
        if let Some(w) = &self.cfg.weighing
            && t >= self.next_line_s
        {
            self.next_line_s += w.period_s;
            if let Some(line) = weighing_line(world.readings().force.as_ref().and_then(|c| c.value))
            {
                out.lines.push(line);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pt100_words_and_markers() {
        assert_eq!(pt100_word(Some(21.34)), 213);
        assert_eq!(pt100_word(Some(-5.0)), (-50i16).cast_unsigned());
        assert_eq!(pt100_word(Some(f64::NAN)), PT100_OVERRANGE);
        assert_eq!(pt100_word(Some(1e9)), PT100_OVERRANGE);
        assert_eq!(pt100_word(None), PT100_BREAK);
    }

    #[test]
    fn int32_pairs_are_hi_lo_and_mark_missing_values() {
        assert_eq!(int32_words(Some(250.04), 0.1), [0, 2500]);
        assert_eq!(
            int32_words(Some(-1.0), 0.01),
            [0xFFFF, (-100i16).cast_unsigned()]
        );
        assert_eq!(int32_words(None, 0.1), [0x8000, 0]);
        assert_eq!(int32_words(Some(f64::NAN), 0.1), [0x8000, 0]);
    }

    #[test]
    fn weighing_lines_parse_as_the_bus_layer_expects() {
        assert_eq!(weighing_line(Some(250.04)).unwrap(), "ST,GS,+00250.0N\r\n");
        assert_eq!(weighing_line(Some(-3.0)).unwrap(), "ST,GS,-00003.0N\r\n");
        assert!(weighing_line(Some(f64::NAN)).unwrap().starts_with("OL,"));
        assert_eq!(weighing_line(None), None);
    }
}
