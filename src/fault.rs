//! The fault vocabulary every part reports in: what can be wrong ([`FaultKind`]), who reports it
//! ([`FaultSource`]) and a log that reports each fault episode once when it starts and once when
//! it clears (tracing), never every cycle ([`FaultLog`]). It sits below the gateway, the sinks
//! (`origin_shift`, `quadrature`) and `telemetry` so all of them can use it without importing
//! upward.
//!
//! A fault's source is a typed identity (a channel, the model, an axis' compensation) or a name
//! built once at start (`sink.origin_shift.x`, `modbus.plc`); it prints as the names status,
//! metrics and logs have always shown. Reconciling a source's faults allocates nothing unless a
//! fault starts or clears (the cycle path calls it per channel per cycle). Times are seconds on the
//! gateway's clock (`_s`).

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;

use serde::Serialize;

use crate::bus::ChannelId;
use crate::models::Axis;

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

/// Who reports a fault. Prints as its name in status, metrics and logs.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FaultSource {
    /// A sensor channel: its configured name.
    Channel(ChannelId),
    /// The model's evaluation: `model`.
    Model,
    /// Compensation enabled but the axis not tracking its target: `compensation.<axis>`.
    Compensation(Axis),
    /// The axis compensating without the terms of a lost auxiliary input:
    /// `compensation.<axis>.partial`.
    CompensationPartial(Axis),
    /// Any other reporter, named once at start: a bus source (`can`, `modbus.<name>`), a sink
    /// (`sink.origin_shift`, `sink.origin_shift.<axis>`). Cloning it is a reference count.
    Named(Arc<str>),
}

impl FaultSource {
    /// A named source (allocates: build it once, at start).
    pub fn named(name: &str) -> Self {
        FaultSource::Named(Arc::from(name))
    }
}

impl From<&str> for FaultSource {
    fn from(name: &str) -> Self {
        FaultSource::named(name)
    }
}

impl fmt::Display for FaultSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FaultSource::Channel(id) => f.write_str(id.name()),
            FaultSource::Model => f.write_str("model"),
            FaultSource::Compensation(a) => write!(f, "compensation.{a}"),
            FaultSource::CompensationPartial(a) => write!(f, "compensation.{a}.partial"),
            FaultSource::Named(n) => f.write_str(n),
        }
    }
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
    active: BTreeMap<(FaultSource, FaultKind), f64>,
}

impl FaultLog {
    /// Reconcile the faults of `source` with `now_faults`; returns (and logs) only the changes.
    /// Allocates only for a change (a fault starting or clearing).
    pub fn update(
        &mut self,
        source: &FaultSource,
        now_faults: &[FaultKind],
        now_s: f64,
    ) -> Vec<FaultEvent> {
        let mut events = Vec::new();
        for &kind in now_faults {
            // Cloning the source is a copy or a reference count, never an allocation.
            if let std::collections::btree_map::Entry::Vacant(slot) =
                self.active.entry((source.clone(), kind))
            {
                slot.insert(now_s);
                let name = source.to_string();
                tracing::warn!(source = name.as_str(), ?kind, t_s = now_s, "fault started");
                events.push(FaultEvent {
                    source: name,
                    kind,
                    started: true,
                    t_s: now_s,
                });
            }
        }
        // This source's active kinds that are no longer reported (at most one per kind, on the
        // stack).
        let mut cleared = [None; FaultKind::ALL.len()];
        let first = (source.clone(), FaultKind::ALL[0]);
        let last = (source.clone(), FaultKind::ALL[FaultKind::ALL.len() - 1]);
        for (slot, ((_, kind), _)) in cleared.iter_mut().zip(
            self.active
                .range(first..=last)
                .filter(|((_, k), _)| !now_faults.contains(k)),
        ) {
            *slot = Some(*kind);
        }
        for kind in cleared.into_iter().flatten() {
            let since = self.active.remove(&(source.clone(), kind)).unwrap_or(now_s);
            let name = source.to_string();
            tracing::info!(
                source = name.as_str(),
                ?kind,
                t_s = now_s,
                lasted_s = now_s - since,
                "fault cleared"
            );
            events.push(FaultEvent {
                source: name,
                kind,
                started: false,
                t_s: now_s,
            });
        }
        events
    }

    /// The active faults: (source, kind, since t_s), ordered by source identity then kind.
    pub fn active(&self) -> impl Iterator<Item = (&FaultSource, FaultKind, f64)> {
        self.active.iter().map(|((s, k), t)| (s, *k, *t))
    }

    /// The active faults by source name (then kind), names printed: for status and metrics.
    pub fn active_by_name(&self) -> Vec<(String, FaultKind, f64)> {
        let mut out: Vec<(String, FaultKind, f64)> = self
            .active()
            .map(|(s, k, t)| (s.to_string(), k, t))
            .collect();
        out.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
        out
    }
}
