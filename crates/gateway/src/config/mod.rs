//! Field configuration (`retrocomp run --config FIELD.toml`): one TOML file per machine. Every key
//! that carries a quantity has its unit in its name. Parse errors carry file, line, column and key
//! (from the toml crate); semantic errors name the key path (`axis[1].position_channel`).

pub(crate) mod check;
pub(crate) mod field_check;
pub(crate) mod limits;
pub(crate) mod unit_network;

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::engine::direction::DirectionConfig;
use crate::engine::health::ChannelLimits;
use crate::engine::model_switch::Catalog;
use crate::engine::recovery::NeighbourEstimate;
use crate::engine::safety::SafetyConfig;
use crate::engine::safety::SafetyError;
use crate::engine::{Engine, EngineAxis, EngineConfig};
pub use crate::sinks::origin_shift::client::OriginShiftSink;
pub use crate::sinks::quadrature::config::{GpioLines, QuadratureAxis, QuadratureSink};
use retrocomp_bus::ChannelTable;
use retrocomp_bus::can::CanBackendConfig;
use retrocomp_bus::canopen::CanopenConfig;
use retrocomp_bus::config::{ModbusSection, SerialSection};
use retrocomp_model::Axis;
use retrocomp_model::ConfigError;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldConfig {
    pub gateway: GatewaySection,
    pub safety: SafetyConfig,
    pub direction: DirectionConfig,
    #[serde(default)]
    pub model: Option<ModelSection>,
    #[serde(rename = "axis")]
    pub axes: Vec<AxisSection>,
    /// CAN backend (`crates/bus/src/can/backend.rs`: socketcan | socketcand | mem).
    #[serde(default)]
    pub can: Option<CanBackendConfig>,
    /// CANopen nodes on that bus: CiA 406 encoders, CiA 404 analog inputs (`crates/bus/src/canopen`).
    #[serde(default)]
    pub canopen: Option<CanopenConfig>,
    /// Modbus TCP/RTU sources (`[[modbus.source]]`); schema and checks owned by `crates/bus/src/config.rs`.
    #[serde(default)]
    pub modbus: Option<ModbusSection>,
    /// Serial-line sources (DRO, scales, force lines: `[[serial.source]]`); schema in `crates/bus/src/config.rs`.
    #[serde(default)]
    pub serial: Option<SerialSection>,
    #[serde(default, rename = "channel")]
    pub channels: Vec<ChannelSection>,
    #[serde(default, rename = "recovery")]
    pub recoveries: Vec<NeighbourEstimate>,
    #[serde(default)]
    pub sink: SinkSection,
    /// Sparkplug B over MQTT to the plant (`[telemetry.mqtt]`, crates/gateway/src/northbound/telemetry).
    #[serde(default)]
    pub telemetry: Option<crate::northbound::telemetry::TelemetrySection>,
    /// OPC UA server for the plant's systems (`crates/gateway/src/opcua`); absent → none.
    #[serde(default)]
    pub opcua: Option<crate::northbound::opcua::OpcUaSection>,
    /// DNC drip-feed to the controller's serial input (`retrocomp dnc`, crates/gateway/src/sinks/dnc).
    #[serde(default)]
    pub dnc: Option<crate::sinks::dnc::config::DncSection>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GatewaySection {
    pub name: String,
    /// Position-term cycle (1–10 ms typical), ms.
    pub cycle_ms: u64,
    /// Temperatures (and other slow channels) are latched at this period, s (Spaan: 60 s tables).
    #[serde(default = "default_thermal_period_s")]
    pub thermal_period_s: f64,
    /// Read-only status HTTP endpoint; 127.0.0.1 unless you mean otherwise.
    #[serde(default = "default_status_listen")]
    pub status_listen: String,
    /// The status endpoint's listener policy (`retrocomp_bus::listen`): connection caps, idle timeout,
    /// descriptor reserve, and `allow_writes_from`, the peers whose actions are accepted.
    #[serde(default)]
    pub listen_policy: retrocomp_bus::listen::ListenPolicy,
    /// Compensation enabled at start (can be toggled at run time).
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Bearer token for the endpoint's actions (`POST /api/compensation`); absent → every
    /// action is refused (403). At least 16 characters. Never serialised (it is a secret).
    #[serde(default, skip_serializing)]
    pub api_token: Option<String>,
    /// On SIGTERM/SIGINT: ramp the origin-shift correction out (within the per-write cap) before
    /// exiting, or hold it (the controller's watchdog rule then removes it).
    #[serde(default)]
    pub on_stop: OnStop,
    /// Longest ramp-out on stop, s; then the box exits anyway (systemd's TimeoutStopSec must be longer).
    #[serde(default = "default_stop_ramp_max_s")]
    pub stop_ramp_max_s: f64,
    /// `SCHED_FIFO` priority (1–99) for the cycle and sink threads; absent → normal scheduler.
    /// Refused by the kernel → one WARN line and the normal scheduler (see `realtime.rs`).
    #[serde(default)]
    pub realtime_priority: Option<u8>,
    /// Lock all pages in RAM (`mlockall`) at start; refused → one WARN line.
    #[serde(default)]
    pub lock_memory: bool,
    /// Models an operator may switch to at run time (`POST /api/model`, `model_switch.rs`):
    /// `[gateway.models] name = "path"`, paths relative to this file. Each must load at start.
    #[serde(default)]
    pub models: BTreeMap<String, PathBuf>,
}

/// What the box does with the correction when it is asked to stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum OnStop {
    /// Write 0 (moving at most the per-write cap each period) until the controller holds 0.
    #[default]
    RampOut,
    /// Leave the controller's value as it is.
    Hold,
}

