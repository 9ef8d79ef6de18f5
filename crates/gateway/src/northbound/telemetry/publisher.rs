//! The I/O shell of the Sparkplug B edge node: two tasks fed from the gateway's status watch.
//!
//! - the **sampler** reads the latest snapshot (cloning an `Arc`, never holding the watch's lock,
//!   so the cycle's `send` never waits on us), builds records at `rate_hz` (and at once on a
//!   state change), and hands them on over a bounded channel with `try_send`: a full channel
//!   counts a drop, it never waits. The compensation cycle cannot be slowed by anything below.
//! - the **session** task owns the MQTT connection (rumqttc), the Sparkplug numbers
//!   ([`EdgeNode`]) and the store-and-forward [`Queue`]: every record goes into the queue first
//!   and leaves it when the broker acknowledged it (QoS 1). Each connection is a fresh rumqttc
//!   client whose will is the NDEATH of a new bdSeq; after CONNACK (and, with a primary host,
//!   once its STATE says online) it publishes NBIRTH, then the queue in order (records older
//!   than this NBIRTH flagged `is_historical`, each with its source timestamp), then live data.
//!   A broken link drops the client (rumqttc would otherwise replay its own pending publishes
//!   before our NBIRTH); what was not acknowledged is still queued and goes again after the next
//!   NBIRTH. An NCMD `Node Control/Rebirth` = true is answered with a new NBIRTH, at most one per
//!   `rebirth_min_interval_s` ([`RebirthLimiter`]; a request inside it is answered at its end).

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use rumqttc::{
    AsyncClient, ConnectionError, Event, EventLoop, LastWill, MqttOptions, Outgoing, Packet, QoS,
};
use tokio::sync::{mpsc, watch};

use super::TelemetryError;
pub(crate) use super::annotate::TelemetryAnnotator;
use super::config::MqttConfig;
use super::declare::{Declaration, birth_table};
use super::metrics::{Record, Sampler, snapshot_metrics};
use super::queue::{self, Queue, QueueLimits};
use super::rebirth::RebirthLimiter;
use super::sparkplug::{self, EdgeNode, Kind, MetricSpec, NamedValue};
pub(crate) use super::status::TelemetryStatus;
use crate::status::StatusSnapshot;
use retrocomp_bus::Backoff;

/// What the publisher needs besides its config.
#[derive(Debug)]
pub struct PublisherInputs {
    pub status: watch::Receiver<Option<Arc<StatusSnapshot>>>,
    /// Model identity published as `Model/identity` (file name, fit date...).
    pub model_identity: String,
    /// Every metric the box can publish (field config and model): one NBIRTH per session.
    pub declared: Declaration,
}

/// The running publisher: its status, and a stop that sends NDEATH and disconnects.
#[derive(Debug)]
pub struct Publisher {
    pub status: watch::Receiver<TelemetryStatus>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    session: tokio::task::JoinHandle<()>,
    sampler: tokio::task::JoinHandle<()>,
}

impl Publisher {
    /// What the cycle loop uses to show this publisher in the status snapshots.
    pub fn annotator(&self) -> TelemetryAnnotator {
        TelemetryAnnotator::new(self.status.clone())
    }

    /// Stop: the sampler ends, the session sends NDEATH (if connected) and disconnects; waits at
    /// most `grace` for that.
    pub async fn stop(mut self, grace: Duration) {
        self.sampler.abort();
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if tokio::time::timeout(grace, &mut self.session)
            .await
            .is_err()
        {
            self.session.abort();
        }
    }

