//! The box as a Modbus *server* for origin-shift corrections (LinuxCNC's `mb2hal`, a PLC's Modbus
//! master): the sans-IO core. The I/O shell is [`super::server`].
//!
//! Register image (0-based holding-register addresses, all configured in [`ServerMap`]):
//! - per-axis correction registers (read by the controller): the same [`AxisRegister`] schema and
//!   encoding as the client sink (int16/int32, `lsb_um`, `sign`, `word_order`), so a served value is
//!   bit for bit what the client sink would have written;
//! - a heartbeat register, +1 (wrapping u16) at every update, so the controller can see the box alive;
//! - optional position registers the controller writes its axis positions into (FC16), decoded into
//!   channel samples (`x_mm`): `position_mm = counts × lsb_um / 1000`;
//! - optional held registers the controller writes back the correction it actually applies (same
//!   encoding as the axis' correction register).
//!
//! Safety at the last step: every served value passes the box's one guard ([`crate::sinks::guard`]),
//! whose evidence is what the controller reports holding (the held registers, from any writer):
//! never beyond the clamp, never a step beyond `max_change_um_per_cycle` from any value the
//! controller may be applying (the reported value and every value served since it), in whole
//! counts. A reported value beyond the clamp is a `BeyondClamp` fault, a report too far from what
//! was served an `Uncertain` one: that axis' correction registers are withdrawn (reads get
//! exception 02, so the controller keeps what it applies) and the next report is the truth again.
//! Before the controller has reported what it holds (a held register it has not written is no
//! report: the shell reads only registers a client wrote), no correction register exists: after a box
//! restart it resumes from the controller's value instead of jumping from zero. Without held
//! registers the box takes what it served as applied (the config check refuses such maps where
//! it must). Stop ([`ServerCore::begin_ramp_out`]): every axis wants 0, within the cap per update,
//! until the controller reports holding 0. Hold-then-ramp on stale input is the engine's
//! ([`crate::engine::safety`]).
//! Sign: register = `sign × correction_um / lsb_um`; correction = −error.

use super::map::decode_value;
use super::map::{AxisRegister, RegisterMap, Words, WriteBlock};
use super::server_map::ServerMap;
use crate::sinks::guard::{AxisLimits, SinkFaults, Verdict, WriteGuard};
use retrocomp_bus::{ChannelId, ChannelTable};
use retrocomp_model::Axis;

/// One axis of the core.
#[derive(Clone, Debug)]
struct AxisState {
    reg: AxisRegister,
    /// `reg.axis` resolved once (a valid map names only corrected axes).
    axis: Option<Axis>,
    held: Option<AxisRegister>,
}

/// The server's state: which values are exposed, the heartbeat, what the controller reported.
#[derive(Clone, Debug)]
pub struct ServerCore {
    map: ServerMap,
    /// `map`'s correction registers as a register map, built once (encoding reuses it).
    correction_map: RegisterMap,
    /// The position registers with their channels, resolved once.
    positions: Vec<(ChannelId, AxisRegister)>,
    axes: Vec<AxisState>,
    /// The last step of every served value, axes in map order.
    guard: WriteGuard,
    faults: SinkFaults,
    ramping_out: bool,
    heartbeat: u16,
    updates: u64,
}

/// One update's register writes. Reused across updates by [`ServerCore::poll_update_into`]: its
/// buffers keep their capacity, so a steady server allocates nothing per update.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Update {
    /// Blocks to set (corrections merged per contiguous run, then the heartbeat).
    pub blocks: Vec<WriteBlock>,
    /// Exposed correction per served axis, µm.
    pub exposed_um: Vec<(Axis, f64)>,
    /// Correction registers to withdraw (address, count): axes the guard refused this update.
    pub withdrawn: Vec<(u16, u16)>,
}

