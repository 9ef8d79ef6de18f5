//! The run of `gateway_faults_rtu_hil`: the same machine, physics, clamps and dosing cap as
//! `gateway_faults_hil` (`faults_hil_configs.rs`), shorter, with the spindle temperature
//! `T_spindle_C` read over Modbus RTU from hil-sim's pty instead of CAN, and one transport fault:
//! `modbus_rtu_down` (the RTU slave mute) mid-run. Times are simulated seconds.

use std::path::Path;

use crate::configs::{field_toml, sim_io_toml, sim_machine_toml};

/// Out-and-back strokes of 3 s each after the 1 s dwell: the program ends (M30) at ≈ 19.5 s.
pub(crate) const STROKES: usize = 3;
/// The RTU slave mute: the spindle has warmed by ≈ 3.5 °C (Z ≈ −20 µm thermal) and keeps warming.
pub(crate) const RTU_DOWN: (f64, f64) = (7.0, 10.0);
/// The `[[modbus.source]]` of `T_spindle_C` (one copy, shared with the virtual-time twin).
const RTU_SOURCE: &str = include_str!("../fixtures/faults_hil/rtu_source.toml");
/// The poller: a poll every 50 ms, 200 ms reply timeout, 100–400 ms before the port is reopened
/// (as `rtu_source.toml` says; checked when the config is made).
pub(crate) const RTU_PERIOD_S: f64 = 0.05;
pub(crate) const RTU_TIMEOUT_S: f64 = 0.2;
pub(crate) const RTU_BACKOFF_S: (f64, f64) = (0.1, 0.4);

/// hil-sim: the machine of `gateway_faults_hil` plus Modbus RTU (the PT100 block as input registers
/// 0.. in sensor order: spindle, xscrew, spindle2; int16, 0.1 °C) and the `modbus_rtu_down` window.
pub(crate) fn sim_toml(hub_port: u16, weigh_link: &Path, rtu_link: &Path, truth: &Path) -> String {
    sim_machine_toml(STROKES, truth)
        + &format!(
            r#"
{io}
[[io.faults]]
kind = "modbus_rtu_down"
from_s = {d0}
to_s = {d1}
"#,
            io = sim_io_toml(hub_port, weigh_link, Some(rtu_link)),
            d0 = RTU_DOWN.0,
            d1 = RTU_DOWN.1,
        )
}

/// The gateway: `gateway_faults_hil`'s field config with `T_spindle_C` moved from the CiA 404 PDO
/// to a `[[modbus.source]]` on the RTU pty (its neighbour `T_spindle2_C` stays on CAN, so the
/// `[[recovery]]` estimate can stand in while the slave is mute).
pub(crate) fn field_toml_rtu(hub_port: u16, plc: &str, weigh_pty: &Path, rtu_dev: &Path) -> String {
    let base = field_toml(hub_port, plc, weigh_pty);
    let can_line = "  { channel = \"T_spindle_C\", node_id = 10, type = \"int16\", byte_offset = 0, decimal_digits = 1 },\n";
    assert!(
        base.contains(can_line),
        "faults_hil_configs.rs changed: T_spindle_C's CAN mapping not found"
    );
    let (b0, b1) = RTU_BACKOFF_S;
    for key in [
        format!("period_s = {RTU_PERIOD_S}\n"),
        format!("timeout_s = {RTU_TIMEOUT_S}\n"),
        format!("backoff_min_s = {b0}\n"),
        format!("backoff_max_s = {b1}\n"),
    ] {
        assert!(RTU_SOURCE.contains(&key), "rtu_source.toml changed: {key}");
    }
    base.replace(can_line, "") + &RTU_SOURCE.replace("@RTU_DEVICE@", &rtu_dev.display().to_string())
}
