//! Configs and checks shared by the closed-loop harness tests (`closed_loop_*.rs`): the demo mill
//! of `tests/real_peers/gateway_faults_hil.rs` (hidden geometry from `deploy/demo/mill-full.toml`, thermal and
//! cutting physics, a PLC window with strobe/ack handshake) and the gateway's field config with the
//! same clamps, dosing cap and channel limits (one copy: `tests/fixtures/faults_hil/`), on in-process
//! links instead of sockets.

use std::path::{Path, PathBuf};

use hil_sim::SimConfig;
use hil_sim::harness::{ClosedLoop, FaultEvent, ModelFactory, PlcWrite, StepTrace};
use retrocomp_gateway::FaultKind;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_model::MachineModel;

pub(crate) const CLAMP_UM: f64 = 40.0;
pub(crate) const CLAMP_Y_UM: f64 = 5.0;
pub(crate) const CAP_UM: f64 = 1.0;
pub(crate) const LSB_UM: f64 = 0.5;
/// Registers of the shift words (x, y, z: int32 pairs at 0, 2, 4).
pub(crate) const VALUE_REGISTERS: std::ops::Range<u16> = 0..6;

pub(crate) fn truth_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/demo/mill-full.toml")
}

/// The demo mill's machine, the gateway's limits and the PLC window: the one copy shared with the
/// real-socket fault runs (`tests/gateway_support/faults_hil_configs.rs`).
const FIXTURE_SIM: &str = include_str!("../../../tests/fixtures/faults_hil/sim.toml");
const FIXTURE_FIELD: &str = include_str!("../../../tests/fixtures/faults_hil/field.toml");
const FIXTURE_MAP: &str = include_str!("../../../tests/fixtures/faults_hil/origin_shift_map.toml");
const FIXTURE_RTU: &str = include_str!("../../../tests/fixtures/faults_hil/rtu_source.toml");

