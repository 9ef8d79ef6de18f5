//! The fleet's health as a Sparkplug host sees it (sans-IO: messages and times are passed in,
//! outgoing NCMDs are taken out with [`FleetView::poll_transmit`]; `retrocomp fleet` is its MQTT
//! shell, crates/fleet/src/fleet_client.rs). Per edge node:
//! - **online** from any NBIRTH or NDATA (a host started after a box sees its data first: the box is
//!   online from that data, never offline while data flows); offline on an NDEATH whose bdSeq is
//!   the current session's (a late will of an older connection does not kill a re-born node);
//! - a **rebirth request** (NCMD `Node Control/Rebirth` = true, Sparkplug 3.0) when NDATA or an
//!   NDEATH comes from a node it has no birth for, or NDATA uses an alias its birth did not define;
//!   at most one per node per interval (`RebirthLimiter`);
//! - the latest metric values from NBIRTH (names and aliases) and NDATA (aliases), seq gaps, when
//!   it was last seen (host clock), its fault names, the applied correction per axis, and a
//!   verdict: offline, online (data flows, birth not seen yet), compensating, degraded (faults, an
//!   axis not tracking, the controller link down) or idle (compensation disabled).
//!
//! Each node's own state and seq accounting is [`crate::node`]; this module routes messages to
//! nodes, asks for rebirths and measures the NDATA latency.
//!
//! Units as the published metrics (µm, mm); times ms since the Unix epoch.

use std::collections::{BTreeMap, VecDeque};

use prost::Message;

use crate::latency::LatencyHistogram;
use crate::node::Node;
use retrocomp_gateway::northbound::telemetry::sparkplug::{
    self, BD_SEQ, DataType, Kind, Metric, Payload, REBIRTH, Value,
};

/// Rebirth requests per node, at most one per this long by default, ms.
pub const DEFAULT_REBIRTH_INTERVAL_MS: u64 = 5000;

/// Every edge node seen, by (group, edge node), and the NCMDs the host has to send.
#[derive(Debug)]
pub struct FleetView {
    pub nodes: BTreeMap<(String, String), Node>,
    rebirth_interval_ms: u64,
    /// (topic, payload) of NCMDs to publish.
    outbox: VecDeque<(String, Vec<u8>)>,
    /// End-to-end latency of every NDATA with a timestamp (arrival minus its timestamp) from
    /// `latency_since_ms` on.
    pub ndata_latency: LatencyHistogram,
    latency_since_ms: u64,
    /// Some node may hold a deferred rebirth request (only a request defers one): without it the
    /// per-message polls skip the walk over every node, which at 2000 nodes × 20 000 messages/s
    /// was the host's bottleneck.
    maybe_deferred: bool,
}

impl Default for FleetView {
    fn default() -> Self {
        FleetView::new(DEFAULT_REBIRTH_INTERVAL_MS)
    }
}

/// NCMD `Node Control/Rebirth` = true.
pub fn rebirth_request(now_ms: u64) -> Vec<u8> {
    Payload {
        timestamp: Some(now_ms),
        metrics: vec![Metric {
            name: Some(REBIRTH.into()),
            timestamp: Some(now_ms),
            datatype: Some(DataType::Boolean as u32),
            value: Some(Value::Boolean(true)),
            ..Default::default()
        }],
        ..Default::default()
    }
    .encode_to_vec()
}

impl FleetView {
    /// `rebirth_interval_ms`: at most one rebirth request per node per this long.
    pub fn new(rebirth_interval_ms: u64) -> Self {
        FleetView {
            nodes: BTreeMap::new(),
            rebirth_interval_ms,
            outbox: VecDeque::new(),
            ndata_latency: LatencyHistogram::default(),
            latency_since_ms: 0,
            maybe_deferred: false,
        }
    }

