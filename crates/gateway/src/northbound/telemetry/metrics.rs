//! What a box publishes: the gateway's [`StatusSnapshot`] flattened into named Sparkplug metrics,
//! and the report-by-exception sampler that turns a stream of snapshots into data records (the
//! values that changed since the last record, stamped with the snapshot's own time).
//!
//! Names and units: `Axis/<axis>/applied_um` (correction applied after safety, µm; correction =
//! −error), `Axis/<axis>/target_um` (what the model asks, µm; NaN — sent as null — while inputs
//! are faulty),
//! `Axis/<axis>/term/<term>_um` (breakdown by model term, µm), `Axis/<axis>/position_mm`,
//! `Axis/<axis>/mode`; `Channel/<name>/value` (channel units, as in the field config's name),
//! `Channel/<name>/health`; `Sink/*`; `Gateway/*`; `Model/identity`. The publisher's own state
//! (queue, drops) is in the gateway's `/status` and `/metrics`, not in the payloads; so is its
//! link-down fault (`telemetry.mqtt:disconnected`): a host learns of that link from NDEATH, and a
//! birth sent over the link must not say it is down.

use serde::Serialize;

use super::annotate::SOURCE as OWN_LINK;
use super::sparkplug::{NamedValue, Value};
use crate::status::StatusSnapshot;

fn snake<T: Serialize>(t: &T) -> String {
    match serde_json::to_value(t) {
        Ok(serde_json::Value::String(s)) => s,
        Ok(other) => other.to_string(),
        Err(_) => "unknown".into(),
    }
}

/// The metrics of one snapshot, in a stable order (the birth's alias order).
pub(crate) fn snapshot_metrics(snap: &StatusSnapshot, model_identity: &str) -> Vec<NamedValue> {
    let mut out: Vec<NamedValue> = Vec::with_capacity(16 + 8 * snap.axes.len());
    let mut push = |name: String, v: Value| out.push((name, v));
    push("Gateway/cycles".into(), Value::Long(snap.cycles));
    push("Gateway/t_s".into(), Value::Double(snap.t_s));
    push("Gateway/enabled".into(), Value::Boolean(snap.enabled));
    let faults: Vec<String> = snap
        .active_faults
        .iter()
        .filter(|(src, _, _)| src != OWN_LINK)
        .map(|(src, kind, _)| format!("{src}:{}", snake(kind)))
        .collect();
    push(
        "Gateway/active_faults".into(),
        Value::Int(u32::try_from(faults.len()).unwrap_or(u32::MAX)),
    );
    push("Gateway/faults".into(), Value::String(faults.join(",")));
    push(
        "Gateway/model_error".into(),
        Value::String(snap.model_error.clone().unwrap_or_default()),
    );
    push(
        "Model/identity".into(),
        Value::String(model_identity.to_string()),
    );
    for a in &snap.axes {
        let p = format!("Axis/{}", a.axis);
        push(format!("{p}/applied_um"), Value::Double(a.applied_um));
        push(
            format!("{p}/target_um"),
            Value::Double(a.target_um.unwrap_or(f64::NAN)),
        );
        push(
            format!("{p}/position_mm"),
            Value::Double(a.position_mm.unwrap_or(f64::NAN)),
        );
        push(format!("{p}/mode"), Value::String(snake(&a.mode)));
        for (term, v) in &a.terms_um {
            push(format!("{p}/term/{term}_um"), Value::Double(*v));
        }
    }
    for (name, ch) in &snap.channels {
        push(
            format!("Channel/{name}/value"),
            Value::Double(ch.value.unwrap_or(f64::NAN)),
        );
        push(
            format!("Channel/{name}/health"),
            Value::String(snake(&ch.health)),
        );
    }
    if let Some(s) = &snap.sink {
        push("Sink/kind".into(), Value::String(s.kind.clone()));
        push("Sink/connected".into(), Value::Boolean(s.connected));
        push("Sink/writes_ok".into(), Value::Long(s.writes_ok));
        push("Sink/writes_failed".into(), Value::Long(s.writes_failed));
    }
    out
}

/// Same value for report-by-exception purposes (NaN equals NaN: an unchanged "no value").
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        // Bit-identical or both NaN: report-by-exception sends any change, however small.
        (Value::Double(x), Value::Double(y)) => {
            x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan())
        }
        _ => a == b,
    }
}

/// Names whose change is published at once rather than at the next sampling tick.
fn is_state(name: &str) -> bool {
    matches!(
        name,
        "Gateway/enabled" | "Gateway/faults" | "Gateway/model_error" | "Sink/connected"
    ) || name.ends_with("/mode")
        || name.ends_with("/health")
}

/// A data record: the values that changed, sampled at `t_ms` (ms since the Unix epoch).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Record {
    pub t_ms: u64,
    pub values: Vec<NamedValue>,
}

/// Report by exception: remembers the last values sent and yields only the changes.
#[derive(Debug, Default)]
pub(crate) struct Sampler {
    last: Vec<NamedValue>,
}

impl Sampler {
    /// True when a state metric (enable, faults, modes, health, sink link) differs from the last
    /// record: the caller publishes now instead of waiting for its tick.
    pub(crate) fn state_changed(&self, now: &[NamedValue]) -> bool {
        now.iter().filter(|(n, _)| is_state(n)).any(|(n, v)| {
            self.last
                .iter()
                .find(|(m, _)| m == n)
                .is_none_or(|(_, w)| !same(v, w))
        })
    }

    /// The record of what changed since the last one (None when nothing did).
    pub(crate) fn record(&mut self, now: Vec<NamedValue>, t_ms: u64) -> Option<Record> {
        let changed: Vec<NamedValue> = now
            .iter()
            .filter(|(n, v)| {
                self.last
                    .iter()
                    .find(|(m, _)| m == n)
                    .is_none_or(|(_, w)| !same(v, w))
            })
            .cloned()
            .collect();
        self.last = now;
        (!changed.is_empty()).then_some(Record {
            t_ms,
            values: changed,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(pairs: &[(&str, f64)]) -> Vec<NamedValue> {
        pairs
            .iter()
            .map(|(n, x)| (n.to_string(), Value::Double(*x)))
            .collect()
    }

    #[test]
    fn only_changed_values_are_recorded_and_nan_is_unchanged() {
        let mut s = Sampler::default();
        let r = s.record(v(&[("a", 1.0), ("b", f64::NAN)]), 5).unwrap();
        assert_eq!(r.values.len(), 2, "the first record carries everything");
        assert_eq!(s.record(v(&[("a", 1.0), ("b", f64::NAN)]), 6), None);
        let r = s.record(v(&[("a", 2.0), ("b", f64::NAN)]), 7).unwrap();
        assert_eq!((r.t_ms, r.values), (7, v(&[("a", 2.0)])));
    }

    #[test]
    fn state_changes_are_flagged_value_changes_are_not() {
        let mut s = Sampler::default();
        let base = vec![
            ("Gateway/enabled".to_string(), Value::Boolean(true)),
            ("Axis/x/applied_um".to_string(), Value::Double(1.0)),
        ];
        s.record(base.clone(), 1);
        let mut moved = base.clone();
        moved[1].1 = Value::Double(2.0);
        assert!(!s.state_changed(&moved));
        let mut off = base;
        off[0].1 = Value::Boolean(false);
        assert!(s.state_changed(&off));
    }
}
