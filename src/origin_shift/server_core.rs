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
//! Safety at the last step (every update, per axis, µm): the exposed value is the engine's output
//! clamped to ±`max_correction_um`, quantised to whole counts, and moved at most
//! `max_change_um_per_cycle` from the last exposed value AND from what the controller reports holding
//! (when held registers are configured). Before the controller has reported what it holds, no
//! correction register exists (reads get exception 02): after a box restart it resumes from the
//! controller's value instead of jumping from zero. Hold-then-ramp on stale input is the engine's
//! ([`crate::gateway::safety`]); this core only guarantees clamp and per-update cap.
//! Sign: register = `sign × correction_um / lsb_um`; correction = −error.

use super::map::decode_value;
use super::map::{AxisRegister, RegisterMap, Words, WriteBlock};
pub use super::server_map::{
    HeldRegister, PositionRegister, ServerMap, ServerMapError, WriteMarker,
};
use crate::bus::ChannelId;
use crate::models::Axis;

/// Clamp and per-update cap of one axis (from the axis' [`crate::gateway::safety::SafetyConfig`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guard {
    pub max_correction_um: f64,
    pub max_change_um_per_update: f64,
}

/// The value to expose: as close to `target_um` as the clamp and the cap around every reference
/// allow, in whole counts of `lsb_um`. References are values the controller may hold (the last
/// exposed value, the held value it reported). When the references are further apart than allows a
/// common window, the LAST reference wins (callers put the controller's reported value last).
pub fn guarded_counts(target_um: f64, references_um: &[f64], guard: Guard, lsb_um: f64) -> i64 {
    let max_counts = (guard.max_correction_um / lsb_um).floor();
    let cap_counts = (guard.max_change_um_per_update / lsb_um).floor();
    let mut lo = -max_counts;
    let mut hi = max_counts;
    for (k, r) in references_um.iter().enumerate().rev() {
        // References are whole counts already (they came from registers or from this function).
        let rc = (r / lsb_um).round();
        let (l, h) = (rc - cap_counts, rc + cap_counts);
        if k == references_um.len() - 1 {
            // The controller's own value: always honour its window (even beyond the clamp: then
            // move towards the clamp by at most the cap).
            lo = lo.max(l).min(h);
            hi = hi.min(h).max(l);
        } else if l.max(lo) <= h.min(hi) {
            lo = lo.max(l);
            hi = hi.min(h);
        }
    }
    let want = if target_um.is_finite() {
        (target_um / lsb_um).round()
    } else {
        0.0
    };
    want.clamp(lo, hi) as i64
}

/// One axis of the core.
#[derive(Clone, Debug)]
struct AxisState {
    reg: AxisRegister,
    /// `reg.axis` resolved once (a valid map names only corrected axes).
    axis: Option<Axis>,
    held: Option<AxisRegister>,
    guard: Guard,
    /// Last exposed value, µm (None before the first update).
    exposed_um: Option<f64>,
    /// What the controller last reported holding, µm.
    held_um: Option<f64>,
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
    heartbeat: u16,
    updates: u64,
}

/// One update's register writes. Reused across updates by [`ServerCore::poll_update_into`]: its
/// buffers keep their capacity, so a steady server allocates nothing per update.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Update {
    /// Blocks to set (corrections merged per contiguous run, then the heartbeat).
    pub blocks: Vec<WriteBlock>,
    /// Exposed correction per axis, µm.
    pub exposed_um: Vec<(Axis, f64)>,
}

