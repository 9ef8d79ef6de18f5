//! The box's faults as OPC UA Alarms & Conditions events (Part 9): each fault episode — a
//! (component, [`FaultKind`]) pair in the status snapshot's `active_faults` — raises an
//! `AlarmConditionType` event on the machine object when it starts (`ActiveState/Id` true,
//! `Retain` true) and another when it clears (false, false). The machine object is an event
//! notifier under `Server` (HasNotifier), so a client subscribed to events on `Server` or on the
//! machine receives them.
//!
//! Sans-IO: [`Alarms::observe`] diffs a snapshot against the episodes it knows (as the live
//! page's fault log does, `history::fault_changes`) and returns the transitions; [`event`]
//! builds the event a transition is. The shell (`server.rs`) hands them to async-opcua's
//! subscription cache.
//!
//! Times: `t_s` is the gateway clock (s since start, as in `/status`); an event's `Time` is wall
//! time: a start at its `since`, placed that long before now; a clear at the snapshot that no
//! longer has it. A fault that starts and clears between two observations (at most
//! `server::UPDATE_PERIOD` apart) raises no event; the tracing log has it.
//!
//! What is not there (the server is read-only): no condition instances in the address space (so
//! no `ConditionId`, no `ConditionRefresh`), no Acknowledge/Confirm methods: `AckedState` is true
//! from the start, nothing waits for an operator.

use std::collections::BTreeMap;

use opcua::core_namespace::events::AlarmConditionType;
use opcua::nodes::NamespaceMap;
use opcua::types::{ByteString, DateTime, LocalizedText, NodeId, ObjectTypeId, UAString};

use crate::engine::health::FaultKind;
use crate::northbound::history::{FaultKey, fault_changes};
use crate::status::StatusSnapshot;

/// A fault episode that started or cleared.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Transition {
    /// The component the fault is on (a channel, a source, a sink, a listener).
    pub source: String,
    pub kind: FaultKind,
    /// True: it started; false: it cleared.
    pub active: bool,
    /// Gateway clock of the transition, s: the fault's `since` for a start, the snapshot's time
    /// for a clear.
    pub t_s: f64,
    /// Unique within this server's run (part of the EventId).
    pub seq: u64,
}

/// The episodes active at the last observation.
#[derive(Debug, Default)]
pub(crate) struct Alarms {
    active: BTreeMap<FaultKey, f64>,
    seq: u64,
}

impl Alarms {
    /// Transitions since the last observation: clears first, then starts, each in name order.
    pub(crate) fn observe(&mut self, snap: &StatusSnapshot) -> Vec<Transition> {
        let (cleared, started) = fault_changes(&self.active, snap);
        let mut out = Vec::with_capacity(cleared.len() + started.len());
        for (source, kind) in cleared {
            self.active.remove(&(source.clone(), kind));
            out.push(self.transition(source, kind, false, snap.t_s));
        }
        for ((source, kind), since) in started {
            self.active.insert((source.clone(), kind), since);
            out.push(self.transition(source, kind, true, since));
        }
        out
    }

    fn transition(
        &mut self,
        source: String,
        kind: FaultKind,
        active: bool,
        t_s: f64,
    ) -> Transition {
        self.seq += 1;
        Transition {
            source,
            kind,
            active,
            t_s,
            seq: self.seq,
        }
    }
}

/// Part 5 §6.4.2's bands: 801–1000 high … 1–200 low. A controller that gets no correction (link
/// down, writes refused, beyond the clamp) or a refused write attempt is high; an input the
/// model cannot trust is medium-high (its terms hold, then ramp out); the rest medium.
pub(crate) fn severity(kind: FaultKind) -> u16 {
    use FaultKind as K;
    match kind {
        K::Disconnected | K::WriteFailed | K::BeyondClamp | K::Unauthorized | K::BusOff => 800,
        K::Stale
        | K::OutOfRange
        | K::NotFinite
        | K::RateOfChange
        | K::Stuck
        | K::Decode
        | K::Exception
        | K::ListenerFailed => 700,
        K::ErrorPassive | K::BusErrors | K::Overloaded | K::NoSource => 500,
    }
}

/// `ConditionName`: `<component>/<fault>`, e.g. `T_xscrew_C/stale`.
pub(crate) fn condition_name(t: &Transition) -> String {
    format!("{}/{}", t.source, crate::northbound::state_name(&t.kind))
}

/// The event for `t` on the machine object `machine`; `time`: its wall time; `run`: what makes
/// EventIds unique across runs (the server's start time, Unix ns).
pub(crate) fn event(
    t: &Transition,
    machine: &NodeId,
    time: DateTime,
    receive: DateTime,
    run: u64,
) -> AlarmConditionType {
    let name = condition_name(t);
    let message = if t.active {
        format!("{}: {}", t.source, crate::northbound::state_name(&t.kind))
    } else {
        format!(
            "{}: {} cleared",
            t.source,
            crate::northbound::state_name(&t.kind)
        )
    };
    let mut id = Vec::with_capacity(16);
    id.extend_from_slice(&run.to_be_bytes());
    id.extend_from_slice(&t.seq.to_be_bytes());
    let mut e = AlarmConditionType::new_event(
        AlarmConditionType::event_type_id(),
        ByteString::from(id),
        LocalizedText::new("en", &message),
        &NamespaceMap::new(),
        time,
    );
    let severity = severity(t.kind);
    let ack = &mut e.base;
    ack.acked_state.id = true;
    ack.acked_state.base.value = LocalizedText::new("en", "Acknowledged");
    ack.enabled_state.id = true;
    let cond = &mut ack.base;
    cond.condition_name = UAString::from(name);
    cond.condition_class_id = ObjectTypeId::SystemConditionClassType.into();
    cond.condition_class_name = LocalizedText::new("en", "SystemConditionClassType");
    cond.retain = t.active;
    cond.enabled_state.id = true;
    cond.enabled_state.base.value = LocalizedText::new("en", "Enabled");
    let base = &mut cond.base;
    base.source_node = machine.clone();
    base.source_name = UAString::from(t.source.as_str());
    base.severity = severity;
    base.receive_time = receive;
    e.active_state.id = t.active;
    e.active_state.base.value =
        LocalizedText::new("en", if t.active { "Active" } else { "Inactive" });
    e.enabled_state.id = true;
    e
}

