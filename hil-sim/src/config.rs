//! The simulator's TOML configuration: one struct per section, unknown keys rejected so a typo is an
//! error (with line and column from the TOML parser), not a silently ignored setting.
//!
//! Units are in every key that carries a quantity (`_mm`, `_um`, `_s`, `_C`, `_N`, `_ppm`, `_urad`).
//! Axis-indexed settings use `{ x = .., y = .., z = .. }` tables; a missing axis means "effect off".

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The whole simulator configuration.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// Seed of every random stream (noise, spikes). Same config + seed ⇒ byte-identical outputs.
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub clock: ClockConfig,
    pub program: ProgramConfig,
    #[serde(default)]
    pub servo: ServoConfig,
    #[serde(default)]
    pub plc: PlcConfig,
    #[serde(default)]
    pub truth: TruthConfig,
    #[serde(default)]
    pub hidden: HiddenConfig,
    #[serde(default)]
    pub faults: Vec<FaultConfig>,
    #[serde(default)]
    pub record: RecordConfig,
    #[serde(default)]
    pub io: crate::io::IoConfig,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ClockConfig {
    /// Servo (position-loop) rate. The world advances in steps of `1 / servo_hz`.
    #[serde(default = "d_servo_hz")]
    pub servo_hz: f64,
    /// Pace the simulation to the wall clock (demos, live buses) instead of running as fast as possible.
    #[serde(default)]
    pub realtime: bool,
    /// Hard stop even if the program has not reached M30 (a guard against endless scripts).
    #[serde(default = "d_max_duration_s")]
    pub max_duration_s: f64,
    /// With `realtime`: run the simulator's threads under `SCHED_FIFO` at this priority (1–99), so
    /// the simulated machine keeps its pace on a loaded host as a real one does on its own
    /// hardware (`serve` only). Refused (no root, `CAP_SYS_NICE` or `RLIMIT_RTPRIO`) → one line
    /// on stderr and the normal scheduler.
    #[serde(default)]
    pub realtime_priority: Option<u8>,
    /// With `realtime`: simulated seconds per wall-clock second (1 = real time; 20 runs a
    /// 30-minute warm-up in 90 s while the buses and the DNC input stay live).
    #[serde(default = "d_speed")]
    pub speed: f64,
}
fn d_speed() -> f64 {
    1.0
}
fn d_servo_hz() -> f64 {
    1000.0
}
fn d_max_duration_s() -> f64 {
    3600.0
}
impl Default for ClockConfig {
    fn default() -> Self {
        Self {
            servo_hz: d_servo_hz(),
            realtime: false,
            max_duration_s: d_max_duration_s(),
            realtime_priority: None,
            speed: d_speed(),
        }
    }
}

