//! The link-down fault and the publisher's state in every gateway status snapshot
//! ([`TelemetryAnnotator`], owned by the cycle loop). Times are the snapshot's `t_s`, s.

use super::status::TelemetryStatus;
use crate::status::StatusSnapshot;
use retrocomp_bus::fault::FaultKind;

/// The fault-log source of the publisher's link (`telemetry.mqtt:disconnected`).
pub(crate) const SOURCE: &str = "telemetry.mqtt";

/// Copies the publisher's state into each status snapshot; owned by the cycle loop (which builds
/// the snapshots, at ≤ 10 Hz), so it only reads a watch channel.
#[derive(Debug)]
pub struct TelemetryAnnotator {
    status: tokio::sync::watch::Receiver<TelemetryStatus>,
    /// Since when (status `t_s`) the link is not up: the `Disconnected` fault's start.
    down_since_s: Option<f64>,
}

impl TelemetryAnnotator {
    pub fn new(status: tokio::sync::watch::Receiver<TelemetryStatus>) -> Self {
        TelemetryAnnotator {
            status,
            down_since_s: None,
        }
    }

    /// Put the publisher's state into a status snapshot: `telemetry`, and a `Disconnected`
    /// fault of source `telemetry.mqtt` while the link is not up.
    pub fn annotate(&mut self, snap: &mut StatusSnapshot) {
        let st = self.status.borrow().clone();
        if st.connected {
            self.down_since_s = None;
        } else {
            let since = *self.down_since_s.get_or_insert(snap.t_s);
            snap.active_faults
                .push((SOURCE.into(), FaultKind::Disconnected, since));
        }
        snap.telemetry = Some(st);
    }
}