    /// Stop after sending what is left: the sampler ends (records it already handed over are
    /// kept), the session sends the queue until the broker acknowledged every record, then
    /// NDEATH and DISCONNECT. After `grace` it stops as [`Publisher::stop`] does (what is still
    /// queued stays in the disk queue, if any). Returns the final status (counters complete:
    /// `records_total` is every record the sampler produced and did not drop).
    pub async fn finish(mut self, grace: Duration) -> TelemetryStatus {
        self.sampler.abort();
        let _ = (&mut self.sampler).await;
        if tokio::time::timeout(grace, &mut self.session)
            .await
            .is_err()
        {
            if let Some(s) = self.stop.take() {
                let _ = s.send(());
            }
            if tokio::time::timeout(Duration::from_secs(2), &mut self.session)
                .await
                .is_err()
            {
                self.session.abort();
            }
        }
        self.stop = None;
        self.status.borrow().clone()
    }
}

impl Drop for Publisher {
    fn drop(&mut self) {
        self.sampler.abort();
        if self.stop.is_some() {
            self.session.abort();
        }
    }
}

/// The wall clock, ms since the Unix epoch (Sparkplug timestamps; the fleet host's last-seen).
pub fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

/// Hand-over channel between sampler and session, records.
const HANDOVER: usize = 1024;
/// Records published and not yet acknowledged, at most.
const WINDOW: usize = 64;

/// Start the publisher (spawns its tasks on the current runtime). Fails only on what the config
/// check cannot see: an unreadable queue directory, a bad certificate.
pub fn spawn(cfg: MqttConfig, inputs: PublisherInputs) -> Result<Publisher, TelemetryError> {
    let queue = Queue::open(QueueLimits {
        dir: cfg.queue.dir.clone(),
        max_records: cfg.queue.max_records,
        max_bytes: cfg.queue.max_bytes,
        policy: cfg.queue.drop_policy,
    })
    .map_err(TelemetryError::setup("telemetry.mqtt.queue.dir"))?;
    let base = base_options(&cfg)?;
    let (rec_tx, rec_rx) = mpsc::channel::<Record>(HANDOVER);
    let (status_tx, status_rx) = watch::channel(TelemetryStatus::default());
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel();
    let handover_drops = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let declared = inputs.declared.specs();
    let sampler = tokio::spawn(sampler_task(
        inputs,
        cfg.rate_hz,
        rec_tx,
        handover_drops.clone(),
    ));
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        reason = "the config refuses a negative or non-finite interval; `as` saturates a huge one"
    )]
    let min_interval_ms = (cfg.rebirth_min_interval_s.max(0.0) * 1000.0) as u64;
    let rebirths = RebirthLimiter::new(min_interval_ms);
    let session = tokio::spawn(
        Session {
            cfg,
            base,
            queue,
            edge: EdgeNode::new(0),
            rebirths,
            clock: tokio::time::Instant::now(),
            records: rec_rx,
            status: status_tx,
            handover_drops,
            records_open: true,
            current: Vec::new(),
            declared,
            records_total: 0,
            acked_total: 0,
            births_total: 0,
        }
        .run(stop_rx),
    );
    Ok(Publisher {
        status: status_rx,
        stop: Some(stop_tx),
        session,
        sampler,
    })
}

pub(crate) fn base_options(cfg: &MqttConfig) -> Result<MqttOptions, TelemetryError> {
    let (host, port) = cfg
        .host_port()
        .map_err(|e| TelemetryError::Invalid(format!("telemetry.mqtt.broker: {e}")))?;
    let mut o = MqttOptions::new(cfg.client_id(), host, port);
    o.set_keep_alive(Duration::from_secs(cfg.keep_alive_s));
    // Sparkplug: a clean session per connection (`principles-persistence-clean-session`).
    o.set_clean_session(true);
    o.set_max_packet_size(1 << 20, 1 << 20);
    o.set_request_channel_capacity(4 * WINDOW);
    if let Some(user) = &cfg.username {
        let pw = match &cfg.password_file {
            Some(p) => std::fs::read_to_string(p)
                .map_err(TelemetryError::setup(format!(
                    "telemetry.mqtt.password_file {}",
                    p.display()
                )))?
                .lines()
                .next()
                .unwrap_or_default()
                .to_string(),
            None => String::new(),
        };
        o.set_credentials(user.clone(), pw);
    }
    if let Some(t) = &cfg.tls {
        o.set_transport(rumqttc::Transport::tls_with_config(
            rumqttc::TlsConfiguration::Rustls(Arc::new(super::tls::client_config(t)?)),
        ));
    }
    Ok(o)
}