/// What the legacy controller runs: a G-code part program (inline or file) or a scripted trajectory.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProgramConfig {
    #[serde(default)]
    pub gcode: Option<String>,
    /// Relative paths are resolved against the config file's folder.
    #[serde(default)]
    pub gcode_path: Option<PathBuf>,
    /// Scripted trajectory: positions at times, linearly interpolated (time must increase).
    #[serde(default)]
    pub script: Vec<ScriptPoint>,
    /// Tool length (Abbe arm along Z) in the recording's `tool_mm` column and the geometric model.
    #[serde(default)]
    pub tool_mm: f64,
    /// Start position of the slides (machine coordinates).
    #[serde(default)]
    pub start_mm: [f64; 3],
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScriptPoint {
    pub t_s: f64,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    #[serde(default)]
    pub rpm: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ServoConfig {
    /// Position-loop gain (velocity per position error). Following error = (1 − feedforward)·v / kv.
    #[serde(default = "d_kv")]
    pub kv_per_s: f64,
    /// Velocity feedforward fraction 0..1.
    #[serde(default)]
    pub feedforward: f64,
    /// Drive velocity loop as a first-order lag (0 = instantaneous).
    #[serde(default = "d_vel_tau")]
    pub velocity_tau_s: f64,
    #[serde(default = "d_max_speed")]
    pub max_speed_mm_s: f64,
    /// G0 feed.
    #[serde(default = "d_rapid")]
    pub rapid_mm_min: f64,
    /// Feedback encoder count (quantization); also the size of one injected quadrature count.
    #[serde(default = "d_count")]
    pub count_um: f64,
    /// Ideal servo: the motor sits exactly on its target (no following error, no quantization in the loop).
    #[serde(default)]
    pub ideal: bool,
    /// Static friction: a standing axis breaks away only when kv·(position error) exceeds
    /// kv·`stiction_um` (0 = off). Below it the drive's torque does not overcome friction.
    #[serde(default)]
    pub stiction_um: f64,
    /// A moving axis sticks again once its velocity command falls below kv·`coulomb_um`.
    #[serde(default)]
    pub coulomb_um: f64,
}
fn d_kv() -> f64 {
    30.0
}
fn d_vel_tau() -> f64 {
    0.002
}
fn d_max_speed() -> f64 {
    250.0
}
fn d_rapid() -> f64 {
    6000.0
}
fn d_count() -> f64 {
    1.0
}
impl Default for ServoConfig {
    fn default() -> Self {
        Self {
            kv_per_s: d_kv(),
            feedforward: 0.0,
            velocity_tau_s: d_vel_tau(),
            max_speed_mm_s: d_max_speed(),
            rapid_mm_min: d_rapid(),
            count_um: d_count(),
            ideal: false,
            stiction_um: 0.0,
            coulomb_um: 0.0,
        }
    }
}

/// The register vocabulary of the PLC window is the workspace's one (`retrocomp_bus::modbus`):
/// `word = "int16" | "int32" | ...`, `word_order = "high_first" | "low_first"`.
pub use retrocomp_bus::modbus::{DataType, WordOrder};

/// The PLC window through which origin shifts reach the controller (a PMC-like register block).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlcConfig {
    /// PLC scan period: shifts are latched once per scan (legacy PLCs: 8–16 ms).
    #[serde(default = "d_scan")]
    pub scan_s: f64,
    #[serde(default = "d_word")]
    pub word: DataType,
    #[serde(default = "d_order")]
    pub word_order: WordOrder,
    /// Value of one register count.
    #[serde(default = "d_lsb")]
    pub lsb_um: f64,
    /// Holding-register address of the X shift; Y and Z follow (1 or 2 registers apart by `word`).
    #[serde(default)]
    pub first_register: u16,
    /// Optional strobe/acknowledge handshake: shifts are latched only while strobe = 1.
    #[serde(default)]
    pub handshake: Option<HandshakeConfig>,
    /// Optional heartbeat watchdog: ramp the shifts out when the box's heartbeat stops.
    #[serde(default)]
    pub watchdog: Option<WatchdogConfig>,
}

/// The PLC's heartbeat watchdog rule (docs/gateway.md, "The controller's watchdog rule").
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct WatchdogConfig {
    /// Register the box increments every write period (`heartbeat_address` in its map).
    pub heartbeat_register: u16,
    /// Trip when the heartbeat has not changed for this long (N box write periods), s.
    pub timeout_s: f64,
    /// While tripped, move each applied shift towards 0 at this rate, µm/s.
    pub ramp_um_per_s: f64,
}
fn d_scan() -> f64 {
    0.010
}
fn d_word() -> DataType {
    DataType::Int16
}
fn d_order() -> WordOrder {
    WordOrder::HighFirst
}
fn d_lsb() -> f64 {
    1.0
}
impl Default for PlcConfig {
    fn default() -> Self {
        Self {
            scan_s: d_scan(),
            word: d_word(),
            word_order: d_order(),
            lsb_um: d_lsb(),
            first_register: 0,
            handshake: None,
            watchdog: None,
        }
    }
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct HandshakeConfig {
    pub strobe_register: u16,
    pub ack_register: u16,
}

/// The visible geometric model of the true machine (what a calibrated model would know).
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TruthConfig {
    /// The project's machine model (TOML, `retrocomp_model`); relative paths resolve against the
    /// config file's folder. When given, `builtin` must be empty.
    #[serde(default)]
    pub model_path: Option<PathBuf>,
    #[serde(default)]
    pub builtin: crate::truth::BuiltinGeometry,
}

/// Per-axis optional setting.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PerAxis<T> {
    #[serde(default = "none")]
    pub x: Option<T>,
    #[serde(default = "none")]
    pub y: Option<T>,
    #[serde(default = "none")]
    pub z: Option<T>,
}
fn none<T>() -> Option<T> {
    None
}
impl<T> Default for PerAxis<T> {
    fn default() -> Self {
        Self {
            x: None,
            y: None,
            z: None,
        }
    }
}
impl<T> PerAxis<T> {
    pub fn get(&self, axis: usize) -> Option<&T> {
        match axis {
            0 => self.x.as_ref(),
            1 => self.y.as_ref(),
            _ => self.z.as_ref(),
        }
    }
}

