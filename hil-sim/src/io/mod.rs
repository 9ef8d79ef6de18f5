//! Thin I/O shells that put the simulated machine on real transports, around a sans-IO publisher:
//! - CAN ([`retrocomp_bus::can`] backends: in-memory, socketcand hub/daemon, SocketCAN/vcan):
//!   CiA 406 encoder TPDOs (6004h, one node per axis) and CiA 404 temperatures (INT16, 0.1 °C, four per
//!   TPDO), plus CANopen heartbeats; encoder faults (`enc_x` …) silence or freeze an encoder's TPDO;
//! - Modbus TCP and RTU (on a pty), one register image ([`retrocomp_bus::modbus::RegisterBank`]): the PLC's
//!   origin-shift window as holding registers (FC03/06/16; the ack register is read-only), PT100
//!   temperatures as input registers (int16, 0.1 °C; 0x7FFF = NaN/over-range, 0x8000 = sensor break
//!   on dropout), the cutting force and the strain gauges as int32 input register pairs (hi word
//!   first, `force_lsb_N`, `strain_lsb_ue`; i32::MIN = no valid reading), the axis positions too
//!   (`positions_first_input`, int32 pairs in `position_lsb_um`);
//! - the force as ASCII weighing-indicator lines on a pty (`ST,GS,+00250.0N`; `OL` for NaN; silence on
//!   dropout);
//! - the controller's DNC input on a serial device (`dnc_port`, `[io.dnc]`): the program arrives
//!   as it runs, into a buffer of N lines with XON/XOFF;
//! - transport faults on a schedule (`transport_faults`): Modbus TCP down and back, the RTU slave
//!   mute and back (`rtu_slave`), a CAN node silent, garbage on the weighing line; every client write to the PLC window is logged
//!   (`plc_server`, `plc_writes.csv`).

mod dnc_port;
pub(crate) mod plc_server;
mod pty_link;
pub(crate) mod publish;
pub(crate) mod rtu_slave;
pub mod serve;
pub(crate) mod transport_faults;

pub use publish::{Outputs, PT100_BREAK, PT100_OVERRANGE, Publisher};
pub use transport_faults::{Transition, TransportFaultConfig, TransportFaultKind};

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Which buses `hil-sim serve` brings up (all optional).
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct IoConfig {
    #[serde(default)]
    pub modbus: Option<ModbusIoConfig>,
    #[serde(default)]
    pub can: Option<CanIoConfig>,
    #[serde(default)]
    pub weighing: Option<WeighingIoConfig>,
    /// The controller's DNC input: the program arrives on a serial device while it runs.
    #[serde(default)]
    pub dnc: Option<crate::controller::dnc::DncConfig>,
    /// Transport faults on a schedule (`[[io.faults]]`, see `transport_faults`).
    #[serde(default)]
    pub faults: Vec<TransportFaultConfig>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusIoConfig {
    /// Modbus TCP listen address (loopback in tests: `127.0.0.1:0` picks a free port).
    #[serde(default)]
    pub tcp_bind: Option<String>,
    /// Serve Modbus RTU on a pty; a symlink to its device is created at this path.
    #[serde(default)]
    pub rtu_pty_link: Option<PathBuf>,
    #[serde(default = "d_slave")]
    pub rtu_slave: u8,
    /// First input register of the PT100 block (one register per temperature sensor, config order).
    #[serde(default)]
    pub temps_first_input: u16,
    /// First input register of the int32 force pair (none: force not on Modbus).
    #[serde(default)]
    pub force_first_input: Option<u16>,
    #[serde(default = "d_force_lsb")]
    pub force_lsb_N: f64,
    /// First input register of the strain block: one int32 pair (hi word first) per gauge.
    #[serde(default)]
    pub strain_first_input: Option<u16>,
    /// First input register of the axis positions, X, Y, Z: one int32 pair (hi word first) each,
    /// the motor encoder's position (as a drive or a PLC exposes it) in `position_lsb_um`.
    #[serde(default)]
    pub positions_first_input: Option<u16>,
    #[serde(default = "d_position_lsb")]
    pub position_lsb_um: f64,
    #[serde(default = "d_strain_lsb")]
    pub strain_lsb_ue: f64,
}
fn d_position_lsb() -> f64 {
    1.0
}
fn d_strain_lsb() -> f64 {
    0.01
}
fn d_slave() -> u8 {
    1
}
fn d_force_lsb() -> f64 {
    0.1
}

/// Temperatures one CiA 404 node publishes: TPDO1–4 of the pre-defined connection set, 4 int16
/// values each (`Config::validate` refuses more on `io.can.temp_node`).
pub const MAX_TEMPS_PER_NODE: usize = 16;

/// CAN publishing. The backend keys are those of `retrocomp_bus::can::CanBackendConfig` (`backend = "mem" |
/// "socketcand" | "socketcan"`, with `host`/`port`/`channel` or `interface`).
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct CanIoConfig {
    #[serde(flatten)]
    pub backend: retrocomp_bus::can::CanBackendConfig,
    /// CiA 406 encoder node ids for x, y, z.
    #[serde(default = "d_nodes")]
    pub encoder_nodes: [u8; 3],
    /// TPDO1 event timer of the encoders (6200h), s.
    #[serde(default = "d_enc_period")]
    pub encoder_period_s: f64,
    /// What the encoders measure: the motor (semi-closed loop, the controller's own feedback) or the
    /// slide (a linear scale: sees backlash, lead error and expansion).
    #[serde(default)]
    pub encoder_source: EncoderSource,
    /// CiA 404 temperature module node id (none: temperatures not on CAN).
    #[serde(default)]
    pub temp_node: Option<u8>,
    #[serde(default = "d_temp_period")]
    pub temp_period_s: f64,
    /// CANopen heartbeat (1017h) of every simulated node, s (none: no heartbeats).
    #[serde(default)]
    pub heartbeat_period_s: Option<f64>,
}
fn d_nodes() -> [u8; 3] {
    [1, 2, 3]
}
fn d_enc_period() -> f64 {
    0.002
}
fn d_temp_period() -> f64 {
    0.1
}

#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum EncoderSource {
    #[default]
    Motor,
    Slide,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WeighingIoConfig {
    /// A symlink to the pty the lines are written to is created at this path.
    pub pty_link: PathBuf,
    #[serde(default = "d_weigh_period")]
    pub period_s: f64,
}
fn d_weigh_period() -> f64 {
    0.1
}
