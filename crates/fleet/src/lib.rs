//! retrocomp's plant side: [`FleetView`] is a Sparkplug B host for many boxes (alive/compensating/
//! degraded per [`Node`] from its messages, rebirth requests for nodes it has no birth for),
//! [`FleetClient`] its MQTT shell, [`drift`] the scheduled diagnosis of each machine's recordings
//! against its own model, [`dispatch`] that diagnosis shared out to many [`worker`] processes,
//! [`LatencyHistogram`] the end-to-end latency of the data a host receives, [`load`] simulated
//! boxes and a host's totals for the fleet load benches. The box's side of the protocol (the edge
//! node, the payload codec) is
//! `retrocomp_gateway::northbound::telemetry`. Units as in the status snapshot: µm for corrections
//! (correction = −error), mm for positions; timestamps ms since the Unix epoch.
//!
//! Every numeric conversion that could truncate, wrap or lose a sign is a `try_from`, or an `as`
//! after a clamp or check with its reason beside it (these lints are errors in CI).
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
        reason = "tests assert values that are exact in binary or parsed from the same decimal text"
    )
)]

// Namespaces of functions and protocol constants (`drift::judge`, `worker::run`,
// `dispatch::JOBS`) stay public modules; the host's types are re-exported here from private ones.
pub mod dispatch;
pub mod drift;
pub mod load;
pub mod worker;

mod fleet;
mod fleet_client;
mod latency;
mod node;

pub use fleet::{DEFAULT_REBIRTH_INTERVAL_MS, FleetView, rebirth_request};
pub use fleet_client::{FleetClient, FleetClientError};
pub use latency::{LatencyHistogram, LatencySummary};
pub use node::{Node, Verdict};
