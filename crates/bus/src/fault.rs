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

use crate::ChannelId;

use serde::Serialize;

use retrocomp_model::Axis;

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
    /// A listener refuses or delays connections (connection caps, descriptor reserve, accept errors).
    Overloaded,
    /// A listener failed and is being restarted (cleared once it serves again).
    ListenerFailed,
    /// A peer not on the listener's `allow_writes_from` tried to write or act.
    Unauthorized,
    /// An optional model input that no configured source delivers: its terms stay out for as long
    /// as the box runs (a required one is refused at start instead).
    NoSource,
}

impl FaultKind {
    pub const ALL: [FaultKind; 17] = [
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
        FaultKind::Overloaded,
        FaultKind::ListenerFailed,
        FaultKind::Unauthorized,
        FaultKind::NoSource,
    ];

    /// Its position in [`FaultKind::ALL`] (declaration order, which is also its `Ord`).
    pub const fn index(self) -> usize {
        self as usize
    }

    /// Its one spelling, the serde name every API shows (`/status`, `/api/faults`, metrics'
    /// `kind` label, Sparkplug, OPC UA) and the log writes: `beyond_clamp`, not `BeyondClamp`.
    pub const fn as_str(self) -> &'static str {
        match self {
            FaultKind::Stale => "stale",
            FaultKind::OutOfRange => "out_of_range",
            FaultKind::NotFinite => "not_finite",
            FaultKind::RateOfChange => "rate_of_change",
            FaultKind::Stuck => "stuck",
            FaultKind::Decode => "decode",
            FaultKind::Disconnected => "disconnected",
            FaultKind::BusOff => "bus_off",
            FaultKind::ErrorPassive => "error_passive",
            FaultKind::BusErrors => "bus_errors",
            FaultKind::Exception => "exception",
            FaultKind::WriteFailed => "write_failed",
            FaultKind::BeyondClamp => "beyond_clamp",
            FaultKind::Overloaded => "overloaded",
            FaultKind::ListenerFailed => "listener_failed",
            FaultKind::Unauthorized => "unauthorized",
            FaultKind::NoSource => "no_source",
        }
    }
}

impl fmt::Display for FaultKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Who reports a fault. Prints as its name in status, metrics and logs.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FaultSource {
    /// A sensor channel: its id and configured name, from the engine's [`crate::ChannelTable`]
    /// (the id orders and compares, as cheaply as before names were shared; cloning the name is a
    /// reference count).
    Channel(ChannelId, Arc<str>),
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
            FaultSource::Channel(_, n) => f.write_str(n),
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
    /// Per source with at least one active fault: when each kind started (by [`FaultKind::index`]).
    /// One entry per source, so reconciling a source whose faults did not change is one lookup
    /// and a comparison (the cycle path does it per channel per cycle).
    active: BTreeMap<FaultSource, [Option<f64>; FaultKind::ALL.len()]>,
}

impl FaultLog {
    /// Reconcile the faults of `source` with `now_faults`; returns (and logs) only the changes:
    /// starts in the order of `now_faults`, then clears in kind order. Allocates only for a
    /// change (a fault starting or clearing).
    pub fn update(
        &mut self,
        source: &FaultSource,
        now_faults: &[FaultKind],
        now_s: f64,
    ) -> Vec<FaultEvent> {
        let mut now = [false; FaultKind::ALL.len()];
        for k in now_faults {
            now[k.index()] = true;
        }
        let since = match self.active.get_mut(source) {
            // No change: the steady state of every cycle, faulted or not.
            None if now_faults.is_empty() => return Vec::new(),
            Some(since) if since.iter().zip(&now).all(|(s, n)| s.is_some() == *n) => {
                return Vec::new();
            }
            Some(since) => since,
            // Cloning the source is a copy or a reference count, never an allocation.
            None => self
                .active
                .entry(source.clone())
                .or_insert([None; FaultKind::ALL.len()]),
        };
        let mut events = Vec::new();
        let name = source.to_string();
        for &kind in now_faults {
            let slot = &mut since[kind.index()];
            if slot.is_none() {
                *slot = Some(now_s);
                tracing::warn!(
                    source = name.as_str(),
                    kind = kind.as_str(),
                    t_s = now_s,
                    "fault started"
                );
                events.push(FaultEvent {
                    source: name.clone(),
                    kind,
                    started: true,
                    t_s: now_s,
                });
            }
        }
        for kind in FaultKind::ALL {
            if now[kind.index()] {
                continue;
            }
            if let Some(from_s) = since[kind.index()].take() {
                tracing::info!(
                    source = name.as_str(),
                    kind = kind.as_str(),
                    t_s = now_s,
                    lasted_s = now_s - from_s,
                    "fault cleared"
                );
                events.push(FaultEvent {
                    source: name.clone(),
                    kind,
                    started: false,
                    t_s: now_s,
                });
            }
        }
        if since.iter().all(Option::is_none) {
            self.active.remove(source);
        }
        events
    }