/// Physics the visible model does not know about. Every effect is off unless configured.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct HiddenConfig {
    #[serde(default)]
    pub backlash: PerAxis<crate::physics::mechanics::BacklashConfig>,
    #[serde(default)]
    pub cyclic: PerAxis<crate::physics::mechanics::CyclicConfig>,
    #[serde(default)]
    pub thermal: Option<crate::physics::thermal::ThermalConfig>,
    #[serde(default)]
    pub cutting: Option<crate::physics::cutting::CuttingConfig>,
    /// White noise on the recorded tool-tip error (the measuring instrument), 1 σ.
    #[serde(default)]
    pub error_noise_um: f64,
}

/// A sensor fault on demand, on one output channel (`T_<name>_C`, `F_<name>_N`, `strain_<name>_ue`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FaultConfig {
    pub channel: String,
    pub kind: crate::physics::faults::FaultKind,
    pub from_s: f64,
    #[serde(default = "d_inf")]
    pub to_s: f64,
    /// Spikes: size added to the reading.
    #[serde(default)]
    pub spike_size: f64,
    /// Spikes: mean interval between spikes (Poisson, seeded).
    #[serde(default = "d_spike_every")]
    pub spike_every_s: f64,
}
fn d_inf() -> f64 {
    f64::INFINITY
}
fn d_spike_every() -> f64 {
    1.0
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RecordConfig {
    /// Recording interval (a multiple of the servo period is exact; otherwise the next tick is used).
    #[serde(default = "d_every")]
    pub every_s: f64,
    /// Value of the optional `run` column (block id).
    #[serde(default)]
    pub run: Option<i64>,
    /// Also record the applied correction per axis (`shift_x_um`, ...) as context columns.
    #[serde(default)]
    pub shift_columns: bool,
}
fn d_every() -> f64 {
    0.01
}
impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            every_s: d_every(),
            run: None,
            shift_columns: false,
        }
    }
}

