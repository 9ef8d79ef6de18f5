//! One edge node as a Sparkplug host sees it: session (bdSeq, births, alive), the latest metric
//! values by name, the seq accounting (gaps, duplicates, reordered and lost records) and the
//! verdict ([`Verdict`]). [`crate::FleetView`] routes each message to its node.
//!
//! Units as the published metrics (µm, mm); times ms since the Unix epoch; seq is Sparkplug's
//! 0–255 counter.

use std::collections::{BTreeMap, HashMap};

use serde::Serialize;

use retrocomp_gateway::northbound::telemetry::RebirthLimiter;
use retrocomp_gateway::northbound::telemetry::sparkplug::{Payload, Value};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    Offline,
    /// Data flows but no birth was seen yet (its metrics have no names until the rebirth).
    Online,
    Compensating,
    Degraded,
    Idle,
}

#[derive(Clone, Debug, Serialize)]
pub struct Node {
    pub group: String,
    pub edge_node: String,
    pub alive: bool,
    /// The NBIRTH of the current session was seen (names of the aliases known).
    pub born: bool,
    pub bd_seq: Option<u64>,
    pub births: u64,
    pub ndata: u64,
    /// NDATA whose seq was not one more than the message before (messages lost or reordered).
    pub seq_gaps: u64,
    /// NDATA whose seq equals the one before in the same session: a QoS 1 resend (at-least-once
    /// delivery), counted here and neither as a gap nor as a new record.
    pub duplicates: u64,
    /// NDATA that came after a later seq of its session and filled the hole it left: reordered,
    /// not lost (a Sparkplug host waits a reorder timeout for it before asking for a rebirth).
    pub reordered: u64,
    /// Seqs skipped and never filled: holes of ended sessions, and holes that fell 128 or more
    /// behind the highest seq (see [`Node::lost`] for those still open).
    pub lost_closed: u64,
    /// Timestamp of the latest message (the box's clock), ms since the Unix epoch.
    pub last_ms: u64,
    /// When the latest message arrived (the host's clock), ms since the Unix epoch.
    pub last_seen_ms: u64,
    /// Rebirth requests (NCMD) sent to this node.
    pub rebirths_requested: u64,
    /// NDATA metrics whose alias no birth named (dropped; a rebirth is requested).
    pub unknown_aliases: u64,
    #[serde(skip)]
    last_seq: Option<u64>,
    /// The highest seq of the session (mod 256) and the seqs below it not yet seen.
    #[serde(skip)]
    high_seq: Option<u64>,
    #[serde(skip)]
    holes: Vec<u64>,
    #[serde(skip)]
    aliases: HashMap<u64, String>,
    #[serde(skip)]
    pub(crate) rebirth: RebirthLimiter,
    /// Latest value of every metric, by name (numbers as f64, text as strings).
    pub metrics: BTreeMap<String, serde_json::Value>,
}

fn json_of(v: &Value) -> serde_json::Value {
    match v {
        Value::Int(x) => (*x).into(),
        Value::Long(x) => (*x).into(),
        Value::Float(x) => {
            serde_json::Number::from_f64(f64::from(*x)).map_or(serde_json::Value::Null, Into::into)
        }
        Value::Double(x) => {
            serde_json::Number::from_f64(*x).map_or(serde_json::Value::Null, Into::into)
        }
        Value::Boolean(b) => (*b).into(),
        Value::String(s) => s.clone().into(),
    }
}

impl Node {
    pub(crate) fn new(group: &str, edge_node: &str, rebirth_interval_ms: u64) -> Self {
        Node {
            group: group.into(),
            edge_node: edge_node.into(),
            alive: false,
            born: false,
            bd_seq: None,
            births: 0,
            ndata: 0,
            seq_gaps: 0,
            duplicates: 0,
            reordered: 0,
            lost_closed: 0,
            last_ms: 0,
            last_seen_ms: 0,
            rebirths_requested: 0,
            unknown_aliases: 0,
            last_seq: None,
            high_seq: None,
            holes: vec![],
            aliases: HashMap::new(),
            rebirth: RebirthLimiter::new(rebirth_interval_ms),
            metrics: BTreeMap::new(),
        }
    }