    /// The active faults: (source, kind, since t_s), ordered by source identity then kind.
    pub fn active(&self) -> impl Iterator<Item = (&FaultSource, FaultKind, f64)> {
        self.active.iter().flat_map(|(s, since)| {
            FaultKind::ALL
                .into_iter()
                .filter_map(move |k| since[k.index()].map(|t| (s, k, t)))
        })
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

#[cfg(test)]
mod tests {
    use super::*;

    fn edges(ev: &[FaultEvent]) -> Vec<(String, FaultKind, bool)> {
        ev.iter()
            .map(|e| (e.source.clone(), e.kind, e.started))
            .collect()
    }

    #[test]
    fn as_str_is_the_serde_name() {
        for k in FaultKind::ALL {
            let serde = serde_json::to_value(k).unwrap();
            assert_eq!(serde.as_str(), Some(k.as_str()), "{k:?}");
            assert_eq!(k.to_string(), k.as_str());
        }
        assert_eq!(FaultKind::BeyondClamp.as_str(), "beyond_clamp");
    }

    #[test]
    fn kinds_index_all_in_order() {
        for (i, k) in FaultKind::ALL.into_iter().enumerate() {
            assert_eq!(k.index(), i, "{k:?}");
        }
    }

    #[test]
    fn each_fault_is_reported_once_when_it_starts_and_once_when_it_clears() {
        use FaultKind::*;
        let (a, b) = (FaultSource::named("a"), FaultSource::Model);
        let mut log = FaultLog::default();
        assert!(log.update(&a, &[], 0.0).is_empty());
        let ev = log.update(&a, &[Stuck, Stale, Stale], 1.0);
        let s = |k, on| ("a".to_string(), k, on);
        assert_eq!(edges(&ev), [s(Stuck, true), s(Stale, true)]);
        assert!(log.update(&a, &[Stale, Stuck], 2.0).is_empty(), "no change");
        assert_eq!(edges(&log.update(&b, &[Decode], 2.5)).len(), 1);
        // Stuck clears, out of range starts: the start first, then the clear.
        let ev = log.update(&a, &[OutOfRange, Stale], 3.0);
        assert_eq!(edges(&ev), [s(OutOfRange, true), s(Stuck, false)]);
        assert_eq!(
            log.active()
                .map(|(s, k, t)| (s.to_string(), k, t))
                .collect::<Vec<_>>(),
            [
                ("model".to_string(), Decode, 2.5),
                ("a".to_string(), Stale, 1.0),
                ("a".to_string(), OutOfRange, 3.0),
            ],
            "by source identity (Model before Named), then kind; each since it started"
        );
        let ev = log.update(&a, &[], 4.0);
        assert_eq!(edges(&ev), [s(Stale, false), s(OutOfRange, false)]);
        assert_eq!(ev[0].t_s, 4.0);
        assert_eq!(log.active().count(), 1, "only the model's fault is left");
        assert!(log.update(&a, &[], 5.0).is_empty());
    }
}
