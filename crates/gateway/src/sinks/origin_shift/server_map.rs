//! The origin-shift server's register image as configured (`[sink.origin_shift_server.map]`): the
//! controller-facing schema of [`super::server_core`] and its checks at config load. Correction
//! registers use the client sink's [`AxisRegister`] (µm per count `lsb_um`, `sign`, word order);
//! positions the controller writes are decoded as `position_mm = counts × lsb_um / 1000`.

use serde::{Deserialize, Serialize};

use super::map::{AxisRegister, DataType, MapError, RegisterMap, WordOrder};
use retrocomp_model::units::ChannelKind;

/// A register the controller writes an axis position into.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PositionRegister {
    /// Channel the decoded position feeds (unit suffix `_mm`), e.g. the `[[axis]] position_channel`.
    pub channel: String,
    pub address: u16,
    /// The data type (TOML key `kind`, as in the axis registers).
    #[serde(rename = "kind")]
    pub data_type: DataType,
    #[serde(default)]
    pub word_order: WordOrder,
    /// µm per count.
    pub lsb_um: f64,
}

/// A register the controller writes back the correction it applies for `axis` (same encoding as
/// that axis' correction register).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeldRegister {
    pub axis: String,
    pub address: u16,
}

/// A register the controller writes a fixed non-zero value into, in the same FC16 as its positions
/// and held values: writes are taken only while it holds that value. A client that starts writing
/// before its inputs are connected (mb2hal just loaded: every pin 0) is then ignored, not read as
/// "position 0, holding 0".
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WriteMarker {
    pub address: u16,
    pub value: u16,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServerMap {
    /// Correction registers, one per corrected axis.
    #[serde(rename = "axis")]
    pub axes: Vec<AxisRegister>,
    /// u16 incremented at every update.
    pub heartbeat_address: u16,
    #[serde(default, rename = "position")]
    pub positions: Vec<PositionRegister>,
    #[serde(default, rename = "held")]
    pub held: Vec<HeldRegister>,
    #[serde(default)]
    pub write_marker: Option<WriteMarker>,
}

/// A validation problem: the key path under the map (`axis[1].address`) and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("`{key}`: {what}")]
pub struct ServerMapError {
    pub key: String,
    pub what: String,
}

fn bad(key: impl Into<String>, what: impl Into<String>) -> ServerMapError {
    ServerMapError {
        key: key.into(),
        what: what.into(),
    }
}

impl ServerMap {
    /// The correction registers as a client-sink register map (no handshake, no read-back): the one
    /// encoder both sinks use.
    pub fn correction_map(&self) -> RegisterMap {
        RegisterMap {
            axes: self.axes.clone(),
            handshake: None,
            verify_readback: false,
            heartbeat_address: None,
            heartbeat_timeout_ms: None,
        }
    }

    pub fn held_register(&self, h: &HeldRegister) -> Option<AxisRegister> {
        self.axes
            .iter()
            .find(|a| a.axis == h.axis)
            .map(|a| AxisRegister {
                address: h.address,
                ..a.clone()
            })
    }

    pub(super) fn position_register(p: &PositionRegister) -> AxisRegister {
        AxisRegister {
            axis: p.channel.clone(),
            address: p.address,
            data_type: p.data_type,
            word_order: p.word_order,
            lsb_um: p.lsb_um,
            sign: 1,
        }
    }

    /// Every span of the image with its key path (for overlap checks and the write allow-list).
    fn spans(&self) -> Vec<(u32, u32, String)> {
        let mut spans = Vec::new();
        for (i, a) in self.axes.iter().enumerate() {
            spans.push((
                u32::from(a.address),
                u32::from(a.data_type.words()),
                format!("axis[{i}]"),
            ));
        }
        spans.push((
            u32::from(self.heartbeat_address),
            1,
            "heartbeat_address".into(),
        ));
        for (i, p) in self.positions.iter().enumerate() {
            spans.push((
                u32::from(p.address),
                u32::from(p.data_type.words()),
                format!("position[{i}]"),
            ));
        }
        for (i, h) in self.held.iter().enumerate() {
            let words = self
                .held_register(h)
                .map_or(1, |r| u32::from(r.data_type.words()));
            spans.push((u32::from(h.address), words, format!("held[{i}]")));
        }
        if let Some(m) = &self.write_marker {
            spans.push((u32::from(m.address), 1, "write_marker".into()));
        }
        spans
    }

    /// Checks every register, `corrected_axes` all mapped (and nothing else), no overlaps.
    pub fn validate(&self, corrected_axes: &[&str]) -> Result<(), ServerMapError> {
        self.correction_map().validate().map_err(|e| match e {
            MapError::Axis { index, what, .. } => bad(format!("axis[{index}]"), what),
            other => bad("axis", other.to_string()),
        })?;
        for (i, a) in self.axes.iter().enumerate() {
            if !corrected_axes.contains(&a.axis.as_str()) {
                return Err(bad(
                    format!("axis[{i}].axis"),
                    format!(
                        "{:?} is not a corrected [[axis]] ({corrected_axes:?})",
                        a.axis
                    ),
                ));
            }
            if self.axes[..i].iter().any(|b| b.axis == a.axis) {
                return Err(bad(
                    format!("axis[{i}].axis"),
                    format!("{} mapped twice", a.axis),
                ));
            }
        }
        for name in corrected_axes {
            if !self.axes.iter().any(|a| a.axis == *name) {
                return Err(bad(
                    "axis",
                    format!(
                        "corrected axis {name} has no correction register: add an [[…axis]] with axis = \"{name}\""
                    ),
                ));
            }
        }
        for (i, p) in self.positions.iter().enumerate() {
            if ChannelKind::of(&p.channel) != ChannelKind::LengthMm {
                return Err(bad(
                    format!("position[{i}].channel"),
                    format!(
                        "a position carries mm: expected a name ending in _mm, got {:?}",
                        p.channel
                    ),
                ));
            }
            if !(p.lsb_um.is_finite() && p.lsb_um > 0.0) {
                return Err(bad(
                    format!("position[{i}].lsb_um"),
                    format!("expected > 0, got {}", p.lsb_um),
                ));
            }
            if self.positions[..i].iter().any(|q| q.channel == p.channel) {
                return Err(bad(
                    format!("position[{i}].channel"),
                    format!("{} mapped twice", p.channel),
                ));
            }
        }
        for (i, h) in self.held.iter().enumerate() {
            if self.held_register(h).is_none() {
                return Err(bad(
                    format!("held[{i}].axis"),
                    format!("{:?} has no correction register", h.axis),
                ));
            }
            if self.held[..i].iter().any(|g| g.axis == h.axis) {
                return Err(bad(
                    format!("held[{i}].axis"),
                    format!("{} mapped twice", h.axis),
                ));
            }
        }
        if !self.held.is_empty() && self.held.len() != self.axes.len() {
            return Err(bad(
                "held",
                "either every corrected axis has a held register or none does",
            ));
        }
        if self.write_marker.as_ref().is_some_and(|m| m.value == 0) {
            return Err(bad(
                "write_marker.value",
                "expected a non-zero value (0 is what an unconnected client writes)",
            ));
        }
        let spans = self.spans();
        for (i, a) in spans.iter().enumerate() {
            if a.0 + a.1 > 0x1_0000 {
                return Err(bad(a.2.clone(), "register runs past address 65535"));
            }
            for b in &spans[i + 1..] {
                if a.0 < b.0 + b.1 && b.0 < a.0 + a.1 {
                    return Err(bad(
                        b.2.clone(),
                        format!("overlaps {} at address {}", a.2, a.0.max(b.0)),
                    ));
                }
            }
        }
        Ok(())
    }

    /// (address, words) ranges the controller may write: position and held registers.
    pub fn writable(&self) -> Vec<(u16, u16)> {
        let mut w: Vec<(u16, u16)> = self
            .positions
            .iter()
            .map(|p| (p.address, p.data_type.words()))
            .collect();
        for h in &self.held {
            if let Some(r) = self.held_register(h) {
                w.push((r.address, r.data_type.words()));
            }
        }
        w.extend(self.write_marker.as_ref().map(|m| (m.address, 1)));
        w
    }
}