    /// Take one message (`spBv1.0/<group>/<type>/<edge node>`) received at `now_ms` (host clock,
    /// ms since the Unix epoch); other topics are ignored. True when the view changed.
    pub fn handle_message(&mut self, topic: &str, payload: &[u8], now_ms: u64) -> bool {
        let parts: Vec<&str> = topic.split('/').collect();
        let [ns, group, kind, edge] = parts[..] else {
            return false;
        };
        if ns != "spBv1.0" || !matches!(kind, "NBIRTH" | "NDATA" | "NDEATH") {
            return false;
        }
        let Ok(p) = Payload::decode(payload) else {
            return false;
        };
        let interval = self.rebirth_interval_ms;
        let node = self
            .nodes
            .entry((group.to_string(), edge.to_string()))
            .or_insert_with(|| Node::new(group, edge, interval));
        node.last_ms = node.last_ms.max(p.timestamp.unwrap_or(0));
        node.last_seen_ms = node.last_seen_ms.max(now_ms);
        let bd = p.metrics.iter().find_map(|m| {
            (m.name.as_deref() == Some(BD_SEQ)).then_some(())?;
            match m.value {
                Some(Value::Long(v)) => Some(v),
                _ => None,
            }
        });
        let rebirth = match kind {
            "NBIRTH" => {
                node.birth(&p, bd, now_ms);
                false
            }
            "NDEATH" => node.death(bd),
            _ => {
                if let Some(t) = p.timestamp
                    && t >= self.latency_since_ms
                {
                    self.ndata_latency.record(now_ms.saturating_sub(t));
                }
                node.data(&p)
            }
        };
        self.maybe_deferred |= rebirth;
        if rebirth && node.want_rebirth(now_ms) {
            self.outbox.push_back((
                sparkplug::topic(group, Kind::NCmd, edge),
                rebirth_request(now_ms),
            ));
        }
        true
    }

    /// Start the latency histogram again, counting only NDATA sampled at or after `since_ms`
    /// (box clock, ms since the Unix epoch): e.g. the steady state after a fleet's connect storm.
    pub fn reset_latency(&mut self, since_ms: u64) {
        self.ndata_latency = LatencyHistogram::default();
        self.latency_since_ms = since_ms;
    }

    /// The next NCMD to publish (topic, payload), deferred rebirth requests included once due.
    pub fn poll_transmit(&mut self, now_ms: u64) -> Option<(String, Vec<u8>)> {
        if self.outbox.is_empty() && self.maybe_deferred {
            let mut still = false;
            for n in self.nodes.values_mut() {
                if n.rebirth.poll(now_ms) {
                    n.rebirths_requested += 1;
                    self.outbox.push_back((
                        sparkplug::topic(&n.group, Kind::NCmd, &n.edge_node),
                        rebirth_request(now_ms),
                    ));
                }
                still |= n.rebirth.due_ms().is_some();
            }
            self.maybe_deferred = still;
        }
        self.outbox.pop_front()
    }

    /// When a deferred rebirth request becomes due (ms, the clock of `handle_message`).
    pub fn poll_timeout(&self) -> Option<u64> {
        if !self.maybe_deferred {
            return None;
        }
        self.nodes.values().filter_map(|n| n.rebirth.due_ms()).min()
    }

