//! Origin-shift output (Ni 1996 Fig. 3; Fanuc external work zero offset / machine zero point shift):
//! per-axis corrections written to the controller's offset registers over Modbus TCP or RTU.
//!
//! `map` (TOML register map, encoding, allow-list), `cycle` (sans-IO write/strobe/ack/read-back
//! state machine), [`crate::sinks::guard`] (the last-step check every output of the box passes),
//! `sink` (one write period: read, guard, write cycle; sans-IO), `client` (tokio-modbus shell:
//! per-request timeout, reconnect with backoff, start by reading the current values); or served:
//! `server` (tokio-modbus TCP/RTU server shell) around `served` (sans-IO periods: controller
//! writes, silence, stop, fault episodes) and `server_core` (sans-IO register image, clamp and
//! per-update cap). Units: µm; sign convention in `map`.

pub(crate) mod client;
pub(crate) mod cycle;
pub(crate) mod map;
pub(crate) mod served;
pub(crate) mod server;
pub(crate) mod server_core;
pub(crate) mod server_map;
pub(crate) mod sink;
pub(crate) mod sink_task;

pub use crate::sinks::guard::{GuardLimits, Verdict, WriteGuard};
pub use client::{ClientConfig, ClientError, OriginShiftClient, Transport};
pub use cycle::{Action, Outcome, Reply, WriteCycle};
pub use map::{
    AxisRegister, DataType, Handshake, MapError, RegisterMap, WordOrder, Words, WriteBlock,
    decode_value, encode_value,
};
pub use served::{Period, ServedSink, StopEnd};
pub use server::{OriginShiftServer, ServerConfig, ServerStartError, ServerTransport};
pub use server_core::{ServerCore, Update};
pub use server_map::{HeldRegister, PositionRegister, ServerMap, ServerMapError, WriteMarker};
pub use sink::{SinkAxis, SinkCore, SinkFaults};
pub use sink_task::{SinkSources, update_faults_of};
