//! CANopen (CiA 301) subset a retrofit gateway needs, sans-IO: NMT commands, heartbeat with timeout,
//! SDO expedited transfers, and decoding of CiA 406 encoder position TPDOs and CiA 404 analog values.
//!
//! Every decoder has its encoder, because the simulator (hil-sim) plays the encoders with the same code.
//! COB-IDs follow the CiA 301 pre-defined connection set: NMT 0x000, TPDO1..4 at 0x180/0x280/0x380/0x480
//! plus the node id, SDO client→server 0x600 + node, server→client 0x580 + node, heartbeat 0x700 + node.
//! Node ids are 1..=127. Multi-byte values are little-endian (CiA 301).

mod cia404;
mod cia406;
mod nmt;
mod sdo;
mod source;

pub use cia404::{AnalogChannel, AnalogType};
pub use cia406::{CountingDirection, EncoderChannel, PositionDecoder};
pub use nmt::{
    HeartbeatMonitor, NmtCommand, NodeState, decode_heartbeat, decode_nmt, encode_heartbeat,
    encode_nmt,
};
pub use sdo::{CYCLIC_TIMER_6200, SdoRequest, SdoResponse};
pub use source::{CanopenConfig, CanopenCounters, CanopenSource, run, run_observed};

/// A node id was outside 1..=127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("CANopen node id {0} is outside 1..=127")]
pub struct BadNodeId(pub u8);

/// Check a node id (1..=127).
pub fn node_id(n: u8) -> Result<u8, BadNodeId> {
    if (1..=127).contains(&n) {
        Ok(n)
    } else {
        Err(BadNodeId(n))
    }
}

/// COB-ID of TPDO `n` (1..=4) of `node` in the pre-defined connection set.
pub fn tpdo_cob_id(n: u8, node: u8) -> u16 {
    0x080 + 0x100 * u16::from(n.clamp(1, 4)) + u16::from(node)
}
