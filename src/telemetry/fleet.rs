//! The fleet's health as a Sparkplug host sees it (sans-IO; `retrocomp fleet` is its MQTT shell):
//! per edge node, alive from NBIRTH/NDEATH (an NDEATH counts only if its bdSeq is the current
//! session's: a late will of an older connection does not kill a node that re-birthed), the
//! latest metric values from NBIRTH (names and aliases) and NDATA (aliases), seq gaps, and a
//! verdict: offline, compensating, degraded (faults, an axis not tracking, the controller link
//! down) or idle (compensation disabled). Units as the published metrics (µm, mm).

use std::collections::{BTreeMap, HashMap};

use prost::Message;
use serde::Serialize;

use super::sparkplug::{BD_SEQ, Payload, Value};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    Offline,
    Compensating,
    Degraded,
    Idle,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Node {
    pub group: String,
    pub edge_node: String,
    pub alive: bool,
    pub bd_seq: Option<u64>,
    pub births: u64,
    pub ndata: u64,
    /// NDATA whose seq was not one more than the message before (messages lost or reordered).
    pub seq_gaps: u64,
    /// Timestamp of the latest message, ms since the Unix epoch.
    pub last_ms: u64,
    #[serde(skip)]
    last_seq: Option<u64>,
    #[serde(skip)]
    aliases: HashMap<u64, String>,
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
    /// Offline, or what the latest values say.
    pub fn verdict(&self) -> Verdict {
        if !self.alive {
            return Verdict::Offline;
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
}

/// Every edge node seen, by (group, edge node).
#[derive(Debug, Default)]
pub struct FleetView {
    pub nodes: BTreeMap<(String, String), Node>,
}

impl FleetView {
    /// Take one message (`spBv1.0/<group>/<type>/<edge node>`); other topics are ignored.
    pub fn ingest(&mut self, topic: &str, payload: &[u8]) {
        let parts: Vec<&str> = topic.split('/').collect();
        let [ns, group, kind, edge] = parts[..] else {
            return;
        };
        if ns != "spBv1.0" || !matches!(kind, "NBIRTH" | "NDATA" | "NDEATH") {
            return;
        }
        let Ok(p) = Payload::decode(payload) else {
            return;
        };
        let node = self
            .nodes
            .entry((group.to_string(), edge.to_string()))
            .or_insert_with(|| Node {
                group: group.into(),
                edge_node: edge.into(),
                ..Default::default()
            });
        node.last_ms = node.last_ms.max(p.timestamp.unwrap_or(0));
        let bd = p.metrics.iter().find_map(|m| {
            (m.name.as_deref() == Some(BD_SEQ)).then_some(())?;
            match m.value {
                Some(Value::Long(v)) => Some(v),
                _ => None,
            }
        });
        match kind {
            "NBIRTH" => {
                node.alive = true;
                node.bd_seq = bd;
                node.births += 1;
                node.last_seq = p.seq;
                node.aliases.clear();
                for m in &p.metrics {
                    if let (Some(name), Some(v)) = (&m.name, &m.value) {
                        if let Some(a) = m.alias {
                            node.aliases.insert(a, name.clone());
                        }
                        node.metrics.insert(name.clone(), json_of(v));
                    }
                }
            }
            "NDEATH" => {
                if bd.is_none() || bd == node.bd_seq {
                    node.alive = false;
                }
            }
            _ => {
                node.ndata += 1;
                // seq comes off the wire: any u64, u64::MAX included (2^64 is a multiple of 256,
                // so the wrapping sum is the right residue).
                if let (Some(l), Some(s)) = (node.last_seq, p.seq)
                    && s != l.wrapping_add(1) % 256
                {
                    node.seq_gaps += 1;
                }
                node.last_seq = p.seq;
                for m in &p.metrics {
                    let name = m
                        .name
                        .clone()
                        .or_else(|| m.alias.and_then(|a| node.aliases.get(&a).cloned()));
                    if let (Some(name), Some(v)) = (name, &m.value)
                        && m.is_historical != Some(true)
                    {
                        node.metrics.insert(name, json_of(v));
                    }
                }
            }
        }
    }

    /// One line per node: group, edge node, verdict, bdSeq, NDATA count, seq gaps.
    pub fn table(&self) -> String {
        let mut s = format!(
            "{:<16} {:<20} {:<13} {:>5} {:>8} {:>5} {:>7}\n",
            "group", "edge node", "state", "bdSeq", "ndata", "gaps", "faults"
        );
        for n in self.nodes.values() {
            let faults = n
                .metrics
                .get("Gateway/active_faults")
                .and_then(serde_json::Value::as_u64)
                .unwrap_or(0);
            s.push_str(&format!(
                "{:<16} {:<20} {:<13} {:>5} {:>8} {:>5} {:>7}\n",
                n.group,
                n.edge_node,
                format!("{:?}", n.verdict()).to_lowercase(),
                n.bd_seq.map_or("-".into(), |b| b.to_string()),
                n.ndata,
                n.seq_gaps,
                faults
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::telemetry::sparkplug::EdgeNode;

    fn vals(mode: &str, faults: u32) -> Vec<(String, Value)> {
        vec![
            ("Gateway/enabled".into(), Value::Boolean(true)),
            ("Gateway/active_faults".into(), Value::Int(faults)),
            ("Axis/x/mode".into(), Value::String(mode.into())),
        ]
    }

    #[test]
    fn birth_data_and_death_give_the_verdict() {
        let mut f = FleetView::default();
        let mut e = EdgeNode::new(0);
        e.next_connect();
        let t = "spBv1.0/shop/NBIRTH/mill-1";
        f.ingest(t, &e.birth(&vals("tracking", 0), 1));
        let key = ("shop".to_string(), "mill-1".to_string());
        assert_eq!(f.nodes[&key].verdict(), Verdict::Compensating);
        f.ingest(
            "spBv1.0/shop/NDATA/mill-1",
            &e.data(&vals("holding", 1)[1..], 2, false),
        );
        assert_eq!(f.nodes[&key].verdict(), Verdict::Degraded);
        assert_eq!(f.nodes[&key].seq_gaps, 0);
        // A historical value does not replace the current one.
        f.ingest(
            "spBv1.0/shop/NDATA/mill-1",
            &e.data(&vals("tracking", 0)[1..], 1, true),
        );
        assert_eq!(f.nodes[&key].verdict(), Verdict::Degraded);
        f.ingest("spBv1.0/shop/NDEATH/mill-1", &e.death(3));
        assert_eq!(f.nodes[&key].verdict(), Verdict::Offline);
        assert!(f.table().contains("offline"));
    }

    #[test]
    fn a_late_will_of_an_older_session_does_not_kill_a_reborn_node() {
        let mut f = FleetView::default();
        let mut e = EdgeNode::new(0);
        e.next_connect();
        e.connected();
        let old_death = e.death(1);
        e.next_connect();
        f.ingest("spBv1.0/g/NBIRTH/n", &e.birth(&vals("tracking", 0), 2));
        f.ingest("spBv1.0/g/NDEATH/n", &old_death);
        let n = &f.nodes[&("g".to_string(), "n".to_string())];
        assert!(n.alive, "bdSeq 0's will must not end bdSeq 1's session");
        // A skipped seq is counted.
        let mut f2 = FleetView::default();
        f2.ingest("spBv1.0/g/NBIRTH/n", &e.birth(&vals("tracking", 0), 2));
        let _lost = e.data(&vals("tracking", 0), 3, false);
        f2.ingest("spBv1.0/g/NDATA/n", &e.data(&vals("tracking", 0), 4, false));
        assert_eq!(f2.nodes[&("g".to_string(), "n".to_string())].seq_gaps, 1);
    }
}
