//! In-process clients of the origin-shift registers, used by tests and demos to close the loop
//! without a bus: an *oracle* that writes the truth's own static error, and a *table compensator*
//! that reproduces Spaan's (1995, Ch6) experiment — a correction table looked up at the measured or
//! the set-point position, stepped or interpolated, with or without direction hysteresis.
//!
//! Both write correction = −error (µm) rounded to the register LSB, through [`ShiftWriter`], which
//! also drives the PLC's strobe/acknowledge handshake when one is configured.

use crate::controller::plc::OriginShiftPlc;
use crate::world::World;

/// Writes per-axis shift counts into the PLC window, honouring the handshake.
#[derive(Clone, Debug, Default)]
pub struct ShiftWriter {
    pending: Option<[i64; 3]>,
    awaiting_ack: bool,
}

impl ShiftWriter {
    /// Queue new counts; they are written as soon as the handshake allows.
    pub fn set(&mut self, counts: [i64; 3]) {
        self.pending = Some(counts);
    }

    /// Drive the register protocol one step.
    pub fn poll(&mut self, plc: &mut OriginShiftPlc) -> anyhow::Result<()> {
        let hs = plc.config().handshake.clone();
        match hs {
            None => {
                if let Some(c) = self.pending.take() {
                    write_all(plc, c)?;
                }
            }
            Some(h) => {
                let ack = plc.read(h.ack_register, 1)?[0] != 0;
                if self.awaiting_ack {
                    if ack {
                        plc.write(h.strobe_register, &[0])?;
                        self.awaiting_ack = false;
                    }
                } else if !ack && let Some(c) = self.pending.take() {
                    write_all(plc, c)?;
                    plc.write(h.strobe_register, &[1])?;
                    self.awaiting_ack = true;
                }
            }
        }
        Ok(())
    }
}

fn write_all(plc: &mut OriginShiftPlc, counts: [i64; 3]) -> anyhow::Result<()> {
    for (axis, c) in counts.iter().enumerate() {
        let words = plc.encode(*c)?;
        plc.write(plc.shift_register(axis), &words)?;
    }
    Ok(())
}

fn to_counts(correction_um: f64, lsb_um: f64) -> i64 {
    retrocomp_analysis::numeric::round_i64(correction_um / lsb_um)
}

/// Set-point oracle: every `period_s`, writes −(static truth error at the nominal position).
#[derive(Clone, Debug)]
pub struct Oracle {
    pub period_s: f64,
    next_s: f64,
    writer: ShiftWriter,
}

impl Oracle {
    pub fn new(period_s: f64) -> Self {
        Self {
            period_s,
            next_s: 0.0,
            writer: ShiftWriter::default(),
        }
    }