impl SimConfig {
    /// Parse and validate a TOML config; `base_dir` resolves relative `gcode_path`s.
    pub fn from_toml_str(text: &str, base_dir: Option<&Path>) -> anyhow::Result<Self> {
        let mut cfg: SimConfig =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("config: {e}"))?;
        if let (Some(p), Some(base)) = (cfg.program.gcode_path.as_mut(), base_dir)
            && p.is_relative()
        {
            *p = base.join(&*p);
        }
        if let (Some(p), Some(base)) = (cfg.truth.model_path.as_mut(), base_dir)
            && p.is_relative()
        {
            *p = base.join(&*p);
        }
        cfg.validate()?;
        Ok(cfg)
    }

    pub fn from_toml_path(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("config {}: {e}", path.display()))?;
        let cfg = Self::from_toml_str(&text, path.parent())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        retrocomp_bus::modbus::warn_deprecated_spellings(&text, &path.display().to_string());
        Ok(cfg)
    }

    /// Range checks the parser cannot do. Each message names the key.
    pub fn validate(&self) -> anyhow::Result<()> {
        use anyhow::ensure;
        let c = &self.clock;
        ensure!(
            c.servo_hz.is_finite() && c.servo_hz > 0.0,
            "clock.servo_hz must be > 0, got {}",
            c.servo_hz
        );
        ensure!(c.max_duration_s > 0.0, "clock.max_duration_s must be > 0");
        ensure!(
            c.speed.is_finite() && (0.01..=1000.0).contains(&c.speed),
            "clock.speed must be 0.01..=1000 (simulated s per wall s), got {}",
            c.speed
        );
        if let Some(p) = c.realtime_priority {
            ensure!(
                (1..=99).contains(&p),
                "clock.realtime_priority must be 1..=99, got {p}"
            );
        }
        let s = &self.servo;
        ensure!(
            s.kv_per_s > 0.0,
            "servo.kv_per_s must be > 0, got {}",
            s.kv_per_s
        );
        ensure!(
            (0.0..=1.0).contains(&s.feedforward),
            "servo.feedforward must be in 0..=1"
        );
        ensure!(s.velocity_tau_s >= 0.0, "servo.velocity_tau_s must be >= 0");
        ensure!(s.count_um > 0.0, "servo.count_um must be > 0");
        ensure!(
            s.stiction_um >= 0.0 && s.coulomb_um >= 0.0 && s.coulomb_um <= s.stiction_um,
            "servo: need 0 <= coulomb_um <= stiction_um"
        );
        ensure!(
            s.max_speed_mm_s > 0.0 && s.rapid_mm_min > 0.0,
            "servo speeds must be > 0"
        );
        let p = &self.plc;
        ensure!(p.scan_s > 0.0, "plc.scan_s must be > 0, got {}", p.scan_s);
        ensure!(p.lsb_um > 0.0, "plc.lsb_um must be > 0, got {}", p.lsb_um);
        if let Some(w) = &p.watchdog {
            ensure!(
                w.timeout_s.is_finite() && w.timeout_s >= p.scan_s,
                "plc.watchdog.timeout_s must be >= plc.scan_s ({} s), got {}",
                p.scan_s,
                w.timeout_s
            );
            ensure!(
                w.ramp_um_per_s.is_finite() && w.ramp_um_per_s > 0.0,
                "plc.watchdog.ramp_um_per_s must be > 0, got {}",
                w.ramp_um_per_s
            );
            let words = u32::from(p.word.words());
            let shifts = u32::from(p.first_register)..u32::from(p.first_register) + 3 * words;
            let hb = u32::from(w.heartbeat_register);
            let on_handshake = p.handshake.as_ref().is_some_and(|h| {
                hb == u32::from(h.strobe_register) || hb == u32::from(h.ack_register)
            });
            ensure!(
                !shifts.contains(&hb) && !on_handshake,
                "plc.watchdog.heartbeat_register {hb} overlaps a shift, strobe or ack register"
            );
        }
        ensure!(self.record.every_s > 0.0, "record.every_s must be > 0");
        ensure!(
            self.truth.model_path.is_none()
                || self.truth.builtin == crate::truth::BuiltinGeometry::default(),
            "truth: give either `model_path` or `[truth.builtin]`, not both"
        );
        let sources = [
            self.program.gcode.is_some(),
            self.program.gcode_path.is_some(),
            !self.program.script.is_empty(),
        ];
        match &self.io.dnc {
            Some(d) => {
                ensure!(
                    !sources.contains(&true),
                    "program: with [io.dnc] the program arrives on the DNC input: no `gcode`, \
                     `gcode_path` or `script`"
                );
                d.validate()?;
            }
            None => ensure!(
                sources.iter().filter(|b| **b).count() == 1,
                "program: give exactly one of `gcode`, `gcode_path` or `script`"
            ),
        }
        for (i, w) in self.program.script.windows(2).enumerate() {
            ensure!(
                w[1].t_s > w[0].t_s,
                "program.script[{}]: t_s must increase ({} after {})",
                i + 1,
                w[1].t_s,
                w[0].t_s
            );
        }
        if let Some(t) = &self.hidden.thermal {
            t.validate()?;
        }
        if let (Some(can), Some(t)) = (&self.io.can, &self.hidden.thermal)
            && can.temp_node.is_some()
        {
            // The pre-defined connection set has TPDO1–4 per node, 4 int16 values each; a fifth
            // TPDO would share TPDO4's COB-ID.
            ensure!(
                t.sensors.len() <= crate::io::MAX_TEMPS_PER_NODE,
                "io.can.temp_node: hidden.thermal has {} sensors, a CiA 404 node sends at most {} (TPDO1–4 × 4 int16 values)",
                t.sensors.len(),
                crate::io::MAX_TEMPS_PER_NODE
            );
        }
        if let Some(c) = &self.hidden.cutting {
            c.validate(self.hidden.thermal.as_ref())?;
        }
        crate::io::transport_faults::validate(&self.io.faults)?;
        for (i, f) in self.faults.iter().enumerate() {
            ensure!(f.to_s >= f.from_s, "faults[{i}]: to_s must be >= from_s");
            ensure!(
                f.spike_every_s > 0.0,
                "faults[{i}]: spike_every_s must be > 0"
            );
        }
        Ok(())
    }

    pub fn dt_s(&self) -> f64 {
        1.0 / self.clock.servo_hz
    }
}
