//! The publisher's own state as the gateway shows it: `telemetry` in `/status`, and
//! `retrocomp_telemetry_*` in `/metrics` (counts of records; no units). The type lives with the
//! status snapshot (`crate::status`), which embeds it; `annotate.rs` puts it (and the link-down
//! fault) into each snapshot; its Prometheus form is here.

pub use crate::status::TelemetryStatus;

impl TelemetryStatus {
    /// `retrocomp_telemetry_*` in the Prometheus text format (appended to the gateway's).
    pub fn prometheus(&self, s: &mut String) {
        use std::fmt::Write as _;
        let mut one = |name: &str, kind: &str, help: &str, v: u64| {
            let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {v}");
        };
        one(
            "retrocomp_telemetry_connected",
            "gauge",
            "1 when the MQTT link is up and NBIRTH was sent.",
            u64::from(self.connected),
        );
        one(
            "retrocomp_telemetry_queued",
            "gauge",
            "Telemetry records waiting for the broker's acknowledgement.",
            self.queued,
        );
        one(
            "retrocomp_telemetry_queued_bytes",
            "gauge",
            "Bytes of the queued telemetry records.",
            self.queued_bytes,
        );
        one(
            "retrocomp_telemetry_dropped_total",
            "counter",
            "Telemetry records dropped (queue full, by the drop policy).",
            self.dropped_total,
        );
        one(
            "retrocomp_telemetry_acked_total",
            "counter",
            "Telemetry records acknowledged by the broker.",
            self.acked_total,
        );
        one(
            "retrocomp_telemetry_births_total",
            "counter",
            "Sparkplug NBIRTHs sent (connects and rebirths).",
            self.births_total,
        );
    }
}