    /// Offline, online (no birth yet), or what the latest values say.
    pub fn verdict(&self) -> Verdict {
        if !self.alive {
            return Verdict::Offline;
        }
        if !self.born {
            return Verdict::Online;
        }
        let m = &self.metrics;
        let faults = m
            .get("Gateway/active_faults")
            .and_then(serde_json::Value::as_u64)
            .unwrap_or(0);
        let not_tracking = m
            .iter()
            .any(|(k, v)| k.starts_with("Axis/") && k.ends_with("/mode") && v != "tracking");
        let sink_down = m.get("Sink/connected") == Some(&serde_json::Value::Bool(false));
        let enabled = m.get("Gateway/enabled") != Some(&serde_json::Value::Bool(false));
        if !enabled {
            Verdict::Idle
        } else if faults > 0 || not_tracking || sink_down {
            Verdict::Degraded
        } else {
            Verdict::Compensating
        }
    }

    /// The active faults' names (`Gateway/faults`, comma-separated by the box).
    pub fn faults(&self) -> Vec<String> {
        self.metrics
            .get("Gateway/faults")
            .and_then(serde_json::Value::as_str)
            .map(|s| {
                s.split(',')
                    .filter(|f| !f.is_empty())
                    .map(str::to_string)
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Correction applied after safety per axis, µm (`Axis/<axis>/applied_um`).
    pub fn applied_um(&self) -> BTreeMap<String, f64> {
        self.metrics
            .iter()
            .filter_map(|(k, v)| {
                let axis = k.strip_prefix("Axis/")?.strip_suffix("/applied_um")?;
                Some((axis.to_string(), v.as_f64()?))
            })
            .collect()
    }

    /// The node as JSON: its fields, `verdict`, `faults` and `applied_um`.
    pub fn to_json(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self).unwrap_or_default();
        v["verdict"] = serde_json::to_value(self.verdict()).unwrap_or_default();
        v["faults"] = self.faults().into();
        v["applied_um"] = serde_json::to_value(self.applied_um()).unwrap_or_default();
        v
    }

    /// Ask for a rebirth (rate-limited); true when one is to be sent now.
    pub(crate) fn want_rebirth(&mut self, now_ms: u64) -> bool {
        let go = self.rebirth.request(now_ms);
        self.rebirths_requested += u64::from(go);
        go
    }

    pub(crate) fn birth(&mut self, p: &Payload, bd: Option<u64>, now_ms: u64) {
        self.alive = true;
        self.born = true;
        self.bd_seq = bd;
        self.births += 1;
        self.last_seq = p.seq;
        self.lost_closed += self.holes.len() as u64;
        self.holes.clear();
        self.high_seq = p.seq.map(|s| s % 256);
        self.rebirth.born(now_ms);
        self.aliases.clear();
        for m in &p.metrics {
            if let Some(name) = &m.name {
                if let Some(a) = m.alias {
                    self.aliases.insert(a, name.clone());
                }
                // A declared metric without a value yet is `is_null` (shown as null).
                let v = m.value.as_ref().map_or(serde_json::Value::Null, json_of);
                self.metrics.insert(name.clone(), v);
            }
        }
    }

    /// Seqs skipped and not (yet) seen: the open holes and those already closed as lost.
    pub fn lost(&self) -> u64 {
        self.lost_closed + self.holes.len() as u64
    }

    /// Loss accounting against the highest seq seen (mod 256): a seq up to 127 ahead of it opens
    /// holes for the seqs it skipped; one behind it fills its hole (reordered) or is a resend.
    fn account(&mut self, s: u64) {
        let Some(high) = self.high_seq else {
            self.high_seq = Some(s);
            return;
        };
        let ahead = (s + 256 - high) % 256;
        if (1..128).contains(&ahead) {
            self.holes.extend((1..ahead).map(|k| (high + k) % 256));
            self.high_seq = Some(s);
            let before = self.holes.len();
            self.holes.retain(|h| (s + 256 - h) % 256 < 128);
            self.lost_closed += (before - self.holes.len()) as u64;
        } else if let Some(i) = self.holes.iter().position(|&h| h == s) {
            self.holes.swap_remove(i);
            self.reordered += 1;
        }
    }

    /// NDATA; true when a rebirth is wanted (no birth, or an alias the birth did not define).
    pub(crate) fn data(&mut self, p: &Payload) -> bool {
        self.alive = true;
        self.ndata += 1;
        // seq comes off the wire: any u64, u64::MAX included (2^64 is a multiple of 256, so the
        // wrapping sum is the right residue).
        if let (Some(l), Some(s)) = (self.last_seq, p.seq) {
            if s == l {
                self.duplicates += 1;
            } else if s != l.wrapping_add(1) % 256 {
                self.seq_gaps += 1;
            }
        }
        self.last_seq = p.seq;
        if let Some(s) = p.seq {
            self.account(s % 256);
        }
        let mut unknown = false;
        for m in &p.metrics {
            let name = m
                .name
                .clone()
                .or_else(|| m.alias.and_then(|a| self.aliases.get(&a).cloned()));
            let Some(name) = name else {
                self.unknown_aliases += 1;
                unknown = true;
                continue;
            };
            if m.is_historical != Some(true) {
                if let Some(v) = &m.value {
                    self.metrics.insert(name, json_of(v));
                } else if m.is_null == Some(true) {
                    self.metrics.insert(name, serde_json::Value::Null);
                }
            }
        }
        !self.born || unknown
    }

    /// NDEATH; true when a rebirth is wanted (a death of a node without a known birth: it may
    /// be a late will while a newer session is up).
    pub(crate) fn death(&mut self, bd: Option<u64>) -> bool {
        if !self.born {
            self.alive = false;
            return true;
        }
        if bd.is_none() || bd == self.bd_seq {
            self.alive = false;
            self.born = false;
            self.rebirth.forget();
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fleet::DEFAULT_REBIRTH_INTERVAL_MS;

    /// A record overtaken by the next one (seq 5, 7, 6, 8) is reordered, not lost: its hole is
    /// filled; a seq that never comes stays lost, and is closed as lost once 128 seqs behind or at
    /// the next birth.
    #[test]
    fn a_reordered_ndata_fills_its_hole_and_a_missing_one_stays_lost() {
        let mut n = Node::new("g", "n", DEFAULT_REBIRTH_INTERVAL_MS);
        n.birth(
            &Payload {
                seq: Some(4),
                ..Payload::default()
            },
            Some(0),
            0,
        );
        for s in [5, 7, 6, 8] {
            n.data(&Payload {
                seq: Some(s),
                ..Payload::default()
            });
        }
        assert_eq!((n.reordered, n.lost()), (1, 0));
        assert!(n.seq_gaps > 0, "the gap count still sees the disorder");
        // 9 never comes; 10..=137 put it 128 behind.
        n.data(&Payload {
            seq: Some(10),
            ..Payload::default()
        });
        assert_eq!((n.lost(), n.lost_closed), (1, 0));
        for s in 11..=137 {
            n.data(&Payload {
                seq: Some(s),
                ..Payload::default()
            });
        }
        assert_eq!((n.lost(), n.lost_closed), (1, 1));
        // Across the wrap: 254, 0 (255 skipped), then 255 late.
        for s in 138..=254 {
            n.data(&Payload {
                seq: Some(s),
                ..Payload::default()
            });
        }
        n.data(&Payload {
            seq: Some(0),
            ..Payload::default()
        });
        n.data(&Payload {
            seq: Some(255),
            ..Payload::default()
        });
        assert_eq!((n.reordered, n.lost()), (2, 1));
        // A hole open at a new birth is lost.
        n.data(&Payload {
            seq: Some(2),
            ..Payload::default()
        });
        n.birth(
            &Payload {
                seq: Some(0),
                ..Payload::default()
            },
            Some(1),
            0,
        );
        assert_eq!(n.lost(), 2);
    }
}
