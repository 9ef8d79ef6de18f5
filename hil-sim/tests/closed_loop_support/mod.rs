//! Configs and checks shared by the closed-loop harness tests (`closed_loop_*.rs`): the demo mill
//! of `tests/gateway_faults_hil.rs` (hidden geometry from `deploy/demo/mill-full.toml`, thermal and
//! cutting physics, a PLC window with strobe/ack handshake) and the gateway's field config with the
//! same clamps, dosing cap and channel limits, on in-process links instead of sockets.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use hil_sim::SimConfig;
use hil_sim::harness::{ClosedLoop, FaultEdge, ModelFactory, PlcWrite, StepTrace};
use retrocomp::gateway::config::FieldConfig;
use retrocomp::gateway::health::FaultKind;
use retrocomp::gateway::model_adapter::MachineModelAdapter;
use retrocomp::models::MachineModel;

pub(crate) const CLAMP_UM: f64 = 40.0;
pub(crate) const CLAMP_Y_UM: f64 = 5.0;
pub(crate) const CAP_UM: f64 = 1.0;
pub(crate) const LSB_UM: f64 = 0.5;
/// Registers of the shift words (x, y, z: int32 pairs at 0, 2, 4).
pub(crate) const VALUE_REGISTERS: std::ops::Range<u16> = 0..6;

pub(crate) fn truth_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/demo/mill-full.toml")
}

/// The sim config: `program` (G-code body between the header and M30), extra TOML (`[[faults]]`,
/// `[[io.faults]]`) appended. `quiet`: no sensor or force noise and no screw heating, so while the machine
/// dwells with the spindle off every input of the gateway, and so its target, is exactly constant.
pub(crate) fn sim_config(program: &str, quiet: bool, extra: &str) -> SimConfig {
    // Sensor noise of 0.08 °C on 0.1 °C CAN steps: a healthy reading never stays bit-identical for
    // 1 s (the stuck detector's time).
    let (sensor_noise, screw_rise, force_noise) = if quiet {
        (0.0, 0.0, 0.0)
    } else {
        (0.08, 0.15, 1.0)
    };
    let text = format!(
        r#"
seed = 5
[clock]
max_duration_s = 60.0

[program]
tool_mm = 100.0
start_mm = [0.0, 0.0, 5.0]
gcode = """
G90 G21
{program}
M30
"""

[servo]
ideal = true
count_um = 1.0

[plc]
scan_s = 0.004
word = "int32"
word_order = "high_first"
lsb_um = {LSB_UM}
first_register = 0
handshake = {{ strobe_register = 10, ack_register = 11 }}

[truth]
model_path = "{truth}"

[record]
every_s = 0.01

[hidden.thermal]
ambient_C = 20.0
ambient_drift_C_per_h = 0.0

[[hidden.thermal.nodes]]
name = "spindle"
tau_s = 8.0
rise_C_per_krpm = 2.0

[[hidden.thermal.nodes]]
name = "xscrew"
tau_s = 5.0
rise_C_per_mm_s = {{ x = {screw_rise} }}

[[hidden.thermal.sensors]]
name = "spindle"
node = "spindle"
tau_s = 0.2
noise_C = {sensor_noise}

[[hidden.thermal.sensors]]
name = "xscrew"
node = "xscrew"
tau_s = 0.2
noise_C = {sensor_noise}

[[hidden.thermal.sensors]]
name = "spindle2"
node = "spindle"
tau_s = 0.3
noise_C = {sensor_noise}

[[hidden.thermal.effects]]
kind = "growth"
node = "spindle"
axis = "z"
um_per_K = -6.0

[[hidden.thermal.effects]]
kind = "expansion"
node = "xscrew"
axis = "x"
ppm_per_K = 11.5

[hidden.cutting]
stock_top_z_mm = 0.0
kc_N_per_mm2 = 2000.0
teeth = 2.0
compliance_um_per_N = {{ x = 0.004, y = 0.003, z = -0.002 }}
force_name = "cut"
force_noise_N = {force_noise}

[io.can]
backend = "mem"
encoder_nodes = [1, 2, 3]
encoder_period_s = 0.002
temp_node = 10
temp_period_s = 0.05

[io.weighing]
pty_link = "unused-in-process"
period_s = 0.02
{extra}
"#,
        truth = truth_model().display(),
    );
    SimConfig::from_toml_str(&text, None).expect("sim config")
}

/// The origin-shift sink of [`field_config`]: the PLC window of the sim, strobe/ack handshake.
const ORIGIN_SHIFT_SINK: &str = r#"
[sink.origin_shift]
transport = { kind = "tcp", address = "127.0.0.1:9" }
write_period_ms = 10
reconnect_min_ms = 100
reconnect_max_ms = 5000