#[cfg(test)]
mod tests {
    use opcua::nodes::Event;
    use opcua::types::{AttributeId, NumericRange, QualifiedName, Variant};

    use super::*;

    fn snap(t_s: f64, faults: &[(&str, FaultKind, f64)]) -> StatusSnapshot {
        let mut s = StatusSnapshot {
            t_s,
            ..StatusSnapshot::default()
        };
        for &(source, kind, since) in faults {
            s.active_faults.push((source.into(), kind, since));
        }
        s
    }

    #[test]
    fn an_episode_starts_once_and_clears_once() {
        let mut a = Alarms::default();
        assert!(a.observe(&snap(1.0, &[])).is_empty());
        let stale = ("T_xscrew_C", FaultKind::Stale, 15.2);
        let started = a.observe(&snap(15.3, &[stale]));
        assert_eq!(started.len(), 1);
        assert_eq!(
            (started[0].active, started[0].t_s, started[0].seq),
            (true, 15.2, 1)
        );
        // Still active: nothing new, also when another fault joins.
        let link = ("sink", FaultKind::Disconnected, 16.0);
        let joined = a.observe(&snap(16.1, &[stale, link]));
        assert_eq!(joined.len(), 1);
        assert_eq!(joined[0].source, "sink");
        let cleared = a.observe(&snap(21.4, &[link]));
        assert_eq!(cleared.len(), 1);
        let c = &cleared[0];
        assert_eq!(
            (c.source.as_str(), c.kind, c.active, c.t_s),
            ("T_xscrew_C", FaultKind::Stale, false, 21.4)
        );
        // Each transition its own sequence number (its EventId).
        assert_eq!(c.seq, 3);
        // The same fault again is a new episode.
        let again = a.observe(&snap(30.0, &[("T_xscrew_C", FaultKind::Stale, 29.9), link]));
        assert_eq!((again.len(), again[0].active, again[0].seq), (1, true, 4));
    }

    fn field(e: &AlarmConditionType, ty: ObjectTypeId, path: &[&str]) -> Variant {
        let path: Vec<QualifiedName> = path.iter().map(|p| QualifiedName::new(0, *p)).collect();
        e.get_field(&ty.into(), AttributeId::Value, &NumericRange::None, &path)
    }

    /// The fields a client selects (each by the type that declares it) read what the fault is.
    #[test]
    fn a_transition_is_an_alarm_condition_event_with_the_standard_fields() {
        let machine = NodeId::new(2, "Machines/mill");
        let t = Transition {
            source: "T_xscrew_C".into(),
            kind: FaultKind::Stale,
            active: true,
            t_s: 15.0,
            seq: 7,
        };
        let now = DateTime::now();
        let e = event(&t, &machine, now, now, 42);
        use ObjectTypeId as T;
        let base = T::BaseEventType;
        assert_eq!(
            field(&e, base, &["EventType"]),
            Variant::from(NodeId::from(T::AlarmConditionType))
        );
        assert_eq!(field(&e, base, &["SourceNode"]), Variant::from(machine));
        assert_eq!(
            field(&e, base, &["SourceName"]),
            Variant::from("T_xscrew_C")
        );
        assert_eq!(field(&e, base, &["Severity"]), Variant::from(700u16));
        assert_eq!(
            field(&e, base, &["Message"]),
            Variant::from(LocalizedText::new("en", "T_xscrew_C: stale"))
        );
        let mut id = 42u64.to_be_bytes().to_vec();
        id.extend_from_slice(&7u64.to_be_bytes());
        assert_eq!(
            field(&e, base, &["EventId"]),
            Variant::from(ByteString::from(id))
        );
        let cond = T::ConditionType;
        assert_eq!(
            field(&e, cond, &["ConditionName"]),
            Variant::from("T_xscrew_C/stale")
        );
        assert_eq!(field(&e, cond, &["Retain"]), Variant::from(true));
        let alarm = T::AlarmConditionType;
        assert_eq!(
            field(&e, alarm, &["ActiveState", "Id"]),
            Variant::from(true)
        );
        let clear = event(
            &Transition { active: false, ..t },
            &NodeId::null(),
            now,
            now,
            42,
        );
        assert_eq!(
            field(&clear, alarm, &["ActiveState", "Id"]),
            Variant::from(false)
        );
        assert_eq!(field(&clear, cond, &["Retain"]), Variant::from(false));
        assert_eq!(
            field(&clear, base, &["Message"]),
            Variant::from(LocalizedText::new("en", "T_xscrew_C: stale cleared"))
        );
    }
}
