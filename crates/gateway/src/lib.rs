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
//! - [`gateway_core`]: the same parts composed sans-IO, time passed in ([`gateway_core::CycleCore`]
//!   is the cycle the runtime runs; [`gateway_core::GatewayCore`] is what the closed-loop harness
//!   drives);
//! - [`run`], [`cycle`], [`supervise`] and `servers`: the thin tokio runtime that wires them;
//!   [`status`] is the snapshot every consumer reads; [`error`] the runtime's error.
//!
//! Signs and units: correction = −error, µm; positions mm (see each module).
//!
//! Every numeric conversion that could truncate, wrap or lose a sign is a `try_from`, or an `as`
//! after a clamp or check with its reason beside it (these lints are errors in CI); float
//! comparisons say what they compare. Tests compare floats exactly where the value is exact.
#![warn(
    unreachable_pub,
    unnameable_types,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]
#![cfg_attr(
    test,
    allow(
        clippy::float_cmp,
        reason = "tests assert values that are exact in binary (caps, clamps, sums of halves)"
    )
)]

pub mod config;
pub mod cycle;
pub mod engine;
pub mod error;
pub mod gateway_core;
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
pub use engine::recovery::{NeighbourEstimate, RecoveryError};
pub use engine::safety::{AxisSafety, Input, Mode, SafetyConfig, SafetyError};
pub use engine::{AxisErrors, Engine, ErrorModel, MachineState, TermError};
pub use status::{AxisStatus, SinkStatus, SourceStatus, StatusSnapshot};