impl ServerCore {
    /// `guards`: per corrected axis. The map must be valid.
    pub fn new(map: ServerMap, guards: &[(String, Guard)]) -> Self {
        let axes = map
            .axes
            .iter()
            .map(|reg| {
                let guard = guards
                    .iter()
                    .find(|(a, _)| *a == reg.axis)
                    .map(|g| g.1)
                    .unwrap_or(Guard {
                        max_correction_um: 0.0,
                        max_change_um_per_update: 0.0,
                    });
                let held = map
                    .held
                    .iter()
                    .find(|h| h.axis == reg.axis)
                    .and_then(|h| map.held_register(h));
                AxisState {
                    axis: Axis::from_name(&reg.axis),
                    reg: reg.clone(),
                    held,
                    guard,
                    exposed_um: None,
                    held_um: None,
                }
            })
            .collect();
        Self {
            correction_map: map.correction_map(),
            positions: map
                .positions
                .iter()
                .map(|p| (ChannelId::of(&p.channel), ServerMap::position_register(p)))
                .collect(),
            map,
            axes,
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
        self.axes
            .iter()
            .all(|a| a.held.is_none() || a.held_um.is_some())
    }

    /// What the controller reported holding per axis, µm (for the engine's start value).
    pub fn held_um(&self) -> Vec<(String, f64)> {
        self.axes
            .iter()
            .filter_map(|a| a.held_um.map(|v| (a.reg.axis.clone(), v)))
            .collect()
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
        out.into_iter()
            .map(|(c, mm)| (c.name().to_string(), mm))
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
        for a in &mut self.axes {
            if let Some(h) = &a.held
                && let Some(words) = read(h.address, h.data_type.words())
                && let Ok(v) = decode_value(h, &words)
            {
                a.held_um = Some(v);
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
        for a in &mut self.axes {
            let start = a.exposed_um.or(a.held_um).unwrap_or(0.0);
            let target = targets
                .iter()
                .find(|(n, _)| Some(*n) == a.axis)
                .map_or(start, |t| t.1);
            // The cap holds from the last exposed value AND from what the controller holds.
            let refs: [Option<f64>; 2] = [a.exposed_um, a.held_um];
            let mut buf = [0.0; 2];
            let mut n = 0;
            for r in refs.into_iter().flatten() {
                buf[n] = r;
                n += 1;
            }
            let refs = if n == 0 { &[0.0][..] } else { &buf[..n] };
            let lsb = a.reg.lsb_um;
            let counts = guarded_counts(target, refs, a.guard, lsb);
            let v = counts as f64 * lsb;
            a.exposed_um = Some(v);
            if let Some(axis) = a.axis {
                out.exposed_um.push((axis, v));
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

    fn guards() -> Vec<(String, Guard)> {
        let g = Guard {
            max_correction_um: 50.0,
            max_change_um_per_update: 1.0,
        };
        vec![("x".into(), g), ("z".into(), g)]
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
        let mut c = ServerCore::new(map(), &guards());
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
        let mut c = ServerCore::new(m, &guards());
        // A freshly loaded client writes zeros everywhere, marker included: not taken.
        let zeros: BTreeMap<u16, u16> = [(30, 0), (31, 0), (32, 0), (20, 0), (40, 0)].into();
        let pos =
            c.handle_controller_write(|a, n| (a..a + n).map(|k| zeros.get(&k).copied()).collect());
        assert!(pos.is_empty() && !c.is_seeded());
        let good: BTreeMap<u16, u16> = [(30, 5), (31, 0), (32, 0), (20, 100), (40, 0x55AA)].into();
        let pos =
            c.handle_controller_write(|a, n| (a..a + n).map(|k| good.get(&k).copied()).collect());
        assert_eq!(pos, vec![("x_mm".to_string(), 1.0)]);
        assert_eq!(c.held_um()[0], ("x".to_string(), 0.5));
    }

    #[test]
    fn a_controller_holding_zero_keeps_the_exposed_value_within_one_cap() {
        // Not homed: the controller gates the counts to 0 and reports 0, so the box may not run
        // ahead to the target however many updates pass.
        let mut c = ServerCore::new(map(), &guards());
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
mod proptests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Whatever the target (NaN, huge) and references, the exposed value is within the clamp
        /// (when the controller's value is) and within one cap of the controller's value, in counts.
        #[test]
        fn clamp_and_cap_hold(
            target in prop_oneof![Just(f64::NAN), Just(f64::INFINITY), -1e6f64..1e6],
            last in -50.0f64..50.0,
            held in -50.0f64..50.0,
            max in 1.0f64..100.0,
            cap in 0.1f64..5.0,
            lsb in prop_oneof![Just(0.1f64), Just(0.05), Just(1.0)],
        ) {
            let q = |v: f64| (v / lsb).round() * lsb;
            let (last, held) = (q(last.clamp(-max, max)), q(held.clamp(-max, max)));
            let g = Guard { max_correction_um: max, max_change_um_per_update: cap };
            let v = guarded_counts(target, &[last, held], g, lsb) as f64 * lsb;
            prop_assert!(v.abs() <= max + 1e-9 || (v - held).abs() <= cap + 1e-9);
            prop_assert!((v - held).abs() <= cap + 1e-9, "v {v} held {held}");
            if (last - held).abs() <= cap {
                prop_assert!((v - last).abs() <= cap + 1e-9, "v {v} last {last}");
            }
            if target.is_finite() && target.abs() <= max && (target - held).abs() <= cap
                && (target - last).abs() <= cap {
                prop_assert!((v - target).abs() <= lsb + 1e-9);
            }
        }
    }
}