/// The sim config: `program` (G-code body between the header and M30), extra TOML (`[[faults]]`,
/// `[[io.faults]]`) appended. `quiet`: no sensor or force noise and no screw heating, so while the
/// machine dwells with the spindle off every input of the gateway, and so its target, is exactly
/// constant.
pub(crate) fn sim_config(program: &str, quiet: bool, extra: &str) -> SimConfig {
    let mut machine = FIXTURE_SIM.to_string();
    if quiet {
        for (noisy, still, n) in [
            ("noise_C = 0.08", "noise_C = 0.0", 3),
            (
                "rise_C_per_mm_s = { x = 0.15 }",
                "rise_C_per_mm_s = { x = 0.0 }",
                1,
            ),
            ("force_noise_N = 1.0", "force_noise_N = 0.0", 1),
        ] {
            assert_eq!(
                machine.matches(noisy).count(),
                n,
                "fixture changed: {noisy}"
            );
            machine = machine.replace(noisy, still);
        }
    }
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

[truth]
model_path = "{truth}"

[record]
every_s = 0.01
{machine}
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

/// The box as a Modbus server instead (`[sink.origin_shift_server]`): the PLC's master reads the
/// corrections (int32 at 0, 2, 4, the PLC's 0.5 µm) and writes what the PLC applies into the held
/// registers (20, 22, 24), then the write marker (26); updated every 10 ms, as the client sink
/// writes.
const SERVER_SINK: &str = r#"
[sink.origin_shift_server]
transport = { kind = "tcp", listen = "127.0.0.1:0" }
update_period_ms = 10
controller_timeout_ms = 1000

[sink.origin_shift_server.map]
heartbeat_address = 30
axis = [
  { axis = "x", address = 0, kind = "int32", lsb_um = 0.5, sign = 1 },
  { axis = "y", address = 2, kind = "int32", lsb_um = 0.5, sign = 1 },
  { axis = "z", address = 4, kind = "int32", lsb_um = 0.5, sign = 1 },
]
held = [{ axis = "x", address = 20 }, { axis = "y", address = 22 }, { axis = "z", address = 24 }]
write_marker = { address = 26, value = 21930 }
"#;

pub(crate) fn field_config() -> FieldConfig {
    field_config_with(&format!("{ORIGIN_SHIFT_SINK}\n{FIXTURE_MAP}"))
}

/// [`field_config`] with `T_spindle_C` read over Modbus RTU from the sim's slave instead of CAN
/// (`gateway_faults_rtu_hil`'s gateway; its neighbour `T_spindle2_C` stays on CAN).
pub(crate) fn field_config_rtu() -> FieldConfig {
    let can_line = "  { channel = \"T_spindle_C\", node_id = 10, type = \"int16\", byte_offset = 0, decimal_digits = 1 },\n";
    assert!(
        FIXTURE_FIELD.contains(can_line),
        "fixture changed: T_spindle_C on CAN"
    );
    let sink = format!(
        "{}\n{ORIGIN_SHIFT_SINK}\n{FIXTURE_MAP}",
        FIXTURE_RTU.replace("@RTU_DEVICE@", "in-process")
    );
    field_config_from(&FIXTURE_FIELD.replace(can_line, ""), &sink)
}

/// [`field_config`] with the box's heartbeat in the PLC window (`gateway_watchdog_hil`'s gateway:
/// register 12, the controller's rule armed with `timeout_ms`).
pub(crate) fn field_config_heartbeat(register: u16, timeout_ms: u64) -> FieldConfig {
    let map = "[sink.origin_shift.map]\n";
    assert!(FIXTURE_MAP.contains(map), "fixture changed: {map}");
    let with = FIXTURE_MAP.replace(
        map,
        &format!("{map}heartbeat_address = {register}\nheartbeat_timeout_ms = {timeout_ms}\n"),
    );
    field_config_with(&format!("{ORIGIN_SHIFT_SINK}\n{with}"))
}

/// The same gateway with the quadrature sink instead of the origin shift.
pub(crate) fn field_config_quadrature() -> FieldConfig {
    field_config_with(QUADRATURE_SINK)
}

fn field_config_with(sink: &str) -> FieldConfig {
    field_config_from(FIXTURE_FIELD, sink)
}

fn field_config_from(fixture_field: &str, sink: &str) -> FieldConfig {
    let text = format!(
        r#"
[gateway]
name = "harness"
cycle_ms = 5
thermal_period_s = 0.1
status_listen = "127.0.0.1:0"
{fixture_field}
[can]
backend = "mem"

[serial]
[[serial.source]]
name = "scale"
device = "in-process"
format = {{ kind = "weighing", unit = "N" }}
channel = [ {{ name = "F_cut_N" }} ]
{sink}
"#
    );
    let cfg = FieldConfig::parse(&text, Path::new("harness-field.toml")).expect("field config");
    // The constants the scenarios assert with are the fixture's numbers.
    for a in &cfg.axes {
        let s = cfg.safety_for(&a.name);
        let clamp = if a.name == "y" { CLAMP_Y_UM } else { CLAMP_UM };
        assert_eq!(
            (s.max_correction_um, s.max_change_um_per_cycle),
            (clamp, CAP_UM),
            "{}",
            a.name
        );
    }
    if let Some(os) = &cfg.sink.origin_shift {
        assert!(os.map.axes.iter().all(|r| r.lsb_um == LSB_UM));
    }
    cfg
}

/// The gateway's model: the demo mill's full model (hil-sim's visible truth plus the thermal and
/// load terms), loaded afresh at every gateway start.
pub(crate) fn model_factory() -> ModelFactory {
    let model = MachineModel::from_toml_path(&truth_model()).expect("model");
    Box::new(move || Box::new(MachineModelAdapter::new(model.clone())))
}

/// The loop with the box serving the corrections and the PLC's master polling it.
pub(crate) fn closed_loop_served(sim: SimConfig) -> ClosedLoop {
    let field = field_config_with(SERVER_SINK);
    ClosedLoop::new(sim, field, model_factory()).expect("harness")
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
pub(crate) fn edges<'a>(h: &'a ClosedLoop, source: &str, kind: FaultKind) -> Vec<&'a FaultEvent> {
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

/// Stationary phases: the spindle off, while the machine dwells (quiet config) the gateway's target
/// is exactly constant, so recovery is a count of capped writes.
pub(crate) const MOVES: &str = "G4 P0.5\nG1 X150 Y100 F3600\nG4 P3.0\nG1 X40 Y30\nG4 P6.0";
/// Spindle on, sensor noise on, strokes out and back: thermal and load terms move all the time.
pub(crate) const STROKES: &str =
    "S3000 M3\nG4 P0.5\nG1 X150 Y100 F3600\nG1 X0 Y0\nG1 X150 Y100\nG1 X0 Y0\nM5";
/// The spindle sensor stuck from 3.0 to 5.0 s, then NaN to 6.5 s.
pub(crate) const STUCK_THEN_NAN: &str = "[[faults]]\nchannel = \"T_spindle_C\"\nkind = \"stuck\"\nfrom_s = 3.0\nto_s = 5.0\n\
     [[faults]]\nchannel = \"T_spindle_C\"\nkind = \"nan\"\nfrom_s = 5.0\nto_s = 6.5\n";

/// CAN node `node` silent from `from_s` to `to_s`.
pub(crate) fn node_silent(node: u8, from_s: f64, to_s: f64) -> String {
    format!(
        "[[io.faults]]\nkind = \"can_node_silent\"\nnode = {node}\nfrom_s = {from_s}\nto_s = {to_s}\n"
    )
}

/// No compensation fault (dropped axis) was ever logged.
pub(crate) fn assert_compensation_never_dropped(h: &ClosedLoop) {
    assert!(
        h.fault_edges()
            .iter()
            .all(|e| !e.source.starts_with("compensation")),
        "{:?}",
        h.fault_edges()
    );
}