[sink.origin_shift.map]
[[sink.origin_shift.map.axis]]
axis = "x"
address = 0
kind = "int32"
lsb_um = 0.5
sign = 1
[[sink.origin_shift.map.axis]]
axis = "y"
address = 2
kind = "int32"
lsb_um = 0.5
sign = 1
[[sink.origin_shift.map.axis]]
axis = "z"
address = 4
kind = "int32"
lsb_um = 0.5
sign = 1
[sink.origin_shift.map.handshake]
strobe_address = 10
ack_address = 11
timeout_ms = 200
"#;

/// The quadrature sink: one count = the sim's feedback count (1 µm), RS-422 edge gap, 100 kHz.
const QUADRATURE_SINK: &str = r#"
[sink.quadrature]
axis = [
  { axis = "x", resolution_um = 1.0, count_sign = 1, min_edge_gap_ns = 400, max_inject_rate_hz = 100000.0 },
  { axis = "y", resolution_um = 1.0, count_sign = 1, min_edge_gap_ns = 400, max_inject_rate_hz = 100000.0 },
  { axis = "z", resolution_um = 1.0, count_sign = 1, min_edge_gap_ns = 400, max_inject_rate_hz = 100000.0 },
]
"#;

pub(crate) fn field_config() -> FieldConfig {
    field_config_with(ORIGIN_SHIFT_SINK)
}

/// The same gateway with the quadrature sink instead of the origin shift.
pub(crate) fn field_config_quadrature() -> FieldConfig {
    field_config_with(QUADRATURE_SINK)
}

fn field_config_with(sink: &str) -> FieldConfig {
    let axis = |name: &str, clamp: f64, lo: f64, hi: f64| {
        format!(
            r#"
[[axis]]
name = "{name}"
position_channel = "{name}_mm"
safety = {{ max_correction_um = {clamp}, max_change_um_per_cycle = {CAP_UM}, ramp_um_per_s = 400.0, stale_hold_s = 0.5 }}
[[channel]]
name = "{name}_mm"
min = {lo}
max = {hi}
stale_after_s = 0.1
"#
        )
    };
    let axes = axis("x", CLAMP_UM, -10.0, 220.0)
        + &axis("y", CLAMP_Y_UM, -10.0, 170.0)
        + &axis("z", CLAMP_UM, -20.0, 70.0);
    let text = format!(
        r#"
[gateway]
name = "harness"
cycle_ms = 5
thermal_period_s = 0.1
status_listen = "127.0.0.1:0"

[safety]
max_correction_um = {CLAMP_UM}
max_change_um_per_cycle = {CAP_UM}
ramp_um_per_s = 400.0
stale_hold_s = 0.5

[direction]
deadband_mm = 0.005
switch_time_s = 0.05
{axes}
[[channel]]
name = "T_spindle_C"
min = 5.0
max = 80.0
stale_after_s = 0.5
stuck_after_s = 1.0

[[channel]]
name = "T_spindle2_C"
min = 5.0
max = 80.0
stale_after_s = 0.5

[[channel]]
name = "T_xscrew_C"
min = 5.0
max = 80.0
stale_after_s = 0.5

[[channel]]
name = "F_cut_N"
min = -2000.0
max = 2000.0
stale_after_s = 0.5

[[recovery]]
target = "T_spindle_C"
neighbours = ["T_spindle2_C"]
coefficients = [0.0, 1.0]
fit_rms = 0.1

[can]
backend = "mem"

[canopen]
pdo_timeout_s = 0.2
encoder = [
  {{ channel = "x_mm", node_id = 1, counts_per_mm = 1000.0 }},
  {{ channel = "y_mm", node_id = 2, counts_per_mm = 1000.0 }},
  {{ channel = "z_mm", node_id = 3, counts_per_mm = 1000.0 }},
]
analog = [
  {{ channel = "T_spindle_C", node_id = 10, type = "int16", byte_offset = 0, decimal_digits = 1 }},
  {{ channel = "T_xscrew_C", node_id = 10, type = "int16", byte_offset = 2, decimal_digits = 1 }},
  {{ channel = "T_spindle2_C", node_id = 10, type = "int16", byte_offset = 4, decimal_digits = 1 }},
]

[serial]
[[serial.source]]
name = "scale"
device = "in-process"
format = {{ kind = "weighing", unit = "N" }}
channel = [ {{ name = "F_cut_N" }} ]

{sink}
"#
    );
    FieldConfig::parse(&text, Path::new("harness-field.toml")).expect("field config")
}

/// The gateway's model: the demo mill's full model (hil-sim's visible truth plus the thermal and
/// load terms), loaded afresh at every gateway start.
pub(crate) fn model_factory() -> ModelFactory {
    let model = MachineModel::from_toml_path(&truth_model()).expect("model");
    Box::new(move || Box::new(MachineModelAdapter::new(model.clone())))
}

