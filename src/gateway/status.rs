//! "Is it working?": a status snapshot (built by the cycle at ≤ 10 Hz, see `cycle.rs`; per axis the applied correction, its breakdown by
//! term, the safety mode; every channel's health; the active faults) and its Prometheus text form.
//! Units: µm for corrections, mm for positions, channel units for channel values.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

use super::health::{ChannelStatus, FaultKind};
use super::safety::Mode;
use crate::approach::Approach;
use crate::bus::Health;
use crate::bus::can::BusState;
pub use crate::sink::SinkStatus;

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AxisStatus {
    pub axis: String,
    pub position_mm: Option<f64>,
    /// Latched direction of approach; serialised `unknown` / `forward` / `reverse`.
    #[serde(serialize_with = "crate::approach::serialize_latched")]
    pub direction: Option<Approach>,
    pub weight_forward: f64,
    /// Correction the model asks for (before safety), µm; None while inputs are stale/faulty.
    pub target_um: Option<f64>,
    /// Correction actually applied (after clamp, dosing and ramps), µm.
    pub applied_um: f64,
    pub mode: Mode,
    /// Breakdown of the target by model term (corrections, µm).
    pub terms_um: BTreeMap<String, f64>,
    /// Cycles whose model target was beyond the clamp (`max_correction_um`), since start.
    pub clamp_hits: u64,
    /// Cycles whose step was cut by the dosing cap (`max_change_um_per_cycle`), since start.
    pub cap_hits: u64,
}

/// The model in use: its name, the SHA-256 of its canonical TOML (the same model written by any
/// tool gives the same hash) and when the gateway loaded it (Unix time, s).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ModelIdentity {
    pub name: String,
    pub sha256: String,
    pub loaded_unix_s: f64,
    /// Term name → `geometric`, `thermal`, `load` or `other` (the OPC UA space groups terms by it).
    pub term_groups: BTreeMap<String, &'static str>,
}

/// One bus source's link (the CAN backend, a Modbus poller, a serial line): what `/status` shows
/// under `sources` and `/metrics` as `retrocomp_source_*`. `name` is also its fault-log source.
#[derive(Clone, Debug, PartialEq, Serialize, Default)]
pub struct SourceStatus {
    /// `can`, `modbus.<name>` or `serial.<name>`.
    pub name: String,
    pub connected: bool,
    /// Links re-established after a loss.
    pub reconnects: u64,
    /// Active source-level faults (`disconnected`, `bus_off`, `error_passive`, `bus_errors`,
    /// `exception`), each with the time it started, s.
    pub faults: Vec<(FaultKind, f64)>,
    pub last_error: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub can: Option<CanBusStatus>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modbus: Option<ModbusCounters>,
}

/// CAN controller state from error frames (see `bus::can::bus_state`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Default)]
pub struct CanBusStatus {
    pub state: BusState,
    pub error_frames: u64,
    pub bus_off_events: u64,
    pub tx_error_count: Option<u8>,
    pub rx_error_count: Option<u8>,
}

