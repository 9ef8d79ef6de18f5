//! What the live page shows over time: a bounded, downsampled history of the status snapshots,
//! kept server-side and fed from the status watch channel (never from the cycle loop).
//!
//! - Correction series, µm, per axis: `applied`, `target` and each model term (corrections, i.e.
//!   −error, the same sign as `/status`). Two rings: one point per second for 15 minutes and one
//!   per 10 s for 24 h (the last snapshot seen in each bucket; a gap when the gateway stopped).
//! - Fault log: each (source, kind) episode once at start (its `since` time) and once at clear
//!   (the first observation without it), plus who acknowledged it.
//! - Sensor health changes: a line per channel whenever its health / substituted / fault set changes.
//! - Actions taken on the API (who, when, what, result).
//!
//! Times: `t_s` is the gateway clock (s since start, as in `/status`); `unix_s` is wall time, s.
//! Everything is bounded ([`FINE_POINTS`], [`COARSE_POINTS`], [`MAX_EVENTS`]); an observation at
//! most every [`OBSERVE_PERIOD`] so a fault shorter than that may be seen only in the tracing log.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::Serialize;

use crate::engine::health::FaultKind;
use crate::status::StatusSnapshot;
use retrocomp_bus::Health;

/// 15 min at 1 s.
pub const FINE_POINTS: usize = 900;
pub const FINE_STEP_S: f64 = 1.0;
/// 24 h at 10 s.
pub const COARSE_POINTS: usize = 8640;
pub const COARSE_STEP_S: f64 = 10.0;
/// Fault, health and action logs keep this many lines each (oldest dropped first).
pub const MAX_EVENTS: usize = 1000;
/// The history task looks at the latest snapshot at most this often (≤ 10 Hz).
pub const OBSERVE_PERIOD: Duration = Duration::from_millis(100);

pub fn unix_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// One downsampled ring: `t_unix_s[i]` with `values[series][i]` (None: series absent then).
#[derive(Debug, Default)]
struct Ring {
    step_s: f64,
    cap: usize,
    t_unix_s: VecDeque<f64>,
    /// Indexed like [`History::series`]; every column as long as `t_unix_s`.
    values: Vec<VecDeque<Option<f64>>>,
}

impl Ring {
    fn new(step_s: f64, cap: usize) -> Self {
        Ring {
            step_s,
            cap,
            ..Default::default()
        }
    }

    /// Store `row` (one value per series) in the bucket of `unix_s`: replaces the last point when
    /// it is in the same bucket, else appends (dropping the oldest beyond `cap`).
    fn put(&mut self, unix_s: f64, row: &[Option<f64>]) {
        while self.values.len() < row.len() {
            self.values
                .push(self.t_unix_s.iter().map(|_| None).collect());
        }
        let bucket = unix_s.div_euclid(self.step_s);
        let same = self
            .t_unix_s
            .back()
            .is_some_and(|t| t.div_euclid(self.step_s).total_cmp(&bucket).is_eq());
        if same {
            *self.t_unix_s.back_mut().expect("non-empty") = unix_s;
            for (col, v) in self.values.iter_mut().zip(row) {
                *col.back_mut().expect("same length as t") = *v;
            }
            return;
        }
        if self.t_unix_s.len() == self.cap {
            self.t_unix_s.pop_front();
            for col in &mut self.values {
                col.pop_front();
            }
        }
        self.t_unix_s.push_back(unix_s);
        for (i, col) in self.values.iter_mut().enumerate() {
            col.push_back(row.get(i).copied().flatten());
        }
    }
}

/// A fault episode's start or clear.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FaultEvent {
    pub unix_s: f64,
    pub t_s: f64,
    pub source: String,
    pub kind: FaultKind,
    /// `start` or `clear`.
    pub event: &'static str,
}

