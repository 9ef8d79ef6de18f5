//! retrocomp's plant side: [`fleet`] is a Sparkplug B host for many boxes (alive/compensating/
//! degraded per box from its messages, rebirth requests for nodes it has no birth for),
//! [`fleet_client`] its MQTT shell, [`drift`] the scheduled diagnosis of each machine's recordings
//! against its own model, [`dispatch`] that diagnosis shared out to many [`worker`] processes, [`latency`] the end-to-end latency of the data a host receives, [`load`]
//! simulated boxes and a host's totals for the fleet load benches. The box's side of the protocol (the edge node, the payload codec) is
//! `retrocomp_gateway::northbound::telemetry`. Units as in the status snapshot: µm for corrections
//! (correction = −error), mm for positions; timestamps ms since the Unix epoch.
//!
//! Every numeric conversion that could truncate, wrap or lose a sign is a `try_from`, or an `as`
//! after a clamp or check with its reason beside it (these lints are errors in CI).
#![warn(
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

pub mod dispatch;
pub mod drift;
pub mod fleet;
pub mod fleet_client;
pub mod latency;
pub mod load;
pub mod node;
pub mod worker;
