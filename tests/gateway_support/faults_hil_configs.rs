//! The run of `gateway_faults_hil`: the fault script (simulated seconds), hil-sim's config (the demo
//! mill with a second spindle sensor, sensor faults and `[[io.faults]]`) and the gateway's field
//! config (clamps, dosing cap, channel limits, the spindle sensor's neighbour estimate).

use std::path::Path;

pub(crate) const CLAMP_UM: f64 = 40.0;
pub(crate) const CLAMP_Y_UM: f64 = 5.0;
pub(crate) const CAP_UM: f64 = 1.0;
pub(crate) const LSB_UM: f64 = 0.5;
/// How close the applied correction must come back to the ideal one after a fault clears, µm.
pub(crate) const TOL_UM: f64 = 5.0;
/// Time allowed to come back after a fault clears (ramp at the dosing cap, PLC scan), s.
pub(crate) const SETTLE_S: f64 = 1.0;

pub(crate) const MODBUS_DOWN: (f64, f64) = (5.0, 7.0);
pub(crate) const CAN_SILENT: (f64, f64) = (9.0, 10.5);
pub(crate) const T_STUCK: (f64, f64) = (12.0, 14.0);
pub(crate) const T_NAN: (f64, f64) = (14.0, 15.5);
pub(crate) const GARBAGE: (f64, f64) = (17.5, 20.0);
pub(crate) const KILL_AT_S: f64 = 22.0;
pub(crate) const TERM_AT_S: f64 = 25.5;

/// The demo mill's machine, the gateway's limits and the PLC window, shared with hil-sim's
/// in-process harness (`hil-sim/tests/closed_loop_support`): one copy, in `tests/fixtures/faults_hil`.
pub(crate) const FIXTURE_SIM: &str = include_str!("../fixtures/faults_hil/sim.toml");
pub(crate) const FIXTURE_FIELD: &str = include_str!("../fixtures/faults_hil/field.toml");
pub(crate) const FIXTURE_MAP: &str = include_str!("../fixtures/faults_hil/origin_shift_map.toml");

/// `[opcua.identification]` of the test machine (OPC 40501-1's mandatory properties), to follow
/// an `[opcua]` section.
pub(crate) const OPCUA_IDENT: &str = "[opcua.identification]\nmanufacturer = \"retrocomp test rig\"\n\
    serial_number = \"faults-hil-1\"\nproduct_instance_uri = \"urn:retrocomp:test:faults-hil-1\"\n";

pub(crate) fn sim_toml(hub_port: u16, pty_link: &Path, truth: &Path) -> String {
    sim_machine_toml(5, truth) + &sim_faults_and_io_toml(hub_port, pty_link)
}

/// The simulated machine (clock, program of `strokes` out-and-back strokes of 3 s each after a 1 s
/// dwell, PLC, truth model, hidden thermal and cutting physics), without sensor faults or I/O.
pub(crate) fn sim_machine_toml(strokes: usize, truth: &Path) -> String {
    let strokes = "G1 X150 Y100\nG1 X0 Y0\n".repeat(strokes);
    format!(
        r#"
seed = 5
[clock]
realtime = true
max_duration_s = 60.0
# The machine keeps its pace on a busy host (SCHED_FIFO when allowed; issue 18.5).
realtime_priority = 20

[program]
tool_mm = 100.0
start_mm = [0.0, 0.0, 5.0]
gcode = """
G90 G21
G4 P1.0
S3000 M3
G1 F3600
{strokes}M5
M30
"""

[truth]
model_path = "{truth}"
{FIXTURE_SIM}"#,
        truth = truth.display(),
    )
}

fn sim_faults_and_io_toml(hub_port: u16, pty_link: &Path) -> String {
    format!(
        r#"
[[faults]]
channel = "T_spindle_C"
kind = "stuck"
from_s = {stuck0}
to_s = {stuck1}

[[faults]]
channel = "T_spindle_C"
kind = "nan"
from_s = {nan0}
to_s = {nan1}

{io}
[[io.faults]]
kind = "modbus_down"
from_s = {mb0}
to_s = {mb1}

[[io.faults]]
kind = "can_node_silent"
node = 1
from_s = {can0}
to_s = {can1}

[[io.faults]]
kind = "serial_garbage"
from_s = {g0}
to_s = {g1}
"#,
        io = sim_io_toml(hub_port, pty_link, None),
        stuck0 = T_STUCK.0,
        stuck1 = T_STUCK.1,
        nan0 = T_NAN.0,
        nan1 = T_NAN.1,
        mb0 = MODBUS_DOWN.0,
        mb1 = MODBUS_DOWN.1,
        can0 = CAN_SILENT.0,
        can1 = CAN_SILENT.1,
        g0 = GARBAGE.0,
        g1 = GARBAGE.1,
    )
}

/// hil-sim's recording and transports: CAN through the hub at `hub_port` (three encoder nodes,
/// the PT100 block on node 10), the PLC on Modbus TCP (an ephemeral port hil-sim prints), weighing
/// lines on the pty `weigh_link`, and, with `rtu_link`, the PT100 block also as input registers
/// 0.. of RTU slave 1 on that pty.
pub(crate) fn sim_io_toml(hub_port: u16, weigh_link: &Path, rtu_link: Option<&Path>) -> String {
    let rtu = rtu_link.map_or(String::new(), |l| {
        format!(
            "rtu_pty_link = \"{}\"\nrtu_slave = 1\ntemps_first_input = 0\n",
            l.display()
        )
    });
    format!(
        r#"[record]
every_s = 0.01
shift_columns = true

[io.can]
backend = "socketcand"
host = "127.0.0.1"
port = {hub_port}
channel = "can0"
encoder_nodes = [1, 2, 3]
encoder_period_s = 0.002
temp_node = 10
temp_period_s = 0.05
heartbeat_period_s = 0.1

[io.modbus]
tcp_bind = "127.0.0.1:0"
{rtu}
[io.weighing]
pty_link = "{pty}"
period_s = 0.02
"#,
        pty = weigh_link.display(),
    )
}

pub(crate) fn field_toml(hub_port: u16, plc: &str, pty: &Path) -> String {
    let pty = pty.display();
    format!(
        r#"
[gateway]
name = "faults-hil"
cycle_ms = 5
# Cycle, sink and readers under SCHED_FIFO when allowed (issue 18.5; refused → normal scheduler).
realtime_priority = 20
# The SIGTERM restart must continue from what the PLC holds (gateway_watchdog_hil covers ramp-out).
on_stop = "hold"
thermal_period_s = 0.1
status_listen = "127.0.0.1:0"

{FIXTURE_FIELD}
[can]
backend = "socketcand"
host = "127.0.0.1"
port = {hub_port}
channel = "can0"

[serial]
[[serial.source]]
name = "scale"
device = "{pty}"
baud = 9600
format = {{ kind = "weighing", unit = "N" }}
channel = [ {{ name = "F_cut_N" }} ]

[sink.origin_shift]
transport = {{ kind = "tcp", address = "{plc}" }}
request_timeout_ms = 300
reconnect_min_ms = 20
reconnect_max_ms = 200
write_period_ms = 10

{FIXTURE_MAP}"#
    )
}