/// A channel's health as it changed.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HealthEvent {
    pub unix_s: f64,
    pub t_s: f64,
    pub channel: String,
    pub health: Health,
    pub substituted: bool,
    pub faults: Vec<FaultKind>,
}

/// An action asked for on the API, allowed or refused.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ActionEvent {
    pub unix_s: f64,
    /// Peer address of the client.
    pub peer: String,
    /// `api_token` when the bearer token matched, `-` otherwise.
    pub who: String,
    pub action: String,
    /// `accepted`, `refused: …`.
    pub result: String,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Ack {
    pub unix_s: f64,
    pub peer: String,
}

#[derive(Debug)]
pub struct History {
    /// Series names: `<axis>/applied`, `<axis>/target`, `<axis>/term/<term>`.
    series: Vec<String>,
    index: BTreeMap<String, usize>,
    fine: Ring,
    coarse: Ring,
    faults: VecDeque<FaultEvent>,
    health: VecDeque<HealthEvent>,
    actions: VecDeque<ActionEvent>,
    /// Active faults at the last observation and their acknowledgement, if any.
    active: BTreeMap<(String, FaultKind), Option<Ack>>,
    channel_state: BTreeMap<String, (Health, bool, Vec<FaultKind>)>,
    row: Vec<Option<f64>>,
}

/// A fault episode: (source, kind), as in the snapshot's `active_faults`.
pub(crate) type FaultKey = (String, FaultKind);

/// The fault episodes of `snap` against those `active` at the last observation: the ones gone
/// (cleared), then the ones new in `snap` with their `since` (started), each in name order.
/// The live page's fault log and the OPC UA alarms both follow episodes this way.
pub(crate) fn fault_changes<V>(
    active: &BTreeMap<FaultKey, V>,
    snap: &StatusSnapshot,
) -> (Vec<FaultKey>, Vec<(FaultKey, f64)>) {
    let now: BTreeMap<FaultKey, f64> = snap
        .active_faults
        .iter()
        .map(|(s, k, since)| ((s.clone(), *k), *since))
        .collect();
    let cleared = active
        .keys()
        .filter(|k| !now.contains_key(*k))
        .cloned()
        .collect();
    let started = now
        .into_iter()
        .filter(|(k, _)| !active.contains_key(k))
        .collect();
    (cleared, started)
}

impl Default for History {
    fn default() -> Self {
        History {
            series: Vec::new(),
            index: BTreeMap::new(),
            fine: Ring::new(FINE_STEP_S, FINE_POINTS),
            coarse: Ring::new(COARSE_STEP_S, COARSE_POINTS),
            faults: VecDeque::new(),
            health: VecDeque::new(),
            actions: VecDeque::new(),
            active: BTreeMap::new(),
            channel_state: BTreeMap::new(),
            row: Vec::new(),
        }
    }
}

fn push_bounded<T>(q: &mut VecDeque<T>, v: T) {
    if q.len() == MAX_EVENTS {
        q.pop_front();
    }
    q.push_back(v);
}

impl History {
    fn slot(&mut self, name: String) -> usize {
        if let Some(&i) = self.index.get(&name) {
            return i;
        }
        let i = self.series.len();
        self.index.insert(name.clone(), i);
        self.series.push(name);
        self.row.push(None);
        i
    }

    /// Take one snapshot seen at wall time `unix_s`.
    pub fn observe(&mut self, snap: &StatusSnapshot, unix_s: f64) {
        self.row.iter_mut().for_each(|v| *v = None);
        for a in &snap.axes {
            let i = self.slot(format!("{}/applied", a.axis));
            self.row[i] = Some(a.applied_um);
            let i = self.slot(format!("{}/target", a.axis));
            self.row[i] = a.target_um;
            for (term, v) in &a.terms_um {
                let i = self.slot(format!("{}/term/{term}", a.axis));
                self.row[i] = Some(*v);
            }
        }
        self.fine.put(unix_s, &self.row);
        self.coarse.put(unix_s, &self.row);
        self.observe_faults(snap, unix_s);
        self.observe_health(snap, unix_s);
    }