impl ServerCore {
    /// `limits`: clamp and per-update cap per corrected axis; the position channels are resolved
    /// in `channels` (the gateway's table). The map must be valid.
    pub fn new(map: ServerMap, limits: &[AxisLimits], channels: &mut ChannelTable) -> Self {
        let mut guard = WriteGuard::new(
            map.axes
                .iter()
                .map(|r| AxisLimits::of(limits, &r.axis, r.lsb_um)),
        );
        let axes: Vec<AxisState> = map
            .axes
            .iter()
            .map(|reg| AxisState {
                axis: Axis::from_name(&reg.axis),
                held: map
                    .held
                    .iter()
                    .find(|h| h.axis == reg.axis)
                    .and_then(|h| map.held_register(h)),
                reg: reg.clone(),
            })
            .collect();
        for (i, a) in axes.iter().enumerate() {
            // Nothing will report this axis: the box starts it from 0 and takes what it serves as
            // applied (a map without held registers is refused where that is unsafe).
            if a.held.is_none() {
                guard.observe_read(i, 0.0);
            }
        }
        let n = axes.len();
        Self {
            correction_map: map.correction_map(),
            positions: map
                .positions
                .iter()
                .map(|p| {
                    (
                        channels.resolve(&p.channel),
                        ServerMap::position_register(p),
                    )
                })
                .collect(),
            map,
            axes,
            guard,
            faults: SinkFaults::none(n),
            ramping_out: false,
            heartbeat: 0,
            updates: 0,
        }
    }

    pub fn map(&self) -> &ServerMap {
        &self.map
    }

    pub fn heartbeat(&self) -> u16 {
        self.heartbeat
    }

    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// True once corrections may be served: without held registers at once; with them once the
    /// controller has reported what it holds for every axis.
    pub fn is_seeded(&self) -> bool {
        (0..self.axes.len()).all(|i| self.guard.read_um(i).is_some())
    }

    /// What the controller last reported holding per axis with a held register, µm (status).
    pub fn held_um(&self) -> impl Iterator<Item = (&str, f64)> {
        self.axes.iter().enumerate().filter_map(|(i, a)| {
            a.held.as_ref()?;
            Some((a.reg.axis.as_str(), self.guard.read_um(i)?))
        })
    }

    /// The engine's start values: the reported values within the clamp (an axis beyond it is not
    /// served, a fault, until its value is back in range; the engine then starts it from 0).
    pub fn start_values(&self) -> Vec<(String, f64)> {
        self.axes
            .iter()
            .enumerate()
            .filter(|(i, a)| {
                a.held.is_some()
                    && !matches!(self.guard.check(*i, f64::NAN), Verdict::BeyondClamp { .. })
            })
            .filter_map(|(i, a)| Some((a.reg.axis.clone(), self.guard.read_um(i)?)))
            .collect()
    }

    /// The guard's refusals of the last update, per axis (map order).
    pub fn faults(&self) -> &SinkFaults {
        &self.faults
    }

    /// The corrected axes' names, map order.
    pub fn axis_names(&self) -> impl Iterator<Item = &str> {
        self.axes.iter().map(|a| a.reg.axis.as_str())
    }

    /// From now on every axis wants 0 (the stop ramp-out), within the cap per update.
    pub fn begin_ramp_out(&mut self) {
        self.ramping_out = true;
    }

    /// Ramping out, and the controller reports holding the 0 served on every axis.
    pub fn is_ramped_out(&self) -> bool {
        self.ramping_out && (0..self.axes.len()).all(|i| self.guard.holds_zero(i))
    }

    /// The controller wrote registers: decode positions (channel, mm) and held values from the
    /// image. `read(address, count)` returns the image's words. Allocates; the server uses
    /// [`Self::handle_controller_write_into`].
    pub fn handle_controller_write(
        &mut self,
        read: impl Fn(u16, u16) -> Option<Vec<u16>>,
    ) -> Vec<(String, f64)> {
        let mut out = Vec::new();
        self.handle_controller_write_into(|a, n| read(a, n).map(Words::from_vec), &mut out);
        // `positions` follows the map's `[[position]]` order: the name is the map's.
        out.into_iter()
            .filter_map(|(c, mm)| {
                let k = self.positions.iter().position(|(id, _)| *id == c)?;
                Some((self.map.positions[k].channel.clone(), mm))
            })
            .collect()
    }

    /// [`Self::handle_controller_write`] with the positions into `out` (cleared first) as channel
    /// ids resolved when the core was built: no allocation once `out` has held them (a position
    /// or held register is at most two words, inline in [`Words`]).
    pub fn handle_controller_write_into(
        &mut self,
        read: impl Fn(u16, u16) -> Option<Words>,
        out: &mut Vec<(ChannelId, f64)>,
    ) {
        out.clear();
        if let Some(m) = &self.map.write_marker
            && read(m.address, 1).as_deref() != Some(&[m.value][..])
        {
            return;
        }
        for (i, a) in self.axes.iter().enumerate() {
            if let Some(h) = &a.held
                && let Some(words) = read(h.address, h.data_type.words())
                && let Ok(v) = decode_value(h, &words)
            {
                self.guard.observe_report(i, v);
            }
        }
        for (channel, r) in &self.positions {
            if let Some(words) = read(r.address, r.data_type.words())
                && let Ok(um) = decode_value(r, &words)
            {
                out.push((*channel, um / 1000.0));
            }
        }
    }