/// Snapshot → records. Never waits on the session: a full hand-over channel is a counted drop.
async fn sampler_task(
    mut inputs: PublisherInputs,
    rate_hz: f64,
    tx: mpsc::Sender<Record>,
    drops: Arc<std::sync::atomic::AtomicU64>,
) {
    let mut sampler = Sampler::default();
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate_hz));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut warned = false;
    loop {
        let due = tokio::select! {
            _ = tick.tick() => true,
            ch = inputs.status.changed() => {
                if ch.is_err() {
                    return;
                }
                false
            }
        };
        // Clone the Arc and let go of the watch at once (the cycle's send takes its write lock).
        let Some(snap) = inputs.status.borrow_and_update().clone() else {
            continue;
        };
        let now = snapshot_metrics(&snap, &inputs.model_identity);
        if !due && !sampler.state_changed(&now) {
            continue;
        }
        if let Some(rec) = sampler.record(now, now_ms()) {
            match tx.try_send(rec) {
                Ok(()) => warned = false,
                Err(mpsc::error::TrySendError::Full(_)) => {
                    drops.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    if !warned {
                        warned = true;
                        tracing::warn!(
                            "telemetry: the session task is behind; dropping records (counted)"
                        );
                    }
                }
                Err(mpsc::error::TrySendError::Closed(_)) => return,
            }
        }
    }
}

/// A connection's progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// CONNECT sent, no CONNACK yet.
    Connecting,
    /// Connected; waiting for the primary host's STATE online before NBIRTH.
    WaitingHost,
    /// Connected (and the host online); waiting for the first snapshot: an NBIRTH must announce
    /// every metric with its value.
    WaitingData,
    /// NBIRTH sent: data flows.
    Born,
}

/// Why a connection ended.
enum End {
    Lost(String),
    Stop,
    HostOffline,
}

struct Session {
    cfg: MqttConfig,
    base: MqttOptions,
    queue: Queue,
    edge: EdgeNode,
    /// NCMD rebirths honoured at most once per interval (ms since `clock`).
    rebirths: RebirthLimiter,
    clock: tokio::time::Instant,
    records: mpsc::Receiver<Record>,
    status: watch::Sender<TelemetryStatus>,
    handover_drops: Arc<std::sync::atomic::AtomicU64>,
    /// False once the sampler ended (a finish): send what is queued, then NDEATH and stop.
    records_open: bool,
    /// Latest value of every metric (what an NBIRTH announces).
    current: Vec<NamedValue>,
    /// The declared metric set (NBIRTH order, units, ranges).
    declared: Vec<MetricSpec>,
    records_total: u64,
    acked_total: u64,
    births_total: u64,
}

/// One connection's bookkeeping.
struct Conn {
    client: AsyncClient,
    events: mpsc::Receiver<Result<Event, ConnectionError>>,
    pump: tokio::task::JoinHandle<()>,
    phase: Phase,
    /// Our publishes in call order (queue id, or None for NBIRTH/NDEATH), matched to the packet
    /// ids rumqttc reports as they go out.
    calls: VecDeque<Option<u64>>,
    /// Packet id → queue id of records awaiting PUBACK.
    inflight: HashMap<u16, u64>,
    /// The next queue id to send.
    next_send: u64,
    /// Queue ids below this were queued before the NBIRTH: sent as historical.
    live_from: u64,
}

impl Drop for Conn {
    fn drop(&mut self) {
        self.pump.abort();
    }
}