pub(crate) fn closed_loop(sim: SimConfig) -> ClosedLoop {
    ClosedLoop::new(sim, field_config(), model_factory()).expect("harness")
}

/// The loop with the quadrature box between the engine and the controller's feedback.
pub(crate) fn closed_loop_quadrature(sim: SimConfig) -> ClosedLoop {
    ClosedLoop::new(sim, field_config_quadrature(), model_factory()).expect("harness")
}

pub(crate) fn clamp_of(axis: usize) -> f64 {
    if axis == 1 { CLAMP_Y_UM } else { CLAMP_UM }
}

/// Clamp and cap per write, against what the PLC applied when the write arrived: every value
/// register written is within the axis' clamp and within one cap of the applied shift.
pub(crate) fn assert_clamp_and_cap_per_write(writes: &[PlcWrite]) {
    let mut values = 0;
    for w in writes
        .iter()
        .filter(|w| VALUE_REGISTERS.contains(&w.address))
    {
        values += 1;
        for k in 0..3 {
            let v = w.registers_um[k];
            assert!(v.abs() <= clamp_of(k), "beyond the clamp: {w:?}");
            assert!(
                (v - w.applied_um[k]).abs() <= CAP_UM,
                "a write more than the cap from what the PLC applies: {w:?}"
            );
        }
    }
    assert!(values > 100, "only {values} value writes");
}

/// No jump: the applied shift moves by at most one cap between consecutive steps, except at the
/// steps listed in `foreign` (a foreign writer's latch).
pub(crate) fn assert_no_jump(trace: &[StepTrace], foreign: &[f64]) {
    for p in trace.windows(2) {
        if foreign.iter().any(|t| (p[1].t_s - t).abs() < 1e-9) {
            continue;
        }
        for k in 0..3 {
            let d = (p[1].applied_um[k] - p[0].applied_um[k]).abs();
            assert!(d <= CAP_UM, "applied shift jumped by {d} µm: {p:?}");
        }
    }
}

/// The first sink period at or after `t_s` (periods at whole multiples of `period_s`).
pub(crate) fn period_at_or_after(t_s: f64, period_s: f64) -> f64 {
    (t_s / period_s - 1e-9).ceil() * period_s
}

/// `v` rounded to the register's resolution, µm.
pub(crate) fn lsb_round(v: f64) -> f64 {
    (v / LSB_UM).round() * LSB_UM
}

/// Steps of the trace at or after `t_s`.
pub(crate) fn from(trace: &[StepTrace], t_s: f64) -> impl Iterator<Item = &StepTrace> {
    trace.iter().filter(move |r| r.t_s >= t_s - 1e-9)
}

/// Edges of (source, kind) in order.
pub(crate) fn edges<'a>(h: &'a ClosedLoop, source: &str, kind: FaultKind) -> Vec<&'a FaultEdge> {
    h.fault_edges()
        .iter()
        .filter(|e| e.source == source && e.kind == kind)
        .collect()
}

/// One start and one clear of (source, kind); returns their times.
pub(crate) fn one_episode(h: &ClosedLoop, source: &str, kind: FaultKind) -> (f64, f64) {
    let e = edges(h, source, kind);
    assert_eq!(e.len(), 2, "{source} {kind:?}: {e:?}");
    assert!(e[0].started && !e[1].started, "{e:?}");
    (e[0].t_s, e[1].t_s)
}

pub(crate) fn assert_at(t: f64, expected: f64, what: &str) {
    assert!(
        (t - expected).abs() < 1e-9,
        "{what} at {t} s, expected {expected} s"
    );
}

/// Engine cycle times in `[a, b]`, as the world's clock gives them (every `cycle_ms` of steps).
pub(crate) fn cycles_in(h: &ClosedLoop, a: f64, b: f64) -> impl Iterator<Item = f64> {
    let (cycle, _) = h.periods_s();
    let dt = h.world().config().dt_s();
    let every = (cycle / dt).round() as usize;
    h.trace()
        .iter()
        .enumerate()
        .filter(move |(i, _)| (i + 1) % every == 0)
        .map(|(_, r)| r.t_s)
        .filter(move |t| *t >= a - 1e-9 && *t <= b + 1e-9)
}

/// The world's time at the step closest to `t_s` (the exact float the gateway saw).
pub(crate) fn step_time(h: &ClosedLoop, t_s: f64) -> f64 {
    h.trace()
        .iter()
        .map(|r| r.t_s)
        .min_by(|a, b| (a - t_s).abs().total_cmp(&(b - t_s).abs()))
        .unwrap()
}