    /// One update from the engine's outputs (axis, correction µm). None until seeded. Axes missing
    /// from `targets` keep their exposed value. Allocates; the server loop uses
    /// [`Self::poll_update_into`].
    pub fn poll_update(&mut self, targets: &[(Axis, f64)]) -> Option<Update> {
        let mut u = Update::default();
        self.poll_update_into(targets, &mut u).then_some(u)
    }

    /// [`Self::poll_update`] into `out`, reusing its buffers: false (and `out` unspecified) when
    /// nothing is to be written. No allocation once `out` has held one update.
    pub fn poll_update_into(&mut self, targets: &[(Axis, f64)], out: &mut Update) -> bool {
        if !self.is_seeded() {
            return false;
        }
        out.exposed_um.clear();
        out.withdrawn.clear();
        for (i, a) in self.axes.iter().enumerate() {
            // An axis the engine does not drive stays where the controller is (the guard's
            // answer to NaN).
            let want = if self.ramping_out {
                0.0
            } else {
                targets
                    .iter()
                    .find(|(n, _)| Some(*n) == a.axis)
                    .map_or(f64::NAN, |t| t.1)
            };
            let verdict = self.guard.check(i, want);
            self.faults.beyond_clamp[i] = matches!(verdict, Verdict::BeyondClamp { .. });
            self.faults.uncertain[i] = matches!(verdict, Verdict::Uncertain { .. });
            match (verdict, a.axis) {
                (Verdict::Write(v), Some(axis)) => {
                    // Applied only once the controller reports it (taken as applied without held
                    // registers).
                    self.guard.wrote(i, v, a.held.is_none());
                    out.exposed_um.push((axis, v));
                }
                (Verdict::Write(_), None) | (Verdict::Unknown, _) => {
                    out.withdrawn.push((a.reg.address, a.reg.data_type.words()));
                }
                (Verdict::BeyondClamp { .. } | Verdict::Uncertain { .. }, _) => {
                    out.withdrawn.push((a.reg.address, a.reg.data_type.words()));
                    // The controller's next report is the truth.
                    self.guard.forget_unconfirmed(i);
                }
            }
        }
        if let Err(e) = self
            .correction_map
            .encode_into(&out.exposed_um, &mut out.blocks)
        {
            // Only reachable when the clamp exceeds the register range: expose nothing new.
            tracing::error!(%e, "origin-shift server: cannot encode; keeping the last values");
            return false;
        }
        self.heartbeat = self.heartbeat.wrapping_add(1);
        self.updates += 1;
        let heartbeat = [self.heartbeat];
        out.blocks.push(WriteBlock {
            address: self.map.heartbeat_address,
            words: Words::from_slice(&heartbeat),
        });
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sinks::origin_shift::WriteMarker;
    use std::collections::BTreeMap;

    pub(crate) fn map() -> ServerMap {
        toml::from_str(
            r#"
            heartbeat_address = 10
            [[axis]]
            axis = "x"
            address = 0
            kind = "int16"
            lsb_um = 0.1
            sign = 1
            [[axis]]
            axis = "z"
            address = 1
            kind = "int32"
            word_order = "low_first"
            lsb_um = 0.1
            sign = -1
            [[position]]
            channel = "x_mm"
            address = 20
            kind = "int16"
            lsb_um = 10.0
            [[held]]
            axis = "x"
            address = 30
            [[held]]
            axis = "z"
            address = 31
            "#,
        )
        .unwrap()
    }

    fn guards() -> Vec<AxisLimits> {
        let g = |axis: &str| AxisLimits {
            axis: axis.into(),
            max_correction_um: 50.0,
            max_change_um_per_write: 1.0,
        };
        vec![g("x"), g("z")]
    }

    #[test]
    fn validation_names_the_key() {
        let m = map();
        m.validate(&["x", "z"]).unwrap();
        let e = m.validate(&["x", "y", "z"]).unwrap_err();
        assert!(e.what.contains("corrected axis y"), "{e}");
        let e = m.validate(&["x"]).unwrap_err();
        assert_eq!(e.key, "axis[1].axis");
        let mut m2 = map();
        m2.heartbeat_address = 2; // inside z's int32 (1..3)
        let e = m2.validate(&["x", "z"]).unwrap_err();
        assert_eq!(e.key, "heartbeat_address", "{e}");
        let mut m3 = map();
        m3.held[1].address = 20; // on the position register
        let e = m3.validate(&["x", "z"]).unwrap_err();
        assert!(e.key == "held[1]" && e.what.contains("position[0]"), "{e}");
        let mut m4 = map();
        m4.positions[0].channel = "x".into();
        assert_eq!(
            m4.validate(&["x", "z"]).unwrap_err().key,
            "position[0].channel"
        );
        let mut m5 = map();
        m5.held.pop();
        assert_eq!(m5.validate(&["x", "z"]).unwrap_err().key, "held");
    }

    #[test]
    fn nothing_served_until_the_controller_reports_then_ramps_from_its_value() {
        let mut c = ServerCore::new(map(), &guards(), &mut ChannelTable::default());
        assert!(c.poll_update(&[(Axis::X, 20.0)]).is_none());
        // The controller writes x held = 12.3 µm (123 counts), z held = 0, position x = 150.00 mm.
        let image: BTreeMap<u16, u16> = [(30, 123), (31, 0), (32, 0), (20, 15000)].into();
        let read = |a: u16, n: u16| (a..a + n).map(|k| image.get(&k).copied()).collect();
        let pos = c.handle_controller_write(read);
        assert_eq!(pos, vec![("x_mm".to_string(), 150.0)]);
        assert!(c.is_seeded());
        let u = c.poll_update(&[(Axis::X, 20.0), (Axis::Z, -3.0)]).unwrap();
        // x: 12.3 → 13.3 (cap 1 µm); z: 0 → −1.0; heartbeat 1.
        assert_eq!(u.exposed_um[0].0, Axis::X);
        assert!((u.exposed_um[0].1 - 13.3).abs() < 1e-9, "{u:?}");
        assert!((u.exposed_um[1].1 + 1.0).abs() < 1e-9, "{u:?}");
        // x int16 at 0 and z int32 (CDAB, sign −1 → +10 counts) at 1..3: one block, then heartbeat.
        assert_eq!(u.blocks[0].address, 0);
        assert_eq!(u.blocks[0].words[..], [133, 10, 0]);
        assert_eq!(
            u.blocks[1],
            WriteBlock {
                address: 10,
                words: vec![1].into()
            }
        );
        assert_eq!(c.poll_update(&[]).unwrap().blocks[1].words[..], [2]);
    }

    #[test]
    fn writes_without_the_marker_are_ignored() {
        let mut m = map();
        m.write_marker = Some(WriteMarker {
            address: 40,
            value: 0x55AA,
        });
        m.validate(&["x", "z"]).unwrap();
        let mut c = ServerCore::new(m, &guards(), &mut ChannelTable::default());
        // A freshly loaded client writes zeros everywhere, marker included: not taken.
        let zeros: BTreeMap<u16, u16> = [(30, 0), (31, 0), (32, 0), (20, 0), (40, 0)].into();
        let pos =
            c.handle_controller_write(|a, n| (a..a + n).map(|k| zeros.get(&k).copied()).collect());
        assert!(pos.is_empty() && !c.is_seeded());
        let good: BTreeMap<u16, u16> = [(30, 5), (31, 0), (32, 0), (20, 100), (40, 0x55AA)].into();
        let pos =
            c.handle_controller_write(|a, n| (a..a + n).map(|k| good.get(&k).copied()).collect());
        assert_eq!(pos, vec![("x_mm".to_string(), 1.0)]);
        assert_eq!(c.held_um().next(), Some(("x", 0.5)));
    }

    #[test]
    fn a_controller_holding_zero_keeps_the_exposed_value_within_one_cap() {
        // Not homed: the controller gates the counts to 0 and reports 0, so the box may not run
        // ahead to the target however many updates pass.
        let mut c = ServerCore::new(map(), &guards(), &mut ChannelTable::default());
        let image: BTreeMap<u16, u16> = [(30, 0), (31, 0), (32, 0)].into();
        c.handle_controller_write(|a, n| (a..a + n).map(|k| image.get(&k).copied()).collect());
        for _ in 0..100 {
            let u = c.poll_update(&[(Axis::X, 40.0), (Axis::Z, 40.0)]).unwrap();
            assert!(
                u.exposed_um.iter().all(|(_, v)| v.abs() <= 1.0 + 1e-9),
                "{u:?}"
            );
        }
    }
}

#[cfg(test)]
#[path = "server_core_tests.rs"]
pub(crate) mod guard_tests;