impl Session {
    async fn run(mut self, mut stop: tokio::sync::oneshot::Receiver<()>) {
        let mut backoff =
            Backoff::from_millis(self.cfg.reconnect_min_ms, self.cfg.reconnect_max_ms);
        let mut down_logged = false;
        loop {
            let (end, was_born) = self.connection(&mut stop).await;
            let why = match end {
                End::Stop => return,
                End::HostOffline => "primary host went offline".to_string(),
                End::Lost(e) => e,
            };
            if was_born {
                // The link had been up: a new outage (logged again), back-off from the start.
                down_logged = false;
                backoff.reset();
            }
            if !down_logged {
                // Fault start, once per outage; the clear is logged with the next NBIRTH.
                tracing::error!(
                    why,
                    broker = self.cfg.broker,
                    "telemetry: MQTT link down; queueing records"
                );
                down_logged = true;
            }
            self.publish_status(false, Some(why));
            // Back off, still taking records into the queue.
            let wake = tokio::time::sleep(backoff.next_delay());
            tokio::pin!(wake);
            loop {
                tokio::select! {
                    _ = &mut wake => break,
                    _ = &mut stop => return,
                    r = self.records.recv(), if self.records_open => match r {
                        Some(r) => {
                            self.enqueue(r);
                            self.publish_status(false, None);
                        }
                        // Finishing: what is queued still goes after the reconnect.
                        None => self.records_open = false,
                    },
                }
            }
        }
    }

    fn enqueue(&mut self, r: Record) {
        for (n, v) in &r.values {
            match self.current.iter_mut().find(|(m, _)| m == n) {
                Some(slot) => slot.1 = v.clone(),
                None => self.current.push((n.clone(), v.clone())),
            }
        }
        self.queue.push(queue::encode(&r));
        self.records_total += 1;
    }

    fn publish_status(&self, connected: bool, last_error: Option<String>) {
        let st = TelemetryStatus {
            connected,
            bd_seq: self.edge.bd_seq(),
            queued: self.queue.len() as u64,
            queued_bytes: self.queue.bytes(),
            dropped_total: self.queue.dropped_total()
                + self
                    .handover_drops
                    .load(std::sync::atomic::Ordering::Relaxed),
            records_total: self.records_total,
            acked_total: self.acked_total,
            births_total: self.births_total,
            last_error,
        };
        self.status.send_if_modified(|old| {
            let changed = *old != st;
            *old = st;
            changed
        });
    }

    fn open(&mut self) -> Conn {
        self.edge.next_connect();
        let mut o = self.base.clone();
        let g = &self.cfg.group_id;
        let n = &self.cfg.edge_node_id;
        // NDEATH as the will: QoS 1, not retained (`payloads-ndeath-will-message-qos/-retain`).
        o.set_last_will(LastWill::new(
            sparkplug::topic(g, Kind::NDeath, n),
            self.edge.death(now_ms()),
            QoS::AtLeastOnce,
            false,
        ));
        let (client, eventloop) = AsyncClient::new(o, 4 * WINDOW);
        let (tx, events) = mpsc::channel(4 * WINDOW);
        let pump = tokio::spawn(pump_events(eventloop, tx));
        Conn {
            client,
            events,
            pump,
            phase: Phase::Connecting,
            calls: VecDeque::new(),
            inflight: HashMap::new(),
            next_send: 0,
            live_from: u64::MAX,
        }
    }

    /// One MQTT connection, until it ends; also says whether it got as far as NBIRTH.
    async fn connection(&mut self, stop: &mut tokio::sync::oneshot::Receiver<()>) -> (End, bool) {
        let mut c = self.open();
        let end = self.drive(&mut c, stop).await;
        (end, c.live_from != u64::MAX)
    }

