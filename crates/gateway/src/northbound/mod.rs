//! What the plant reads from the box: the HTTP status endpoint and its Prometheus text, the live
//! page (feature `web`), the OPC UA server (feature `opcua`) and the Sparkplug B edge node
//! (feature `mqtt`). Every server reads the status snapshots (`crate::status`) on its own tasks;
//! none can slow the cycle. Units as in the snapshot unless a module says otherwise (Prometheus:
//! base units).

pub mod history;
pub mod http;
pub(crate) mod http_state;
pub mod opcua;
pub mod prometheus;
pub(crate) mod prometheus_text;
pub mod telemetry;
#[cfg(feature = "web")]
pub mod web;
