//! retrocomp's gateway crate: sources → engine → sinks, with the plant's servers beside them.
//!
//! - [`config`]: the field file (`FieldConfig`), refused at start with file, line and key when it
//!   cannot be safe;
//! - [`sources`]: the buses' tasks feeding samples to the cycle, and their health;
//! - [`engine`]: the sans-IO core (state, model, direction latch, sensor health and recovery,
//!   safety limits) that turns samples into a correction per axis;
//! - [`sinks`]: the output trait and the last-step guard every output passes, the origin-shift
//!   (Modbus client and server) and quadrature sinks;
//! - [`northbound`]: HTTP/Prometheus, the live page, OPC UA, Sparkplug;
//! - [`run`], [`cycle`], [`supervise`] and `servers`: the thin tokio runtime that wires them;
//!   [`status`] is the snapshot every consumer reads; [`error`] the runtime's error.
//!
//! Signs and units: correction = −error, µm; positions mm (see each module).

pub mod config;
pub mod cycle;
pub mod engine;
pub mod error;
pub mod northbound;
pub mod pacer;
pub mod run;
mod servers;
pub mod sinks;
pub mod sources;
pub mod status;
pub mod supervise;

pub use engine::direction::{DirectionConfig, DirectionLatch};
pub use engine::health::{
    ChannelLimits, ChannelMonitor, ChannelStatus, FaultEvent, FaultKind, FaultLog,
};
pub use engine::recovery::NeighbourEstimate;
pub use engine::safety::{AxisSafety, Input, Mode, SafetyConfig};
pub use engine::{AxisErrors, Engine, ErrorModel, MachineState, TermError};
pub use status::{AxisStatus, SinkStatus, SourceStatus, StatusSnapshot};