    async fn drive(&mut self, c: &mut Conn, stop: &mut tokio::sync::oneshot::Receiver<()>) -> End {
        let g = self.cfg.group_id.clone();
        let n = self.cfg.edge_node_id.clone();
        let ncmd = sparkplug::topic(&g, Kind::NCmd, &n);
        let state = self
            .cfg
            .primary_host_id
            .as_deref()
            .map(sparkplug::state_topic);
        loop {
            let rebirth_due = self
                .rebirths
                .due_ms()
                .map(|ms| self.clock + Duration::from_millis(ms));
            tokio::select! {
                _ = tokio::time::sleep_until(rebirth_due.unwrap_or(self.clock)), if rebirth_due.is_some() => {
                    let now = self.clock_ms();
                    if self.rebirths.poll(now) && c.phase == Phase::Born {
                        self.birth(c);
                    }
                }
                _ = &mut *stop => {
                    if c.phase == Phase::Born {
                        self.say_goodbye(c).await;
                    }
                    return End::Stop;
                }
                r = self.records.recv(), if self.records_open => match r {
                    Some(r) => {
                        let rebirth = (c.phase == Phase::Born && !self.edge.knows_all(&r.values))
                            || c.phase == Phase::WaitingData;
                        self.enqueue(r);
                        if rebirth {
                            // A metric the NBIRTH did not announce: announce it first.
                            self.birth(c);
                        }
                    }
                    // The sampler ended (a finish): drain the queue, then say goodbye.
                    None => self.records_open = false,
                },
                ev = c.events.recv() => match ev {
                    None => return End::Lost("event loop ended".into()),
                    Some(Err(e)) => return End::Lost(e.to_string()),
                    Some(Ok(Event::Incoming(Packet::ConnAck(_)))) => {
                        self.edge.connected();
                        let _ = c.client.try_subscribe(ncmd.clone(), QoS::AtLeastOnce);
                        if let Some(t) = &state {
                            let _ = c.client.try_subscribe(t.clone(), QoS::AtLeastOnce);
                            c.phase = Phase::WaitingHost;
                        } else {
                            self.birth_when_data(c);
                        }
                    }
                    Some(Ok(Event::Incoming(Packet::Publish(p)))) => {
                        if p.topic == ncmd && sparkplug::is_rebirth_request(&p.payload) {
                            tracing::debug!("telemetry: rebirth requested by NCMD");
                            let now = self.clock_ms();
                            if c.phase == Phase::Born && self.rebirths.request(now) {
                                self.birth(c);
                            }
                        } else if state.as_deref() == Some(p.topic.as_str()) {
                            match sparkplug::host_online(&p.payload) {
                                Some(true) if c.phase == Phase::WaitingHost => self.birth_when_data(c),
                                Some(false) if c.phase == Phase::Born => {
                                    // Spec: NDEATH, disconnect, and start over.
                                    self.say_goodbye(c).await;
                                    return End::HostOffline;
                                }
                                _ => {}
                            }
                        }
                    }
                    Some(Ok(Event::Outgoing(Outgoing::Publish(pkid)))) => {
                        if let Some(Some(id)) = c.calls.pop_front() {
                            c.inflight.insert(pkid, id);
                        }
                    }
                    Some(Ok(Event::Incoming(Packet::PubAck(a)))) => {
                        if let Some(id) = c.inflight.remove(&a.pkid) {
                            self.queue.remove(id);
                            self.acked_total += 1;
                        }
                    }
                    Some(Ok(_)) => {}
                },
            }
            if c.phase == Phase::Born {
                self.send_queued(c);
            }
            let nothing_left = self.queue.is_empty() && c.inflight.is_empty();
            if !self.records_open && (nothing_left || c.phase == Phase::WaitingData) {
                // Finished: every record acknowledged (or never any data to announce).
                if c.phase == Phase::Born {
                    self.say_goodbye(c).await;
                }
                return End::Stop;
            }
            let last_error = (c.phase != Phase::Born).then(|| "connecting".to_string());
            self.publish_status(c.phase == Phase::Born, last_error);
        }
    }

    /// NBIRTH now if there is a snapshot to announce, else at the first one.
    fn birth_when_data(&mut self, c: &mut Conn) {
        if self.current.is_empty() {
            c.phase = Phase::WaitingData;
        } else {
            self.birth(c);
        }
    }

