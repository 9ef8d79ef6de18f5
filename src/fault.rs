//! The fault vocabulary every part reports in: what can be wrong ([`FaultKind`]) and a log that
//! reports each fault episode once when it starts and once when it clears (tracing), never every
//! cycle ([`FaultLog`]). It sits below the gateway, the sinks (`origin_shift`, `quadrature`) and
//! `telemetry` so all of them can use it without importing upward.
//!
//! A fault's `source` names who reports it (`sink.origin_shift.x`, `modbus.plc`, a channel name);
//! times are seconds on the gateway's clock (`_s`).

use std::collections::BTreeMap;

use serde::Serialize;

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    Stale,
    OutOfRange,
    NotFinite,
    RateOfChange,
    Stuck,
    Decode,
    /// A link is down (transport closed, no reply, interface down): a sink's controller or a
    /// source's bus, reported by that sink or source, not a channel.
    Disconnected,
    /// A CAN controller is bus-off (error frames `CAN_ERR_BUSOFF`).
    BusOff,
    /// A CAN controller is error-passive (its error counters passed 127).
    ErrorPassive,
    /// CAN error frames arrived within the last `gateway::health::BUS_ERROR_HOLD_S`.
    BusErrors,
    /// A Modbus device answered a request with an exception.
    Exception,
    /// A sink's request was refused (Modbus exception), failed, or was not acknowledged/read back.
    WriteFailed,
    /// The controller holds a correction beyond the clamp: the sink does not write that axis.
    BeyondClamp,
}

impl FaultKind {
    pub const ALL: [FaultKind; 13] = [
        FaultKind::Stale,
        FaultKind::OutOfRange,
        FaultKind::NotFinite,
        FaultKind::RateOfChange,
        FaultKind::Stuck,
        FaultKind::Decode,
        FaultKind::Disconnected,
        FaultKind::BusOff,
        FaultKind::ErrorPassive,
        FaultKind::BusErrors,
        FaultKind::Exception,
        FaultKind::WriteFailed,
        FaultKind::BeyondClamp,
    ];
}

/// Transition of one fault, for logs and tests.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaultEvent {
    pub source: String,
    pub kind: FaultKind,
    pub started: bool,
    pub t_s: f64,
}

/// Remembers which faults are active so each is logged once when it starts and once when it clears.
#[derive(Clone, Debug, Default)]
pub struct FaultLog {
    active: BTreeMap<(String, FaultKind), f64>,
}

impl FaultLog {
    /// Reconcile the faults of `source` with `now_faults`; returns (and logs) only the changes.
    pub fn update(
        &mut self,
        source: &str,
        now_faults: &[FaultKind],
        now_s: f64,
    ) -> Vec<FaultEvent> {
        let mut events = Vec::new();
        for &kind in now_faults {
            let key = (source.to_string(), kind);
            if let std::collections::btree_map::Entry::Vacant(slot) = self.active.entry(key) {
                tracing::warn!(source, ?kind, t_s = now_s, "fault started");
                slot.insert(now_s);
                events.push(FaultEvent {
                    source: source.to_string(),
                    kind,
                    started: true,
                    t_s: now_s,
                });
            }
        }
        let cleared: Vec<(String, FaultKind)> = self
            .active
            .keys()
            .filter(|(s, k)| s == source && !now_faults.contains(k))
            .cloned()
            .collect();
        for key in cleared {
            let since = self.active.remove(&key).unwrap_or(now_s);
            tracing::info!(source, kind = ?key.1, t_s = now_s, lasted_s = now_s - since, "fault cleared");
            events.push(FaultEvent {
                source: key.0,
                kind: key.1,
                started: false,
                t_s: now_s,
            });
        }
        events
    }

    pub fn active(&self) -> impl Iterator<Item = (&str, FaultKind, f64)> {
        self.active.iter().map(|((s, k), t)| (s.as_str(), *k, *t))
    }
}
