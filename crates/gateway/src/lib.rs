//! The gateway runtime: sources → state → model → safety → sinks. This module holds the sans-IO parts
//! (safety limits, direction latch, sensor health and recovery, field configuration, status) and the
//! thin async runtime that wires them to the buses.

pub mod config;
mod config_check;
mod config_limits;
pub mod cycle;
pub mod direction;
pub mod engine;
pub mod error;
pub mod error_model;
pub mod field_check;
pub mod guard;
pub mod health;
pub mod history;
pub mod http;
mod http_state;
pub mod model_adapter;
pub mod model_switch;
pub mod opcua;
pub mod origin_shift;
pub mod prometheus;
mod prometheus_text;
pub mod quadrature;
pub mod recovery;
pub mod run;
pub mod safety;
pub mod sink;
pub mod source_health;
pub mod sources;
pub mod status;
pub mod supervise;
pub mod telemetry;
pub mod unit_network;
#[cfg(feature = "web")]
pub mod web;

pub use direction::{DirectionConfig, DirectionLatch};
pub use engine::{AxisErrors, Engine, ErrorModel, MachineState, TermError};
pub use health::{ChannelLimits, ChannelMonitor, ChannelStatus, FaultEvent, FaultKind, FaultLog};
pub use recovery::NeighbourEstimate;
pub use safety::{AxisSafety, Input, Mode, SafetyConfig};
pub use status::{AxisStatus, SinkStatus, SourceStatus, StatusSnapshot};