    /// NBIRTH with every metric's latest value; seq restarts at 0; the queue is sent (again)
    /// from its start after it, what was queued before flagged historical.
    fn birth(&mut self, c: &mut Conn) {
        let table = birth_table(&self.declared, &self.current);
        let payload = self.edge.birth_declared(&table, &self.current, now_ms());
        let topic = sparkplug::topic(&self.cfg.group_id, Kind::NBirth, &self.cfg.edge_node_id);
        // QoS 0, not retained (`payloads-nbirth-qos/-retain`).
        if c.client
            .try_publish(topic, QoS::AtMostOnce, false, payload)
            .is_ok()
        {
            c.calls.push_back(None);
        }
        if c.phase != Phase::Born {
            tracing::info!(
                bd_seq = self.edge.bd_seq(),
                queued = self.queue.len(),
                broker = self.cfg.broker,
                "telemetry: NBIRTH sent; MQTT link up"
            );
            // The first birth of this connection: everything still queued (never acknowledged)
            // is sent after it, what was queued before it as historical.
            c.next_send = 0;
            c.live_from = self.queue.next_id();
        }
        // A rebirth keeps its place in the queue: in-flight records are acknowledged as usual,
        // the rest follow the new NBIRTH with the new seq.
        self.births_total += 1;
        let now = self.clock_ms();
        self.rebirths.born(now);
        c.phase = Phase::Born;
    }

    fn clock_ms(&self) -> u64 {
        u64::try_from(self.clock.elapsed().as_millis()).unwrap_or(u64::MAX)
    }

    fn send_queued(&mut self, c: &mut Conn) {
        let qos = if self.cfg.ndata_qos == 0 {
            QoS::AtMostOnce
        } else {
            QoS::AtLeastOnce
        };
        let topic = sparkplug::topic(&self.cfg.group_id, Kind::NData, &self.cfg.edge_node_id);
        while c.inflight.len() + c.calls.len() < WINDOW {
            let Some(e) = self.queue.first_from(c.next_send) else {
                break;
            };
            let id = e.id;
            let Some(rec) = queue::decode(&e.bytes) else {
                // Unreadable (a file damaged on disk): counted as dropped by removing it.
                self.queue.remove(id);
                continue;
            };
            let payload = self.edge.data(&rec.values, rec.t_ms, id < c.live_from);
            if c.client
                .try_publish(topic.clone(), qos, false, payload)
                .is_err()
            {
                break;
            }
            c.next_send = id + 1;
            if qos == QoS::AtMostOnce {
                // Nothing will acknowledge it: sent is as far as QoS 0 goes.
                c.calls.push_back(None);
                self.queue.remove(id);
                self.acked_total += 1;
            } else {
                c.calls.push_back(Some(id));
            }
        }
    }

    /// NDEATH before an intentional disconnect (`payloads-ndeath-will-message-publisher`).
    async fn say_goodbye(&mut self, c: &mut Conn) {
        let topic = sparkplug::topic(&self.cfg.group_id, Kind::NDeath, &self.cfg.edge_node_id);
        let _ = c
            .client
            .try_publish(topic, QoS::AtLeastOnce, false, self.edge.death(now_ms()));
        let _ = c.client.try_disconnect();
        // Let the event loop flush both (bounded: a dead broker never answers).
        let _ = tokio::time::timeout(Duration::from_secs(2), async {
            while let Some(Ok(ev)) = c.events.recv().await {
                if matches!(ev, Event::Outgoing(Outgoing::Disconnect)) {
                    break;
                }
            }
        })
        .await;
        self.publish_status(false, Some("stopped".into()));
    }
}

/// Drive a rumqttc event loop until its first error, forwarding events. It is not polled again
/// after an error, so it never reconnects on its own (the session opens a new client).
async fn pump_events(mut el: EventLoop, tx: mpsc::Sender<Result<Event, ConnectionError>>) {
    loop {
        let ev = el.poll().await;
        let failed = ev.is_err();
        if tx.send(ev).await.is_err() || failed {
            return;
        }
    }
}