    /// One line per node: group, edge node, verdict, bdSeq, NDATA count, seq gaps, seconds since
    /// it was last seen (at `now_ms`), applied correction per axis (µm), fault names.
    pub fn table(&self, now_ms: u64) -> String {
        let mut s = format!(
            "{:<16} {:<20} {:<13} {:>5} {:>8} {:>5} {:>7}  {:<24} {}\n",
            "group",
            "edge node",
            "state",
            "bdSeq",
            "ndata",
            "gaps",
            "seen_s",
            "applied_um",
            "faults"
        );
        for n in self.nodes.values() {
            let applied: Vec<String> = n
                .applied_um()
                .iter()
                .map(|(a, v)| format!("{a}:{v:.2}"))
                .collect();
            let seen_s = now_ms.saturating_sub(n.last_seen_ms) as f64 / 1000.0;
            s.push_str(&format!(
                "{:<16} {:<20} {:<13} {:>5} {:>8} {:>5} {:>7.1}  {:<24} {}\n",
                n.group,
                n.edge_node,
                format!("{:?}", n.verdict()).to_lowercase(),
                n.bd_seq.map_or("-".into(), |b| b.to_string()),
                n.ndata,
                n.seq_gaps,
                seen_s,
                applied.join(" "),
                n.faults().join(",")
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Verdict;
    use retrocomp_gateway::northbound::telemetry::sparkplug::EdgeNode;

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
        f.handle_message(t, &e.birth(&vals("tracking", 0), 1), 1);
        let key = ("shop".to_string(), "mill-1".to_string());
        assert_eq!(f.nodes[&key].verdict(), Verdict::Compensating);
        f.handle_message(
            "spBv1.0/shop/NDATA/mill-1",
            &e.data(&vals("holding", 1)[1..], 2, false),
            0,
        );
        assert_eq!(f.nodes[&key].verdict(), Verdict::Degraded);
        assert_eq!(f.nodes[&key].seq_gaps, 0);
        // A historical value does not replace the current one.
        f.handle_message(
            "spBv1.0/shop/NDATA/mill-1",
            &e.data(&vals("tracking", 0)[1..], 1, true),
            0,
        );
        assert_eq!(f.nodes[&key].verdict(), Verdict::Degraded);
        f.handle_message("spBv1.0/shop/NDEATH/mill-1", &e.death(3), 0);
        assert_eq!(f.nodes[&key].verdict(), Verdict::Offline);
        assert!(f.table(0).contains("offline"));
    }

    #[test]
    fn a_late_will_of_an_older_session_does_not_kill_a_reborn_node() {
        let mut f = FleetView::default();
        let mut e = EdgeNode::new(0);
        e.next_connect();
        e.connected();
        let old_death = e.death(1);
        e.next_connect();
        f.handle_message("spBv1.0/g/NBIRTH/n", &e.birth(&vals("tracking", 0), 2), 0);
        f.handle_message("spBv1.0/g/NDEATH/n", &old_death, 0);
        let n = &f.nodes[&("g".to_string(), "n".to_string())];
        assert!(n.alive, "bdSeq 0's will must not end bdSeq 1's session");
        // A skipped seq is counted.
        let mut f2 = FleetView::default();
        f2.handle_message("spBv1.0/g/NBIRTH/n", &e.birth(&vals("tracking", 0), 2), 0);
        let _lost = e.data(&vals("tracking", 0), 3, false);
        f2.handle_message(
            "spBv1.0/g/NDATA/n",
            &e.data(&vals("tracking", 0), 4, false),
            0,
        );
        assert_eq!(f2.nodes[&("g".to_string(), "n".to_string())].seq_gaps, 1);
    }

    #[test]
    fn an_ndata_resent_with_the_same_seq_is_a_duplicate_not_a_gap() {
        let mut f = FleetView::default();
        let mut e = EdgeNode::new(0);
        e.next_connect();
        f.handle_message("spBv1.0/g/NBIRTH/n", &e.birth(&vals("tracking", 0), 1), 0);
        let d1 = e.data(&vals("tracking", 0), 2, false);
        f.handle_message("spBv1.0/g/NDATA/n", &d1, 0);
        // A QoS 1 resend: the broker got it, its PUBACK was lost.
        f.handle_message("spBv1.0/g/NDATA/n", &d1, 0);
        f.handle_message(
            "spBv1.0/g/NDATA/n",
            &e.data(&vals("tracking", 0), 3, false),
            0,
        );
        let n = &f.nodes[&("g".to_string(), "n".to_string())];
        assert_eq!((n.ndata, n.duplicates, n.seq_gaps), (3, 1, 0));
    }

    /// A host started after the box: NDATA first (aliases only).
    fn running_box() -> (EdgeNode, Vec<(String, Value)>) {
        let mut e = EdgeNode::new(7);
        e.next_connect();
        let mut v = vals("tracking", 1);
        v.push(("Gateway/faults".into(), Value::String("can:stale".into())));
        v.push(("Axis/x/applied_um".into(), Value::Double(-3.25)));
        let _birth_before_the_host_came = e.birth(&v, 0);
        (e, v)
    }

    #[test]
    fn data_without_a_birth_is_online_and_asks_for_one_rebirth_per_interval() {
        let mut f = FleetView::new(5000);
        let (mut e, v) = running_box();
        let key = ("shop".to_string(), "mill-1".to_string());
        let t = "spBv1.0/shop/NDATA/mill-1";
        // 10 Hz for 12 s of virtual time, the host polled after every message.
        let mut ncmds = vec![];
        for i in 0..120u64 {
            let now = 1_000_000 + i * 100;
            assert!(f.handle_message(t, &e.data(&v, now, false), now));
            assert_eq!(
                f.nodes[&key].verdict(),
                Verdict::Online,
                "data flows: online"
            );
            while let Some((topic, payload)) = f.poll_transmit(now) {
                assert_eq!(topic, "spBv1.0/shop/NCMD/mill-1");
                assert!(sparkplug::is_rebirth_request(&payload));
                ncmds.push(now);
            }
        }
        assert_eq!(ncmds, vec![1_000_000, 1_005_000, 1_010_000], "one per 5 s");
        let n = &f.nodes[&key];
        assert_eq!((n.rebirths_requested, n.ndata, n.born), (3, 120, false));
        assert_eq!(n.last_seen_ms, 1_011_900);
        assert!(
            n.unknown_aliases > 0,
            "aliases without a birth cannot be named"
        );
        // The box answers: born, and what the birth says.
        let now = 1_012_000;
        f.handle_message("spBv1.0/shop/NBIRTH/mill-1", &e.birth(&v, now), now);
        let n = &f.nodes[&key];
        assert_eq!(n.verdict(), Verdict::Degraded, "one active fault");
        assert_eq!(n.bd_seq, Some(7));
        assert_eq!(n.faults(), vec!["can:stale".to_string()]);
        assert_eq!(n.applied_um()["x"], -3.25);
        let j = n.to_json();
        assert_eq!(j["verdict"], "degraded");
        assert_eq!(j["applied_um"]["x"], -3.25);
        assert_eq!(j["faults"][0], "can:stale");
        // Born: its data asks for nothing more, even long after.
        let later = now + 60_000;
        f.handle_message(t, &e.data(&v[..1], later, false), later);
        assert_eq!(f.poll_transmit(later), None);
        assert_eq!(f.poll_timeout(), None);
        let table = f.table(later + 2500);
        assert!(
            table.contains("degraded") && table.contains("x:-3.25"),
            "{table}"
        );
        assert!(
            table.contains("can:stale") && table.contains("2.5"),
            "{table}"
        );
    }

    #[test]
    fn a_deferred_request_goes_out_when_due_and_a_birth_cancels_it() {
        let mut f = FleetView::new(5000);
        let (mut e, v) = running_box();
        let t = "spBv1.0/shop/NDATA/mill-1";
        f.handle_message(t, &e.data(&v, 0, false), 0);
        assert!(f.poll_transmit(0).is_some());
        f.handle_message(t, &e.data(&v, 1000, false), 1000);
        assert_eq!(f.poll_transmit(1000), None, "inside the interval");
        assert_eq!(f.poll_timeout(), Some(5000));
        assert_eq!(f.poll_transmit(4999), None);
        assert!(f.poll_transmit(5000).is_some(), "due without new data");
        f.handle_message(t, &e.data(&v, 6000, false), 6000);
        f.handle_message("spBv1.0/shop/NBIRTH/mill-1", &e.birth(&v, 6100), 6100);
        assert_eq!(f.poll_timeout(), None, "the birth answered it");
        assert_eq!(f.poll_transmit(20_000), None);
    }

    #[test]
    fn a_death_without_a_birth_asks_and_data_after_it_is_online_again() {
        let mut f = FleetView::new(5000);
        let (mut e, v) = running_box();
        let key = ("g".to_string(), "n".to_string());
        f.handle_message("spBv1.0/g/NDEATH/n", &e.death(0), 0);
        assert_eq!(f.nodes[&key].verdict(), Verdict::Offline);
        assert!(f.poll_transmit(0).is_some(), "maybe a late will: ask");
        f.handle_message("spBv1.0/g/NDATA/n", &e.data(&v, 10, false), 10);
        assert_eq!(f.nodes[&key].verdict(), Verdict::Online);
        // Born (a birth the host saw with fewer metrics than the data uses), then an alias that
        // birth did not define: ask again.
        let mut smaller = EdgeNode::new(7);
        smaller.next_connect();
        f.handle_message("spBv1.0/g/NBIRTH/n", &smaller.birth(&v[..2], 6000), 6000);
        f.handle_message("spBv1.0/g/NDATA/n", &e.data(&v, 6010, false), 6010);
        assert_eq!(
            f.poll_transmit(6010),
            None,
            "the birth at 6000 restarted the interval"
        );
        assert!(
            f.poll_transmit(11_000).is_some(),
            "then the unknown alias is asked about"
        );
    }
}
