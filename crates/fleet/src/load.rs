//! A fleet's load, for the fleet benches and their test (hil-sim's test program `fleet_load`;
//! benches/telemetry_fleet.rs, benches/fleet_processes.rs): simulated boxes that publish
//! through the same Sparkplug publisher as `retrocomp run` (crates/gateway/src/northbound/telemetry),
//! and the totals a fleet host ([`FleetView`]) has seen. A simulated box is a task that updates a
//! status snapshot at twice the telemetry rate (so every sampler tick has a change to send) instead
//! of a whole gateway. Units as the status snapshot (µm, mm); rates Hz; latencies ms.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::watch;

use crate::latency::LatencySummary;
use crate::{FleetView, Node};
use retrocomp_gateway::Mode;
use retrocomp_gateway::northbound::telemetry::{self, MqttConfig, PublisherInputs, TelemetryError};
use retrocomp_gateway::status::{AxisStatus, StatusSnapshot};
use retrocomp_model::approach::Approach;

/// The `k`-th status of a simulated box: three axes whose values change every time.
pub fn snapshot(k: u64) -> StatusSnapshot {
    #[allow(clippy::cast_precision_loss)]
    let kf = k as f64;
    let axes = ["x", "y", "z"]
        .iter()
        .map(|a| AxisStatus {
            axis: (*a).to_string(),
            position_mm: Some(kf * 0.5),
            direction: Some(Approach::Forward),
            weight_forward: 1.0,
            target_um: Some(-(kf % 50.0)),
            applied_um: -(kf % 50.0),
            mode: Mode::Tracking,
            terms_um: BTreeMap::from([
                ("geometric".to_string(), -(kf % 30.0)),
                ("thermal".to_string(), -(kf % 20.0)),
            ]),
            clamp_hits: 0,
            cap_hits: 0,
        })
        .collect();
    StatusSnapshot {
        t_s: kf * 0.001,
        cycles: k,
        enabled: true,
        axes,
        ..Default::default()
    }
}

/// A simulated box: a task that sends [`snapshot`] 1, 2, … to a publisher's status watch at twice
/// its telemetry rate `rate_hz`, until aborted.
pub fn feed(
    tx: watch::Sender<Option<Arc<StatusSnapshot>>>,
    rate_hz: f64,
) -> tokio::task::JoinHandle<()> {
    let period = Duration::from_secs_f64(0.5 / rate_hz);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        let mut k = 0;
        loop {
            tick.tick().await;
            k += 1;
            tx.send_replace(Some(Arc::new(snapshot(k))));
        }
    })
}

/// What a set of simulated boxes did, once every publisher finished (its queue acknowledged by
/// the broker, then NDEATH): records produced, dropped by a full queue, and left unsent.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BoxesReport {
    pub boxes: usize,
    pub produced: u64,
    pub dropped: u64,
    pub left: u64,
}

/// Runs `count` boxes named `box-<first>` …, each a real publisher of `cfg`'s broker, group, rate
/// and TLS; once every box is connected and born (or after `grace`) awaits `on_connected` with how
/// many are (a driver can hold the window there), runs `seconds` more, then finishes them all (up
/// to `grace` each) and reports their counters.
pub async fn run_boxes<F: Future<Output = ()>>(
    cfg: &MqttConfig,
    (first, count): (usize, usize),
    seconds: f64,
    grace: Duration,
    on_connected: impl FnOnce(usize) -> F,
) -> Result<BoxesReport, TelemetryError> {
    let mut pubs = Vec::with_capacity(count);
    let mut feeders = Vec::with_capacity(count);
    for i in first..first + count {
        let (tx, rx) = watch::channel(None);
        let mut c = cfg.clone();
        c.edge_node_id = format!("box-{i:05}");
        c.client_id = None;
        let p = telemetry::spawn(
            c,
            PublisherInputs {
                status: rx,
                model_identity: "fleet-load".into(),
                declared: Default::default(),
            },
        )?;
        feeders.push(feed(tx, cfg.rate_hz));
        pubs.push(p);
    }
    let mut connected = 0;
    let until = tokio::time::Instant::now() + grace;
    for p in &pubs {
        let mut st = p.status.clone();
        let born = tokio::time::timeout_at(until, st.wait_for(|s| s.connected)).await;
        connected += usize::from(matches!(born, Ok(Ok(_))));
    }
    on_connected(connected).await;
    tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
    for f in &feeders {
        f.abort();
    }
    // Every publisher finishes (its sampler stops; the session sends what is queued until the
    // broker acknowledged all of it, then NDEATH), so the counters are final.
    let mut finishing = tokio::task::JoinSet::new();
    for p in pubs {
        finishing.spawn(p.finish(grace));
    }
    let mut r = BoxesReport {
        boxes: count,
        ..BoxesReport::default()
    };
    while let Some(st) = finishing.join_next().await {
        let st = st.expect("a publisher's finish panicked");
        r.produced += st.records_total;
        r.dropped += st.dropped_total;
        r.left += st.queued;
    }
    Ok(r)
}

/// What a fleet host has seen: NDATA received (duplicates included), seq gaps, duplicates (an
/// NDATA with the seq of the one before), reordered and lost seqs, nodes, nodes offline (their NDEATH seen), births, and
/// the end-to-end latency of the NDATA.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct HostTotals {
    pub subscribed: bool,
    pub ndata: u64,
    pub gaps: u64,
    #[serde(default)]
    pub duplicates: u64,
    /// NDATA that filled a hole a later seq had left (`Node::reordered`).
    #[serde(default)]
    pub reordered: u64,
    /// Seqs skipped and never seen (`Node::lost`).
    #[serde(default)]
    pub lost: u64,
    pub nodes: usize,
    pub offline: usize,
    pub births: u64,
    pub latency: LatencySummary,
}

impl HostTotals {
    pub fn of(view: &FleetView, subscribed: bool) -> Self {
        let n = view.nodes.values();
        HostTotals {
            subscribed,
            ndata: n.clone().map(|n| n.ndata).sum(),
            gaps: n.clone().map(|n| n.seq_gaps).sum(),
            duplicates: n.clone().map(|n| n.duplicates).sum(),
            reordered: n.clone().map(|n| n.reordered).sum(),
            lost: n.clone().map(Node::lost).sum(),
            nodes: n.clone().count(),
            offline: n.clone().filter(|n| !n.alive).count(),
            births: n.map(|n| n.births).sum(),
            latency: view.ndata_latency.summary(),
        }
    }
}