/// A Modbus poller's request outcomes since start.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Default)]
pub struct ModbusCounters {
    pub requests: u64,
    pub exceptions: u64,
    pub timeouts: u64,
    pub transport_errors: u64,
    pub connect_failures: u64,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct StatusSnapshot {
    pub t_s: f64,
    pub cycles: u64,
    pub enabled: bool,
    pub axes: Vec<AxisStatus>,
    pub channels: BTreeMap<String, ChannelStatus>,
    /// (source, fault, since t_s).
    pub active_faults: Vec<(String, FaultKind, f64)>,
    pub model_error: Option<String>,
    pub sink: Option<SinkStatus>,
    /// Bus sources' links (filled by the runtime; empty when the samples come from elsewhere).
    pub sources: Vec<SourceStatus>,
    /// The model in use (filled by the runtime from [`crate::gateway::engine::ErrorModel::identity`]).
    pub model: Option<ModelIdentity>,
    /// The Sparkplug B publisher (`[telemetry.mqtt]`), when configured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub telemetry: Option<crate::telemetry::status::TelemetryStatus>,
}

fn esc(label: &str) -> String {
    label
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

fn num(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 {
            "+Inf".into()
        } else {
            "-Inf".into()
        }
    } else {
        format!("{v}")
    }
}

impl StatusSnapshot {
    /// Prometheus text exposition format 0.0.4.
    pub fn prometheus(&self) -> String {
        let mut s = String::with_capacity(2048);
        let family = |s: &mut String, name: &str, kind: &str, help: &str| {
            let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} {kind}");
        };
        family(
            &mut s,
            "retrocomp_cycles_total",
            "counter",
            "Gateway cycles run.",
        );
        let _ = writeln!(s, "retrocomp_cycles_total {}", self.cycles);
        family(
            &mut s,
            "retrocomp_enabled",
            "gauge",
            "1 when compensation is enabled.",
        );
        let _ = writeln!(s, "retrocomp_enabled {}", u8::from(self.enabled));
        if let Some(m) = &self.model {
            family(
                &mut s,
                "retrocomp_model_info",
                "gauge",
                "The model in use (name, sha256 of its canonical TOML); loaded_unix_s below.",
            );
            let (name, sha) = (esc(&m.name), esc(&m.sha256));
            let _ = writeln!(
                s,
                "retrocomp_model_info{{name=\"{name}\",sha256=\"{sha}\"}} 1"
            );
            family(
                &mut s,
                "retrocomp_model_loaded_unix_seconds",
                "gauge",
                "When the model in use was loaded (Unix time), s.",
            );
            let _ = writeln!(
                s,
                "retrocomp_model_loaded_unix_seconds {}",
                num(m.loaded_unix_s)
            );
        }
        family(
            &mut s,
            "retrocomp_correction_applied_um",
            "gauge",
            "Correction applied per axis after safety, um.",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_correction_applied_um{{axis=\"{}\"}} {}",
                esc(&a.axis),
                num(a.applied_um)
            );
        }
        family(
            &mut s,
            "retrocomp_correction_target_um",
            "gauge",
            "Correction requested by the model per axis, um.",
        );
        for a in &self.axes {
            if let Some(t) = a.target_um {
                let _ = writeln!(
                    s,
                    "retrocomp_correction_target_um{{axis=\"{}\"}} {}",
                    esc(&a.axis),
                    num(t)
                );
            }
        }
        family(
            &mut s,
            "retrocomp_correction_term_um",
            "gauge",
            "Correction per axis and model term, um.",
        );
        for a in &self.axes {
            for (term, v) in &a.terms_um {
                let _ = writeln!(
                    s,
                    "retrocomp_correction_term_um{{axis=\"{}\",term=\"{}\"}} {}",
                    esc(&a.axis),
                    esc(term),
                    num(*v)
                );
            }
        }
        family(
            &mut s,
            "retrocomp_axis_tracking",
            "gauge",
            "1 when the axis output tracks the model (no ramp/hold).",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_axis_tracking{{axis=\"{}\"}} {}",
                esc(&a.axis),
                u8::from(a.mode == Mode::Tracking)
            );
        }
        family(
            &mut s,
            "retrocomp_safety_clamp_hits_total",
            "counter",
            "Cycles whose model target was beyond the clamp, per axis.",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_safety_clamp_hits_total{{axis=\"{}\"}} {}",
                esc(&a.axis),
                a.clamp_hits
            );
        }
        family(
            &mut s,
            "retrocomp_safety_cap_hits_total",
            "counter",
            "Cycles whose step was cut by the dosing cap, per axis.",
        );
        for a in &self.axes {
            let _ = writeln!(
                s,
                "retrocomp_safety_cap_hits_total{{axis=\"{}\"}} {}",
                esc(&a.axis),
                a.cap_hits
            );
        }
        family(
            &mut s,
            "retrocomp_channel_healthy",
            "gauge",
            "1 when the channel's latest value is healthy.",
        );
        for (name, c) in &self.channels {
            let _ = writeln!(
                s,
                "retrocomp_channel_healthy{{channel=\"{}\"}} {}",
                esc(name),
                u8::from(c.health == Health::Ok)
            );
        }
        family(
            &mut s,
            "retrocomp_channel_substituted",
            "gauge",
            "1 when the channel is replaced by its neighbour estimate.",
        );
        for (name, c) in &self.channels {
            let _ = writeln!(
                s,
                "retrocomp_channel_substituted{{channel=\"{}\"}} {}",
                esc(name),
                u8::from(c.substituted)
            );
        }
        family(
            &mut s,
            "retrocomp_channel_value",
            "gauge",
            "Last good (or substituted) channel value, channel units.",
        );
        for (name, c) in &self.channels {
            if let Some(v) = c.value {
                let _ = writeln!(
                    s,
                    "retrocomp_channel_value{{channel=\"{}\"}} {}",
                    esc(name),
                    num(v)
                );
            }
        }
        family(
            &mut s,
            "retrocomp_faults_active",
            "gauge",
            "Faults active now.",
        );
        let _ = writeln!(s, "retrocomp_faults_active {}", self.active_faults.len());
        if let Some(k) = &self.sink {
            family(
                &mut s,
                "retrocomp_sink_connected",
                "gauge",
                "1 when the output sink is connected.",
            );
            let _ = writeln!(
                s,
                "retrocomp_sink_connected{{sink=\"{}\"}} {}",
                esc(&k.kind),
                u8::from(k.connected)
            );
            family(
                &mut s,
                "retrocomp_sink_writes_total",
                "counter",
                "Sink write cycles by result.",
            );
            let _ = writeln!(
                s,
                "retrocomp_sink_writes_total{{sink=\"{}\",result=\"ok\"}} {}",
                esc(&k.kind),
                k.writes_ok
            );
            let _ = writeln!(
                s,
                "retrocomp_sink_writes_total{{sink=\"{}\",result=\"failed\"}} {}",
                esc(&k.kind),
                k.writes_failed
            );
            family(
                &mut s,
                "retrocomp_sink_held_um",
                "gauge",
                "Correction the controller's registers hold per axis (read back), um.",
            );
            for (axis, v) in &k.held_um {
                let _ = writeln!(
                    s,
                    "retrocomp_sink_held_um{{sink=\"{}\",axis=\"{}\"}} {}",
                    esc(&k.kind),
                    esc(axis),
                    num(*v)
                );
            }
            family(
                &mut s,
                "retrocomp_sink_fault_active",
                "gauge",
                "1 per active sink fault (source, kind).",
            );
            for (source, kind, _) in &k.faults {
                let _ = writeln!(
                    s,
                    "retrocomp_sink_fault_active{{source=\"{}\",kind=\"{kind:?}\"}} 1",
                    esc(source)
                );
            }
        }
        self.prometheus_sources(&mut s);
        if let Some(t) = &self.telemetry {
            t.prometheus(&mut s);
        }
        s
    }

    /// `retrocomp_source_*` and the CAN/Modbus link counters.
    fn prometheus_sources(&self, s: &mut String) {
        if self.sources.is_empty() {
            return;
        }
        let family = |s: &mut String, name: &str, kind: &str, help: &str| {
            let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} {kind}");
        };
        let each = |s: &mut String, name: &str, v: &dyn Fn(&SourceStatus) -> Option<String>| {
            for src in &self.sources {
                if let Some(v) = v(src) {
                    let _ = writeln!(s, "{name}{{source=\"{}\"}} {v}", esc(&src.name));
                }
            }
        };
        family(
            s,
            "retrocomp_source_connected",
            "gauge",
            "1 when the source's link is up.",
        );
        each(s, "retrocomp_source_connected", &|x| {
            Some(u8::from(x.connected).to_string())
        });
        family(
            s,
            "retrocomp_source_reconnects_total",
            "counter",
            "Links re-established after a loss.",
        );
        each(s, "retrocomp_source_reconnects_total", &|x| {
            Some(x.reconnects.to_string())
        });
        family(
            s,
            "retrocomp_source_faults_active",
            "gauge",
            "Source-level faults active now.",
        );
        each(s, "retrocomp_source_faults_active", &|x| {
            Some(x.faults.len().to_string())
        });
        family(
            s,
            "retrocomp_can_bus_state",
            "gauge",
            "CAN controller state: 0 error-active, 1 warning, 2 error-passive, 3 bus-off.",
        );
        each(s, "retrocomp_can_bus_state", &|x| {
            x.can.map(|c| (c.state as u8).to_string())
        });
        family(
            s,
            "retrocomp_can_error_frames_total",
            "counter",
            "CAN error frames received.",
        );
        each(s, "retrocomp_can_error_frames_total", &|x| {
            x.can.map(|c| c.error_frames.to_string())
        });
        family(
            s,
            "retrocomp_can_bus_off_total",
            "counter",
            "Times the CAN controller went bus-off.",
        );
        each(s, "retrocomp_can_bus_off_total", &|x| {
            x.can.map(|c| c.bus_off_events.to_string())
        });
        family(
            s,
            "retrocomp_can_tx_error_count",
            "gauge",
            "CAN transmit error counter (TEC).",
        );
        each(s, "retrocomp_can_tx_error_count", &|x| {
            x.can.and_then(|c| c.tx_error_count).map(|v| v.to_string())
        });
        family(
            s,
            "retrocomp_can_rx_error_count",
            "gauge",
            "CAN receive error counter (REC).",
        );
        each(s, "retrocomp_can_rx_error_count", &|x| {
            x.can.and_then(|c| c.rx_error_count).map(|v| v.to_string())
        });
        family(
            s,
            "retrocomp_modbus_exceptions_total",
            "counter",
            "Modbus exception replies.",
        );
        each(s, "retrocomp_modbus_exceptions_total", &|x| {
            x.modbus.map(|m| m.exceptions.to_string())
        });
        family(
            s,
            "retrocomp_modbus_failed_requests_total",
            "counter",
            "Modbus requests without an answer (timeout or transport error).",
        );
        each(s, "retrocomp_modbus_failed_requests_total", &|x| {
            x.modbus
                .map(|m| (m.timeouts + m.transport_errors).to_string())
        });
    }

    /// Human-readable table for `retrocomp status`.
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "t = {:.3} s, {} cycles, compensation {}",
            self.t_s,
            self.cycles,
            if self.enabled { "ENABLED" } else { "disabled" }
        );
        let _ = writeln!(
            s,
            "{:<4} {:>12} {:>9} {:>12} {:>12}  {:<11} terms (µm)",
            "axis", "pos_mm", "dir", "target_um", "applied_um", "mode"
        );
        for a in &self.axes {
            let terms: Vec<String> = a
                .terms_um
                .iter()
                .map(|(k, v)| format!("{k}={v:+.2}"))
                .collect();
            let _ = writeln!(
                s,
                "{:<4} {:>12} {:>9} {:>12} {:>12.3}  {:<11} {}",
                a.axis,
                a.position_mm.map_or("-".into(), |p| format!("{p:.4}")),
                crate::approach::latched_name(a.direction),
                a.target_um.map_or("-".into(), |t| format!("{t:.3}")),
                a.applied_um,
                format!("{:?}", a.mode).to_lowercase(),
                terms.join(" ")
            );
        }
        let _ = writeln!(s, "channels:");
        for (name, c) in &self.channels {
            let _ = writeln!(
                s,
                "  {:<20} {:>12} {:?}{}{}",
                name,
                c.value.map_or("-".into(), |v| format!("{v:.3}")),
                c.health,
                if c.substituted {
                    " (substituted from neighbours)"
                } else {
                    ""
                },
                if c.faults.is_empty() {
                    String::new()
                } else {
                    format!(" faults={:?}", c.faults)
                }
            );
        }
        if !self.sources.is_empty() {
            let _ = writeln!(s, "sources:");
        }
        for src in &self.sources {
            let _ = writeln!(
                s,
                "  {:<20} {} reconnects={}{}{}{}",
                src.name,
                if src.connected { "connected" } else { "DOWN" },
                src.reconnects,
                src.can
                    .map(
                        |c| format!(" bus={:?} error_frames={}", c.state, c.error_frames)
                            .to_lowercase()
                    )
                    .unwrap_or_default(),
                if src.faults.is_empty() {
                    String::new()
                } else {
                    format!(" faults={:?}", src.faults)
                },
                src.last_error
                    .as_ref()
                    .map(|e| format!(" last_error={e}"))
                    .unwrap_or_default(),
            );
        }
        if let Some(e) = &self.model_error {
            let _ = writeln!(s, "model error: {e}");
        }
        if let Some(k) = &self.sink {
            let held: Vec<String> = k
                .held_um
                .iter()
                .map(|(a, v)| format!("{a}={v:+.3}"))
                .collect();
            let _ = writeln!(
                s,
                "sink {}: {}, {} writes ok, {} failed; controller holds (µm) {}",
                k.kind,
                if k.connected {
                    "connected"
                } else {
                    "DISCONNECTED"
                },
                k.writes_ok,
                k.writes_failed,
                held.join(" ")
            );
            for (source, kind, since) in &k.faults {
                let _ = writeln!(s, "  fault {source} {kind:?} since {since:.3} s");
            }
        }
        s
    }
}
