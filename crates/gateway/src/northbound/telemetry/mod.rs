//! Telemetry of a box to the plant: Sparkplug B (Eclipse Sparkplug 3.0) over MQTT, so a shop of
//! retrofitted machines shows up in any Sparkplug host (Ignition, a `retrocomp fleet`, a stock
//! decoder). Layout: [`sparkplug`] (the protobuf payload, topics, bdSeq/seq: sans-IO),
//! `metrics` (a gateway status snapshot as named metrics, report by exception), `declare` (the
//! metric set of the NBIRTH, with units and ranges, from the field config and model), `queue`
//! (bounded store-and-forward queue, on disk), `config` (`[telemetry.mqtt]`), `publisher` (the
//! rumqttc shell fed from the gateway's status watch; it can never block the cycle), `retrocomp_fleet::FleetView` (the
//! host side: per box alive/compensating/degraded from its messages, for `retrocomp fleet`;
//! `retrocomp_fleet::FleetClient` is its MQTT shell), `rebirth` (the rate limit of rebirths, both sides),
//! [`recordings`] + `shipper` (a box's recording CSV to the fleet, chunked through the same queue;
//! collected per machine), `retrocomp_fleet::drift` (scheduled diagnose per machine against its own model). Units as in
//! the status: µm for corrections (correction = −error), mm for positions; timestamps ms since
//! the Unix epoch, taken when the snapshot was sampled.

pub(crate) mod annotate;
pub(crate) mod config;
#[cfg(feature = "mqtt")]
pub(crate) mod declare;
mod error;
#[cfg(feature = "mqtt")]
pub(crate) mod metrics;
#[cfg(feature = "mqtt")]
pub(crate) mod publisher;
#[cfg(feature = "mqtt")]
pub(crate) mod queue;
pub(crate) mod rebirth;
pub mod recordings;
#[cfg(feature = "mqtt")]
pub(crate) mod shipper;
#[cfg(feature = "mqtt")]
pub mod sparkplug;
pub(crate) mod status;
#[cfg(feature = "mqtt")]
pub mod tls;

pub use annotate::TelemetryAnnotator;
pub use config::{
    DropPolicy, MqttConfig, QueueConfig, TelemetrySection, TlsConfig, broker_host_port,
    demo_section,
};
#[cfg(feature = "mqtt")]
pub use declare::{Declaration, DeclaredAxis, DeclaredChannel, HEALTH_STATES, MODE_STATES};
pub use error::TelemetryError;
#[cfg(feature = "mqtt")]
pub use publisher::{Publisher, PublisherInputs, now_ms, spawn};
pub use rebirth::RebirthLimiter;
#[cfg(feature = "mqtt")]
pub use shipper::{ShipReport, Shipment, default_topic, ship};
pub use status::TelemetryStatus;
