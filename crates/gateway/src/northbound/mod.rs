//! What the plant reads from the box: the HTTP status endpoint and its Prometheus text, the live
//! page (feature `web`), the OPC UA server (feature `opcua`) and the Sparkplug B edge node
//! (feature `mqtt`). Every server reads the status snapshots (`crate::status`) on its own tasks;
//! none can slow the cycle. Units as in the snapshot unless a module says otherwise (Prometheus:
//! base units).
//!
//! One spelling per state: every state (health, mode, fault kind, CAN bus state) is written as its
//! serde name (`ok`, `ramping_in`, `stale`, `bus_off`) in every API, JSON, Prometheus label or
//! text table alike ([`state_name`]); `http_spelling_tests.rs` reads every route and the page.

pub mod history;
pub mod http;
pub(crate) mod http_state;
pub mod opcua;
pub mod prometheus;
pub(crate) mod prometheus_text;
pub mod telemetry;
pub mod text;
#[cfg(feature = "web")]
pub mod web;

/// A state's one spelling: its serde name (`"ramping_in"` for a snake_case enum).
pub fn state_name<T: serde::Serialize>(v: &T) -> String {
    match serde_json::to_value(v) {
        Ok(serde_json::Value::String(s)) => s,
        other => format!("{other:?}"),
    }
}