fn default_stop_ramp_max_s() -> f64 {
    10.0
}

fn default_thermal_period_s() -> f64 {
    60.0
}
fn default_status_listen() -> String {
    "127.0.0.1:9184".into()
}
fn yes() -> bool {
    true
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelSection {
    /// Machine model TOML (see `crates/model/src`), relative to this file.
    pub path: PathBuf,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PositionSource {
    /// The interpolator's set-point (Spaan Ch6: stable, no limit cycle). Preferred.
    #[default]
    Setpoint,
    /// The measured scale position (can limit-cycle at table steps; then keep the dosing cap small).
    Feedback,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSection {
    /// Axis name: x, y or z.
    pub name: String,
    /// Channel carrying the axis position, mm (e.g. `x_mm`).
    pub position_channel: String,
    #[serde(default)]
    pub position_source: PositionSource,
    /// Per-axis override of `[safety]`.
    #[serde(default)]
    pub safety: Option<SafetyConfig>,
}

/// Health limits of one channel (the fields of [`ChannelLimits`] plus its name; spelled out rather
/// than `flatten`ed because serde ignores `deny_unknown_fields` under `flatten`, and typos must fail).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSection {
    pub name: String,
    pub min: f64,
    pub max: f64,
    pub stale_after_s: f64,
    #[serde(default)]
    pub max_rate_per_s: Option<f64>,
    #[serde(default)]
    pub stuck_after_s: Option<f64>,
}

impl ChannelSection {
    pub fn limits(&self) -> ChannelLimits {
        ChannelLimits {
            min: self.min,
            max: self.max,
            stale_after_s: self.stale_after_s,
            max_rate_per_s: self.max_rate_per_s,
            stuck_after_s: self.stuck_after_s,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SinkSection {
    #[serde(default)]
    pub origin_shift: Option<OriginShiftSink>,
    #[serde(default)]
    pub quadrature: Option<QuadratureSink>,
    /// The box as a Modbus server the controller reads (crates/gateway/src/sinks/origin_shift/server.rs).
    #[serde(default)]
    pub origin_shift_server: Option<crate::sinks::origin_shift::server::ServerConfig>,
}

pub use field_check::{CheckedField, check_field};
pub use unit_network::UnitNetwork;

/// The optional parts this build of the gateway has (its cargo features): a field file naming a
/// part the build lacks is refused at its line ([`FieldConfig::parse`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Built {
    pub(crate) opcua: bool,
    pub(crate) mqtt: bool,
    /// GPIO lines for the quadrature injector (the `gpio` feature, on Linux only).
    pub(crate) gpio: bool,
}

impl Built {
    pub(crate) const THIS: Built = Built {
        opcua: cfg!(feature = "opcua"),
        mqtt: cfg!(feature = "mqtt"),
        gpio: cfg!(all(feature = "gpio", target_os = "linux")),
    };
}

/// A semantic problem at `key`, placed on the key's line of `text`.
fn invalid(path: &Path, text: &str, key: String, what: String) -> ConfigError {
    let line = retrocomp_bus::config::locate(text, &key).unwrap_or(0);
    ConfigError::single_at(&path.display().to_string(), line, &key, what)
}

impl FieldConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|e| {
            ConfigError::single(&path.display().to_string(), "", format!("cannot read: {e}"))
        })?;
        Self::parse(&text, path)
    }

    /// Parse and validate; `path` is only used in messages and to resolve relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        Self::parse_built(text, path, Built::THIS)
    }

    /// [`Self::parse`] as a build with only `built`'s optional parts would (tests check both
    /// answers in one build).
    fn parse_built(text: &str, path: &Path, built: Built) -> Result<Self, ConfigError> {
        let mut cfg: FieldConfig = toml::from_str(text)
            .map_err(|e| ConfigError::from_toml(&path.display().to_string(), text, &e))?;
        retrocomp_bus::modbus::warn_deprecated_spellings(text, &path.display().to_string());
        if let Some(m) = cfg.telemetry.as_mut().and_then(|t| t.mqtt.as_mut()) {
            m.resolve_paths(path.parent().unwrap_or(Path::new(".")));
        }
        cfg.validate(built)
            .map_err(|(key, what)| invalid(path, text, key, what))?;
        Ok(cfg)
    }

    /// `[sink.quadrature] state_file` and `trace.path`: made absolute against the config's
    /// directory, and their directories must be writable (the held counts are persisted there
    /// before every step; the trace is written there).
    fn resolve_quadrature_state(&mut self, base: &Path) -> Result<(), (String, String)> {
        let Some(q) = self.sink.quadrature.as_mut() else {
            return Ok(());
        };
        let path = q.state_path(base);
        crate::sinks::quadrature::held::check_writable(&path)
            .map_err(|what| ("sink.quadrature.state_file".to_string(), what))?;
        q.state_file = Some(path);
        if let Some(t) = q.trace.as_mut() {
            if t.path.is_relative() {
                t.path = base.join(&t.path);
            }
            crate::sinks::quadrature::held::check_writable(&t.path)
                .map_err(|what| ("sink.quadrature.trace.path".to_string(), what))?;
        }
        Ok(())
    }

    /// [`Self::load`] plus the checks only a deployment needs (`retrocomp run`): every axis has a
    /// position source among the configured buses. (Tests feed samples themselves, so `parse`
    /// does not require sources.)
    pub fn load_for_run(path: &Path) -> Result<Self, ConfigError> {
        let mut cfg = Self::load(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        let opcua = cfg.opcua.as_mut().map_or(Ok(()), |o| o.resolve(base));
        let checked = opcua
            .and_then(|()| cfg.check_position_sources())
            .and_then(|()| cfg.resolve_quadrature_state(base))
            .and_then(|()| resolve_models(&mut cfg.gateway.models, base));
        if let Err((key, what)) = checked {
            let text = std::fs::read_to_string(path).unwrap_or_default();
            return Err(invalid(path, &text, key, what));
        }
        Ok(cfg)
    }

    /// The box's channel table: every channel this file names, resolved in one fixed order
    /// (`[[channel]]`, axis positions, source channels, recovery targets and neighbours), so
    /// every part built from this file (decoders on their threads, the engine, the sink's
    /// server) gets the same id for a name. The engine adds the model's inputs after these.
    pub fn channel_table(&self) -> ChannelTable {
        let mut table = ChannelTable::default();
        let recoveries = self
            .recoveries
            .iter()
            .flat_map(|r| std::iter::once(&r.target).chain(&r.neighbours))
            .map(String::as_str);
        let names = self
            .channels
            .iter()
            .map(|c| c.name.as_str())
            .chain(self.axes.iter().map(|a| a.position_channel.as_str()))
            .chain(self.source_channels())
            .chain(recoveries);
        for name in names {
            table.resolve(name);
        }
        table
    }

    /// Channels the configured sources deliver.
    pub fn source_channels(&self) -> Vec<&str> {
        let mut out: Vec<&str> = Vec::new();
        if let Some(co) = &self.canopen {
            out.extend(co.encoder.iter().map(|e| e.channel.as_str()));
            out.extend(co.analog.iter().map(|a| a.channel.as_str()));
        }
        if let Some(m) = &self.modbus {
            for src in &m.source {
                out.extend(src.channel.iter().map(|c| c.channel.as_str()));
            }
        }
        if let Some(sr) = &self.serial {
            for src in &sr.source {
                out.extend(src.channel.iter().map(|c| c.name.as_str()));
            }
        }
        // A served register image takes the positions the controller writes into it (FC16).
        if let Some(srv) = &self.sink.origin_shift_server {
            out.extend(srv.map.positions.iter().map(|p| p.channel.as_str()));
        }
        out
    }

    /// The engine of this field file, with the values each axis' sink holds now by axis name
    /// (origin-shift registers read at start; 0 for quadrature). Names resolve here, once.
    pub fn engine(
        &self,
        initial_outputs_um: &BTreeMap<String, f64>,
    ) -> Result<Engine, SafetyError> {
        let initial: Vec<(Axis, f64)> = initial_outputs_um
            .iter()
            .filter_map(|(n, v)| Some((Axis::from_name(n)?, *v)))
            .collect();
        let mut table = self.channel_table();
        let cfg = self.engine_config(&mut table);
        Engine::from_config(&cfg, table, &initial)
    }

    /// The declared models and the channels the box has (configured, delivered by a source, or
    /// estimated by a recovery), for the HTTP task's model switch.
    pub fn model_catalog(&self) -> Catalog {
        let mut channels: BTreeSet<String> = self.channels.iter().map(|c| c.name.clone()).collect();
        channels.extend(self.source_channels().into_iter().map(str::to_string));
        channels.extend(self.recoveries.iter().map(|r| r.target.clone()));
        Catalog::new(self.gateway.models.clone(), channels)
    }

    /// The engine's part of this file, names resolved in `table` (this file's
    /// [`FieldConfig::channel_table`]). Panics on an axis name other than x, y or z, which
    /// [`FieldConfig::parse`] refuses.
    pub fn engine_config(&self, table: &mut ChannelTable) -> EngineConfig {
        EngineConfig {
            axes: self
                .axes
                .iter()
                .map(|a| EngineAxis {
                    axis: Axis::from_name(&a.name)
                        .unwrap_or_else(|| panic!("axis {:?} is not x, y or z", a.name)),
                    position: table.resolve(&a.position_channel),
                    safety: a.safety.unwrap_or(self.safety),
                })
                .collect(),
            channels: self
                .channels
                .iter()
                .map(|c| (table.resolve(&c.name), c.limits()))
                .collect(),
            recoveries: self.recoveries.clone(),
            direction: self.direction,
            thermal_period_s: self.gateway.thermal_period_s,
            enabled: self.gateway.enabled,
        }
    }

    /// Safety settings for an axis (its override or the global one).
    /// The clamp and per-write cap of every configured axis: the limits of the one last-step guard
    /// every sink passes its outputs through (`sinks/guard.rs`).
    pub fn sink_limits(&self) -> Vec<crate::sinks::guard::AxisLimits> {
        self.axes
            .iter()
            .map(|a| {
                let s = self.safety_for(&a.name);
                crate::sinks::guard::AxisLimits {
                    axis: a.name.clone(),
                    max_correction_um: s.max_correction_um,
                    max_change_um_per_write: s.max_change_um_per_cycle,
                }
            })
            .collect()
    }

    pub fn safety_for(&self, axis: &str) -> SafetyConfig {
        self.axes
            .iter()
            .find(|a| a.name == axis)
            .and_then(|a| a.safety)
            .unwrap_or(self.safety)
    }
}

/// At start (`FieldConfig::load_for_run`): make every declared path absolute (relative to the
/// config's folder) and load each model once, so a model that cannot be used is refused now.
fn resolve_models(
    models: &mut BTreeMap<String, PathBuf>,
    base: &Path,
) -> Result<(), (String, String)> {
    for (name, path) in models.iter_mut() {
        if path.is_relative() {
            *path = base.join(&*path);
        }
        retrocomp_model::MachineModel::from_toml_path(path).map_err(|e| {
            (
                format!("gateway.models.{name}"),
                format!("expected a machine model TOML: {}: {e}", path.display()),
            )
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str = r#"
[gateway]
name = "t"
cycle_ms = 5
[safety]
max_correction_um = 50.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 10.0
stale_hold_s = 1.0
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
"#;

    fn parse(extra: &str) -> Result<FieldConfig, ConfigError> {
        FieldConfig::parse(&format!("{BASE}{extra}"), Path::new("field.toml"))
    }

    /// A section whose server or output this build leaves out is refused with its key and line,
    /// never ignored; a build with it accepts the same text (the check can fail both ways). The
    /// shipped builds have every part ([`Built::THIS`]); `--no-default-features` has none.
    #[test]
    fn a_section_this_build_cannot_serve_is_refused_at_its_line() {
        let all = Built {
            opcua: true,
            mqtt: true,
            gpio: true,
        };
        let opcua = "[opcua]\nlisten = \"127.0.0.1:4840\"\nanonymous = true\n\
                     [opcua.identification]\nmanufacturer = \"m\"\nserial_number = \"1\"\n\
                     product_instance_uri = \"urn:m:1\"\n";
        let mqtt = "[telemetry.mqtt]\nbroker = \"127.0.0.1:1883\"\ngroup_id = \"g\"\nedge_node_id = \"n\"\n";
        let base_lines = BASE.lines().count();
        for (text, key, line, without) in [
            (
                format!("{BASE}{opcua}"),
                "opcua",
                base_lines + 1,
                Built {
                    opcua: false,
                    ..all
                },
            ),
            (
                format!("{BASE}{mqtt}"),
                "telemetry.mqtt",
                base_lines + 1,
                Built { mqtt: false, ..all },
            ),
        ] {
            FieldConfig::parse_built(&text, Path::new("field.toml"), all).unwrap();
            let e = FieldConfig::parse_built(&text, Path::new("field.toml"), without)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("field.toml:{line}"))
                    && e.contains(key)
                    && e.contains("cargo feature"),
                "{key}: {e}"
            );
        }
        // The shipped quadrature field file names GPIO lines on every axis.
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
            .join("deploy/field/mill-quadrature.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let first_gpio = 1 + text.lines().position(|l| l.starts_with("gpio =")).unwrap();
        FieldConfig::parse_built(&text, Path::new("mill.toml"), all).unwrap();
        let e =
            FieldConfig::parse_built(&text, Path::new("mill.toml"), Built { gpio: false, ..all })
                .unwrap_err()
                .to_string();
        assert!(
            e.contains(&format!("mill.toml:{first_gpio}"))
                && e.contains("sink.quadrature.axis[0].gpio")
                && e.contains("cargo feature `gpio`"),
            "{e}"
        );
    }

    #[test]
    fn modbus_and_serial_sources_parse_into_the_bus_schema() {
        let cfg = parse(
            r#"
[[modbus.source]]
name = "pt100"
transport = "tcp"
host = "127.0.0.1"
channel = [ { channel = "T_bed_C", kind = "input", address = 3, type = "int16", scale = 0.1 } ]
[[serial.source]]
name = "dro"
device = "/dev/ttyUSB0"
format = { kind = "nd522" }
channel = [ { name = "x_mm", key = "X" } ]
"#,
        )
        .unwrap();
        let m = &cfg.modbus.as_ref().unwrap().source[0];
        assert_eq!((m.port, m.channel[0].address), (502, 3));
        let s = &cfg.serial.as_ref().unwrap().source[0];
        assert_eq!(s.channel[0].key.as_deref(), Some("X"));
    }

    #[test]
    fn bus_section_problems_are_reported_with_their_key() {
        // TCP without a host (crates/bus/src/config.rs check) names the key path.
        let e = parse(
            r#"
[[modbus.source]]
name = "pt100"
transport = "tcp"
"#,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("modbus.source[0].transport") && e.contains("host"),
            "{e}"
        );
        // The same channel from two sources is refused.
        let e = parse(
            r#"
[[modbus.source]]
name = "a"
transport = "tcp"
host = "127.0.0.1"
channel = [ { channel = "x_mm", kind = "input", address = 0, type = "int16" } ]
[[serial.source]]
name = "dro"
device = "/dev/ttyUSB0"
format = { kind = "nd522" }
channel = [ { name = "x_mm" } ]
"#,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("x_mm") && e.contains("already defined"), "{e}");
        // A typo in a source key is a parse error naming it.
        let e = parse(
            "[[serial.source]]\nname = \"d\"\ndevice = \"/dev/ttyS0\"\nformat = { kind = \"nd522\" }\nbaudrate = 9600\n",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("baudrate"), "{e}");
    }
}
