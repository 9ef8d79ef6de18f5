//! retrocomp's plant side: [`fleet`] is a Sparkplug B host for many boxes (alive/compensating/
//! degraded per box from its messages, rebirth requests for nodes it has no birth for),
//! [`fleet_client`] its MQTT shell, [`drift`] the scheduled diagnosis of each machine's recordings
//! against its own model, [`latency`] the end-to-end latency of the data a host receives, [`load`]
//! simulated boxes and a host's totals for the fleet load benches. The box's side of the protocol (the edge node, the payload codec) is
//! `retrocomp_gateway::northbound::telemetry`. Units as in the status snapshot: µm for corrections
//! (correction = −error), mm for positions; timestamps ms since the Unix epoch.

pub mod drift;
pub mod fleet;
pub mod fleet_client;
pub mod latency;
pub mod load;