    pub fn update(&mut self, world: &mut World) -> anyhow::Result<()> {
        if world.t_s() + 1e-9 >= self.next_s {
            self.next_s += self.period_s;
            let e = world.static_error_um(world.setpoint().pos_mm);
            let lsb = world.plc().config().lsb_um;
            self.writer.set(e.map(|v| to_counts(-v, lsb)));
        }
        self.writer.poll(world.plc_mut())
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lookup {
    /// Zero-order hold: the value of the cell the position is in (the controller's 200-interval grid).
    Stepped,
    /// Linear interpolation between table points.
    Linear,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    /// The axis' measured (feedback) position: the correction feeds back into what it reads.
    Measured,
    /// The nominal set-point: open loop (Spaan's fix).
    Setpoint,
}

/// One-axis bidirectional correction table (error values, µm, at `origin_mm + i·pitch_mm`).
#[derive(Clone, Debug)]
pub struct TableCompensator {
    pub axis: usize,
    pub origin_mm: f64,
    pub pitch_mm: f64,
    pub forward_um: Vec<f64>,
    pub reverse_um: Vec<f64>,
    pub lookup: Lookup,
    pub source: Source,
    /// Direction changes only after the position moved this far against the latched direction
    /// (0: direction = sign of the last change).
    pub hysteresis_um: f64,
    pub period_s: f64,
    /// Age of the position the compensator acts on (bus sampling + transport delay), s.
    pub latency_s: f64,
    history: std::collections::VecDeque<(f64, f64)>,
    next_s: f64,
    dir: i8,
    anchor_mm: Option<f64>,
    writer: ShiftWriter,
}

impl TableCompensator {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        axis: usize,
        origin_mm: f64,
        pitch_mm: f64,
        forward_um: Vec<f64>,
        reverse_um: Vec<f64>,
        lookup: Lookup,
        source: Source,
        hysteresis_um: f64,
        period_s: f64,
    ) -> Self {
        assert!(!forward_um.is_empty() && forward_um.len() == reverse_um.len() && pitch_mm > 0.0);
        Self {
            axis,
            origin_mm,
            pitch_mm,
            forward_um,
            reverse_um,
            lookup,
            source,
            hysteresis_um,
            period_s,
            latency_s: 0.0,
            history: std::collections::VecDeque::new(),
            next_s: 0.0,
            dir: 1,
            anchor_mm: None,
            writer: ShiftWriter::default(),
        }
    }

    /// Table value at a position for a direction.
    pub fn error_at_um(&self, pos_mm: f64, dir: i8) -> f64 {
        let t = if dir >= 0 {
            &self.forward_um
        } else {
            &self.reverse_um
        };
        let u = ((pos_mm - self.origin_mm) / self.pitch_mm).clamp(0.0, (t.len() - 1) as f64);
        let i = retrocomp_analysis::numeric::trunc_usize(u).min(t.len() - 1);
        match self.lookup {
            Lookup::Stepped => t[i],
            Lookup::Linear => {
                if i + 1 < t.len() {
                    t[i] + (t[i + 1] - t[i]) * (u - i as f64)
                } else {
                    t[i]
                }
            }
        }
    }

    fn update_direction(&mut self, pos_mm: f64) {
        let h_mm = self.hysteresis_um / 1000.0;
        match self.anchor_mm {
            None => self.anchor_mm = Some(pos_mm),
            Some(a) => {
                let d = pos_mm - a;
                if self.dir > 0 {
                    if d < -h_mm && d != 0.0 {
                        self.dir = -1;
                        self.anchor_mm = Some(pos_mm);
                    } else if d > 0.0 {
                        self.anchor_mm = Some(pos_mm);
                    }
                } else if d > h_mm && d != 0.0 {
                    self.dir = 1;
                    self.anchor_mm = Some(pos_mm);
                } else if d < 0.0 {
                    self.anchor_mm = Some(pos_mm);
                }
            }
        }
    }

    pub fn direction(&self) -> i8 {
        self.dir
    }

    /// Act on positions `latency_s` old (the gateway sees the encoder through a bus).
    pub fn with_latency(mut self, latency_s: f64) -> Self {
        self.latency_s = latency_s;
        self
    }

    /// Call after every world step.
    pub fn update(&mut self, world: &mut World) -> anyhow::Result<()> {
        let now = match self.source {
            Source::Measured => world.measured_mm(self.axis),
            Source::Setpoint => world.setpoint().pos_mm[self.axis],
        };
        let t = world.t_s();
        self.history.push_back((t, now));
        while self.history.len() > 1 && self.history[1].0 <= t - self.latency_s + 1e-9 {
            self.history.pop_front();
        }
        if t + 1e-9 >= self.next_s {
            self.next_s += self.period_s;
            let pos = self.history[0].1;
            self.update_direction(pos);
            let e = self.error_at_um(pos, self.dir);
            let lsb = world.plc().config().lsb_um;
            let mut counts = world.plc().shift_counts();
            counts[self.axis] = to_counts(-e, lsb);
            self.writer.set(counts);
        }
        self.writer.poll(world.plc_mut())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(lookup: Lookup) -> TableCompensator {
        TableCompensator::new(
            0,
            0.0,
            10.0,
            vec![0.0, 2.0, 4.0],
            vec![1.0, 3.0, 5.0],
            lookup,
            Source::Measured,
            0.0,
            0.01,
        )
    }

    #[test]
    fn stepped_and_linear_lookup() {
        let s = table(Lookup::Stepped);
        assert_eq!(s.error_at_um(9.99, 1), 0.0);
        assert_eq!(s.error_at_um(10.0, 1), 2.0);
        assert_eq!(s.error_at_um(15.0, -1), 3.0);
        assert_eq!(s.error_at_um(99.0, 1), 4.0, "clamped");
        let l = table(Lookup::Linear);
        assert!((l.error_at_um(15.0, 1) - 3.0).abs() < 1e-12);
        assert_eq!(l.error_at_um(-5.0, -1), 1.0);
    }

    #[test]
    fn hysteresis_ignores_small_reversals() {
        let mut t = table(Lookup::Linear);
        t.hysteresis_um = 5.0;
        for p in [0.0, 0.010, 0.020, 0.017, 0.016] {
            t.update_direction(p);
        }
        assert_eq!(t.direction(), 1, "4 µm back is inside the 5 µm band");
        t.update_direction(0.014);
        assert_eq!(t.direction(), -1);
    }
}
