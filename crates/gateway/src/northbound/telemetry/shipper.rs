//! The I/O shell that ships a recording's chunks ([`super::recordings`]) to an MQTT topic: the
//! chunks go into the same bounded store-and-forward [`Queue`] as the telemetry (on disk when a
//! directory is given) and leave it when the broker acknowledged them (QoS 1). A broken link
//! drops the client and, after a back-off, a new one sends again from the first chunk not
//! acknowledged; a process stopped mid-way leaves the rest on disk, and the next `ship` (same
//! queue directory) sends it first. Order is kept: one client, publishes in queue order, and
//! rumqttc/Mosquitto keep a session's order. The client id is the telemetry client id + `.rec`
//! (the same id would take the box's telemetry session over).

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::Duration;

use rumqttc::{AsyncClient, Event, Outgoing, Packet, QoS};

use super::TelemetryError;
use super::config::MqttConfig;
use super::queue::{DropPolicy, Queue, QueueLimits};
use super::recordings::Chunk;
use retrocomp_bus::Backoff;

/// Default topic of a machine's recordings: `retrocomp/recordings/<group>/<edge node>`.
pub fn default_topic(group: &str, edge_node: &str) -> String {
    format!("retrocomp/recordings/{group}/{edge_node}")
}

/// Chunks published and not yet acknowledged, at most.
const WINDOW: usize = 16;

#[derive(Debug)]
pub struct Shipment {
    pub mqtt: MqttConfig,
    pub topic: String,
    /// Queue directory (resumable across a restart); None: memory only.
    pub queue_dir: Option<PathBuf>,
}

/// What a `ship` did.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct ShipReport {
    /// Chunks acknowledged by the broker.
    pub acked: u64,
    /// Chunks still queued (on disk with a queue directory) when the deadline came.
    pub left: u64,
    pub connections: u64,
}

/// Queue `chunks` (after whatever an earlier, interrupted shipment left in the queue directory)
/// and send until the queue is empty or `deadline` passes. Never drops a chunk: the queue is
/// bounded only by the disk (a chunk dropped would make the recording useless).
pub async fn ship(
    s: &Shipment,
    chunks: &[Chunk],
    deadline: Duration,
) -> Result<ShipReport, TelemetryError> {
    let mut q = Queue::open(QueueLimits {
        dir: s.queue_dir.clone(),
        max_records: usize::MAX,
        max_bytes: u64::MAX,
        policy: DropPolicy::DropNewest,
    })
    .map_err(TelemetryError::setup("recording shipment queue"))?;
    for c in chunks {
        q.push(c.encode());
    }
    let mut base = super::publisher::base_options(&s.mqtt)?;
    base.set_client_id(format!("{}.rec", s.mqtt.client_id()));
    let mut report = ShipReport::default();
    let end = tokio::time::sleep(deadline);
    tokio::pin!(end);
    let mut backoff = Backoff::from_millis(s.mqtt.reconnect_min_ms, s.mqtt.reconnect_max_ms);
    while !q.is_empty() {
        report.connections += 1;
        let (client, mut el) = AsyncClient::new(base.clone(), 2 * WINDOW);
        // Publish call order → queue ids, matched with the packet ids as they go out.
        let mut calls: VecDeque<u64> = VecDeque::new();
        let mut inflight: std::collections::HashMap<u16, u64> = Default::default();
        let mut next_send = 0;
        let mut up = false;
        let lost = loop {
            if up {
                while calls.len() + inflight.len() < WINDOW {
                    let Some(e) = q.first_from(next_send) else {
                        break;
                    };
                    let (id, bytes) = (e.id, e.bytes.clone());
                    if client
                        .try_publish(s.topic.clone(), QoS::AtLeastOnce, false, bytes)
                        .is_err()
                    {
                        break;
                    }
                    calls.push_back(id);
                    next_send = id + 1;
                }
            }
            if q.is_empty() {
                let _ = client.try_disconnect();
                let _ = tokio::time::timeout(Duration::from_secs(2), async {
                    while let Ok(ev) = el.poll().await {
                        if matches!(ev, Event::Outgoing(Outgoing::Disconnect)) {
                            break;
                        }
                    }
                })
                .await;
                return Ok(report);
            }
            tokio::select! {
                _ = &mut end => {
                    report.left = q.len() as u64;
                    return Ok(report);
                }
                ev = el.poll() => match ev {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        up = true;
                        backoff.reset();
                    }
                    Ok(Event::Outgoing(Outgoing::Publish(pkid))) => {
                        if let Some(id) = calls.pop_front() {
                            inflight.insert(pkid, id);
                        }
                    }
                    Ok(Event::Incoming(Packet::PubAck(a))) => {
                        if let Some(id) = inflight.remove(&a.pkid) {
                            q.remove(id);
                            report.acked += 1;
                        }
                    }
                    Ok(_) => {}
                    Err(e) => break e,
                },
            }
        };
        tracing::warn!(%lost, "recording shipment: MQTT link down; resending the rest after a reconnect");
        // A fresh client next time (rumqttc would replay its own pending publishes out of our order).
        drop(client);
        drop(el);
        tokio::select! {
            _ = &mut end => {
                report.left = q.len() as u64;
                return Ok(report);
            }
            _ = tokio::time::sleep(backoff.next_delay()) => {}
        }
    }
    Ok(report)
}