    fn observe_faults(&mut self, snap: &StatusSnapshot, unix_s: f64) {
        let (cleared, started) = fault_changes(&self.active, snap);
        for key in cleared {
            self.active.remove(&key);
            let ev = FaultEvent {
                unix_s,
                t_s: snap.t_s,
                source: key.0,
                kind: key.1,
                event: "clear",
            };
            push_bounded(&mut self.faults, ev);
        }
        for (key, since) in started {
            let ev = FaultEvent {
                unix_s: unix_s - (snap.t_s - since).max(0.0),
                t_s: since,
                source: key.0.clone(),
                kind: key.1,
                event: "start",
            };
            push_bounded(&mut self.faults, ev);
            self.active.insert(key, None);
        }
    }

    fn observe_health(&mut self, snap: &StatusSnapshot, unix_s: f64) {
        for (name, c) in &snap.channels {
            let state = (c.health, c.substituted, c.faults.clone());
            if self.channel_state.get(name) == Some(&state) {
                continue;
            }
            let ev = HealthEvent {
                unix_s,
                t_s: snap.t_s,
                channel: name.clone(),
                health: state.0,
                substituted: state.1,
                faults: state.2.clone(),
            };
            push_bounded(&mut self.health, ev);
            self.channel_state.insert(name.clone(), state);
        }
    }

    /// Record an action asked for on the API.
    pub fn record_action(&mut self, ev: ActionEvent) {
        push_bounded(&mut self.actions, ev);
    }

    /// Acknowledge every active fault (or only `source`'s); returns how many were acknowledged.
    /// Acknowledging changes nothing on the machine: it records that a person saw it.
    pub fn acknowledge(&mut self, source: Option<&str>, ack: &Ack) -> usize {
        let mut n = 0;
        for ((s, _), a) in self.active.iter_mut() {
            if a.is_none() && source.is_none_or(|want| want == s) {
                *a = Some(ack.clone());
                n += 1;
            }
        }
        n
    }

    /// `/api/history`: `window` `fine` (15 min at 1 s) or `coarse` (24 h at 10 s), columnar.
    pub fn history_json(&self, coarse: bool) -> serde_json::Value {
        let ring = if coarse { &self.coarse } else { &self.fine };
        let series: serde_json::Map<String, serde_json::Value> = self
            .series
            .iter()
            .enumerate()
            .map(|(i, name)| {
                let col = ring.values.get(i);
                let v: Vec<Option<f64>> = match col {
                    Some(c) => c.iter().copied().collect(),
                    None => vec![None; ring.t_unix_s.len()],
                };
                (name.clone(), serde_json::json!(v))
            })
            .collect();
        serde_json::json!({
            "step_s": ring.step_s,
            "unit": "um",
            "t_unix_s": ring.t_unix_s,
            "series": series,
        })
    }

    /// `/api/faults`: the active faults with their acknowledgement, and the start/clear log.
    pub fn faults_json(&self) -> serde_json::Value {
        let active: Vec<_> = self
            .active
            .iter()
            .map(|((s, k), ack)| serde_json::json!({"source": s, "kind": k, "ack": ack}))
            .collect();
        serde_json::json!({ "active": active, "log": self.faults })
    }

    pub fn health_json(&self) -> serde_json::Value {
        serde_json::json!({ "log": self.health })
    }

    pub fn actions_json(&self) -> serde_json::Value {
        serde_json::json!({ "log": self.actions })
    }
}

pub type SharedHistory = Arc<Mutex<History>>;

/// Feed a [`History`] from the status channel until the channel closes.
pub fn spawn(
    mut rx: tokio::sync::watch::Receiver<Option<Arc<StatusSnapshot>>>,
) -> (SharedHistory, tokio::task::JoinHandle<()>) {
    let h: SharedHistory = Arc::default();
    let shared = Arc::clone(&h);
    let task = tokio::spawn(async move {
        while rx.changed().await.is_ok() {
            let snap = rx.borrow_and_update().clone();
            if let Some(s) = snap {
                let mut h = shared.lock().unwrap_or_else(|p| p.into_inner());
                h.observe(&s, unix_now_s());
            }
            tokio::time::sleep(OBSERVE_PERIOD).await;
        }
    });
    (h, task)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::safety::Mode;
    use crate::status::AxisStatus;

    fn snap(t_s: f64, applied_um: f64, faults: &[(&str, FaultKind, f64)]) -> StatusSnapshot {
        StatusSnapshot {
            t_s,
            cycles: 1,
            enabled: true,
            axes: vec![AxisStatus {
                axis: "x".into(),
                position_mm: Some(1.0),
                direction: Some(retrocomp_model::approach::Approach::Forward),
                weight_forward: 1.0,
                target_um: Some(applied_um),
                applied_um,
                mode: Mode::Tracking,
                terms_um: [("thermal".to_string(), applied_um / 2.0)].into(),
                clamp_hits: 0,
                cap_hits: 0,
            }],
            channels: BTreeMap::new(),
            active_faults: faults
                .iter()
                .map(|(s, k, t)| (s.to_string(), *k, *t))
                .collect(),
            ..Default::default()
        }
    }

    #[test]
    fn rings_downsample_and_stay_bounded() {
        let mut h = History::default();
        // 10 observations per second for 20 min: the fine ring keeps the last 900 s, 1 point each.
        for i in 0..12_000 {
            let t = f64::from(i) * 0.1;
            h.observe(&snap(t, t, &[]), 1000.0 + t);
        }
        let j = h.history_json(false);
        let t = j["t_unix_s"].as_array().unwrap();
        assert_eq!(t.len(), FINE_POINTS);
        let x = j["series"]["x/applied"].as_array().unwrap();
        assert_eq!(x.len(), FINE_POINTS);
        // Last bucket holds the last snapshot seen in it.
        assert!((x.last().unwrap().as_f64().unwrap() - 1199.9).abs() < 1e-9);
        assert!((t[0].as_f64().unwrap() - (1000.0 + 300.9)).abs() < 1e-6);
        let c = h.history_json(true);
        assert_eq!(c["t_unix_s"].as_array().unwrap().len(), 120);
        assert!((c["series"]["x/term/thermal"][119].as_f64().unwrap() - 599.95).abs() < 1e-9);
    }

    #[test]
    fn fault_log_has_start_and_clear_once_and_acks() {
        let mut h = History::default();
        let f = [("T_spindle_C", FaultKind::Stale, 5.0)];
        h.observe(&snap(4.0, 0.0, &[]), 100.0);
        h.observe(&snap(5.5, 0.0, &f), 101.5);
        h.observe(&snap(6.0, 0.0, &f), 102.0);
        let ack = Ack {
            unix_s: 102.5,
            peer: "127.0.0.1:1".into(),
        };
        assert_eq!(h.acknowledge(Some("other"), &ack), 0);
        assert_eq!(h.acknowledge(None, &ack), 1);
        assert_eq!(h.faults_json()["active"][0]["ack"]["peer"], "127.0.0.1:1");
        h.observe(&snap(7.0, 0.0, &[]), 103.0);
        let log = &h.faults_json()["log"];
        assert_eq!(log.as_array().unwrap().len(), 2);
        assert_eq!(log[0]["event"], "start");
        assert_eq!(log[0]["t_s"], 5.0);
        assert!((log[0]["unix_s"].as_f64().unwrap() - 101.0).abs() < 1e-9);
        assert_eq!(log[1]["event"], "clear");
        assert_eq!(log[1]["kind"], "stale");
        assert!(h.faults_json()["active"].as_array().unwrap().is_empty());
    }
}
