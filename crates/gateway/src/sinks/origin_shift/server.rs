//! The box as a Modbus server for origin-shift corrections: the tokio-modbus shell (TCP or RTU) around
//! [`ServerCore`]. Config `[sink.origin_shift_server]`; register image and safety in
//! [`super::server_core`]. The register image is a [`RegisterBank`] (crates/bus/src/modbus/server.rs): reads
//! of registers not yet served get exception 02, the controller may write only the position and held
//! registers, and a multi-register write is applied all-or-nothing.
//!
//! Flow: [`OriginShiftServer::start`] binds; [`OriginShiftServer::wait_seeded`] waits (logging) until
//! the controller has written what it holds (only when held registers are configured), which is the
//! engine's start value; [`OriginShiftServer::run`] then updates the image every `update_period_ms`
//! from the engine's outputs and turns each controller write into position samples (`x_mm`).
//! [`OriginShiftServerSink`] is that flow as the run loop's [`Sink`].
//!
//! Faults (one log line at start and clear, in status and metrics, as the client sink's):
//! `sink.origin_shift_server` `Disconnected` (the controller has not written for
//! `controller_timeout_ms`); `sink.origin_shift_server.<axis>` `BeyondClamp` (a held value beyond
//! the clamp was reported: the axis is withdrawn) or `WriteFailed` (a report too far from what was
//! served). Stop (`[gateway] on_stop = "ramp_out"`): a ramp to 0 within the cap is served until
//! the controller reports holding 0, for at most `stop_ramp_max_s`; the outcome is logged.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::net::SocketAddr;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio::time::MissedTickBehavior;

use super::map::Words;
use super::server_core::{ServerCore, ServerMap, Update};
use super::sink_task::{SinkSources, update_sink_faults};
use crate::sinks::guard::AxisLimits;
use crate::sinks::{LocalFuture, Sink, SinkError, SinkIo, SinkStatus, StartValues};
use retrocomp_bus::fault::FaultLog;
use retrocomp_bus::modbus::server::{RegisterBank, TcpServer, spawn_rtu};
use retrocomp_bus::{ChannelId, Health, Sample};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ServerTransport {
    /// Modbus TCP server on `listen` (`127.0.0.1:1502`; port 0 = any free port, logged).
    Tcp { listen: String },
    /// Modbus RTU slave on a serial device (8N1).
    Rtu { path: String, baud: u32 },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServerConfig {
    pub transport: ServerTransport,
    /// RTU slave id (TCP answers every unit id).
    #[serde(default = "one")]
    pub unit_id: u8,
    /// Period of register updates (and heartbeat increments), ms.
    #[serde(default = "default_update_period_ms")]
    pub update_period_ms: u64,
    /// The controller counts as gone (a fault) when it has not written for this long, ms. Only used
    /// when position or held registers are configured.
    #[serde(default = "default_controller_timeout_ms")]
    pub controller_timeout_ms: u64,
    /// TCP: the listener policy (`retrocomp_bus::listen`). Its `allow_writes_from` names the controller:
    /// position, held and marker writes from any other peer get exception 01 and a fault naming
    /// the peer (default: loopback only).
    #[serde(default)]
    pub listen_policy: retrocomp_bus::listen::ListenPolicy,
    pub map: ServerMap,
}

fn one() -> u8 {
    1
}
fn default_update_period_ms() -> u64 {
    20
}
fn default_controller_timeout_ms() -> u64 {
    1_000
}

type Outputs = Vec<(retrocomp_model::Axis, f64)>;

/// The running server (listener or RTU task) and its core.
#[derive(Debug)]
pub struct OriginShiftServer {
    cfg: ServerConfig,
    core: ServerCore,
    bank: RegisterBank,
    writes: watch::Receiver<u64>,
    tcp: Option<TcpServer>,
    rtu: Option<JoinHandle<std::io::Result<()>>>,
    /// The last controller write's positions (channel, mm), reused: no allocation per write.
    positions: Vec<(ChannelId, f64)>,
}

/// Why the origin-shift server could not start (the messages as the serving code reports them).
#[derive(Debug, thiserror::Error)]
pub enum ServerStartError {
    #[error(transparent)]
    Listen(#[from] std::net::AddrParseError),
    /// The TCP listener could not be bound or the serial device opened.
    #[error(transparent)]
    Open(std::io::Error),
}

impl OriginShiftServer {
    /// Bind the TCP listener or open the serial device. `limits`: clamp and per-update cap per axis.
    pub async fn start(cfg: ServerConfig, limits: &[AxisLimits]) -> Result<Self, ServerStartError> {
        let bank = RegisterBank::new();
        for (address, count) in cfg.map.writable() {
            bank.allow_writes(address, count);
        }
        let writes = bank.subscribe_writes();
        let (mut tcp, mut rtu) = (None, None);
        match &cfg.transport {
            ServerTransport::Tcp { listen } => {
                let addr: SocketAddr = listen.parse()?;
                let s = TcpServer::start_with(addr, bank.clone(), cfg.listen_policy.clone())
                    .await
                    .map_err(ServerStartError::Open)?;
                tracing::info!(
                    addr = %s.local_addr(),
                    allow_writes_from = ?cfg.listen_policy.allow_writes_from,
                    "origin-shift server listening (Modbus TCP)"
                );
                tcp = Some(s);
            }
            ServerTransport::Rtu { path, baud } => {
                let port = tokio_serial::SerialStream::open(&tokio_serial::new(path, *baud))
                    .map_err(|e| ServerStartError::Open(e.into()))?;
                tracing::info!(
                    path,
                    baud,
                    slave = cfg.unit_id,
                    "origin-shift server on Modbus RTU"
                );
                rtu = Some(spawn_rtu(port, bank.clone(), cfg.unit_id));
            }
        }
        Ok(Self {
            core: ServerCore::new(cfg.map.clone(), limits),
            cfg,
            bank,
            writes,
            tcp,
            rtu,
            positions: Vec::new(),
        })
    }

    /// The bound TCP address (None on RTU).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.tcp.as_ref().map(TcpServer::local_addr)
    }

    /// Handle one controller write: positions out as samples, held values into the core.
    async fn handle_write(&mut self, samples: &mpsc::Sender<Sample>, t_s: f64) {
        let bank = &self.bank;
        let read = |a: u16, n: u16| {
            let mut w = Words::from_elem(0, usize::from(n));
            bank.holding_into(a, &mut w).then_some(w)
        };
        self.core
            .handle_controller_write_into(read, &mut self.positions);
        for &(channel, value) in &self.positions {
            let s = Sample {
                channel,
                t_s,
                value,
                health: Health::Ok,
            };
            let _ = samples.send(s).await;
        }
    }

    /// Wait until the controller has reported what it holds (returns it per axis, µm: the engine's
    /// start value). Immediately (empty) without held registers.
    pub async fn wait_seeded(
        &mut self,
        samples: &mpsc::Sender<Sample>,
        clock: &impl Fn() -> f64,
    ) -> BTreeMap<String, f64> {
        let mut waited = 0u64;
        while !self.core.is_seeded() {
            match tokio::time::timeout(Duration::from_secs(5), self.writes.changed()).await {
                Ok(Ok(())) => self.handle_write(samples, clock()).await,
                Ok(Err(_)) => break,
                Err(_) => {
                    waited += 5;
                    tracing::warn!(
                        waited_s = waited,
                        "origin-shift server: waiting for the controller to write the held registers; serving nothing until then"
                    );
                }
            }
        }
        let reported: BTreeMap<&str, f64> = self.core.held_um().collect();
        let held: BTreeMap<String, f64> = self.core.start_values().into_iter().collect();
        if held.len() < reported.len() {
            tracing::error!(
                ?reported,
                "the controller reports a correction beyond the clamp: that axis is not served until its value is back in range"
            );
        }
        tracing::info!(
            ?held,
            "controller holds these corrections; continuing from them"
        );
        held
    }

    /// Serve until aborted, or until a stop ramp-out (`stop` set to `Some(max_s)`) has ended:
    /// update the image every period, forward controller writes as samples.
    pub async fn run(
        mut self,
        out_rx: watch::Receiver<Outputs>,
        samples: mpsc::Sender<Sample>,
        status: watch::Sender<SinkStatus>,
        stop: watch::Receiver<Option<f64>>,
        clock: impl Fn() -> f64,
    ) {
        let mut tick = tokio::time::interval(Duration::from_millis(self.cfg.update_period_ms));
        tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
        let listens_to_controller = !self.cfg.map.writable().is_empty();
        let timeout_s = self.cfg.controller_timeout_ms as f64 / 1e3;
        let mut last_write_s = clock();
        let mut faults = FaultLog::default();
        let sources = SinkSources::named(SOURCE, self.core.axis_names());
        let mut stop_by: Option<f64> = None;
        status.send_replace(SinkStatus {
            kind: "origin_shift_server".into(),
            connected: true,
            ..Default::default()
        });
        // Reused every update: a server allocates nothing per tick, steady or faulted (the status,
        // its "has not written" text included, is edited in place).
        let mut update = Update::default();
        loop {
            tokio::select! {
                _ = tick.tick() => {}
                r = self.writes.changed() => {
                    if r.is_err() { return; }
                    last_write_s = clock();
                    self.handle_write(&samples, last_write_s).await;
                    continue;
                }
            }
            if let (None, Some(max_s)) = (stop_by, *stop.borrow()) {
                stop_by = Some(clock() + max_s);
                self.core.begin_ramp_out();
                tracing::info!(
                    max_s,
                    "stopping: serving a ramp to 0 within the per-update cap until the controller reports holding 0"
                );
            }
            // The borrow (a read lock on the engine's outputs) ends before the next await.
            let updated = self.core.poll_update_into(&out_rx.borrow(), &mut update);
            if updated {
                for &(address, count) in &update.withdrawn {
                    self.bank.clear_holding(address, count);
                }
                for b in &update.blocks {
                    self.bank.set_holding(b.address, &b.words);
                }
            }
            let now = clock();
            if let Some(by) = stop_by
                && self.stopped(by, now)
            {
                return;
            }
            let gone = listens_to_controller && now - last_write_s > timeout_s;
            let events = update_sink_faults(&mut faults, &sources, self.core.faults(), !gone, now);
            for e in events.iter().filter(|e| e.started) {
                let held: BTreeMap<&str, f64> = self.core.held_um().collect();
                tracing::warn!(
                    source = e.source.as_str(),
                    kind = e.kind.as_str(),
                    ?held,
                    "origin-shift server fault"
                );
            }
            let writes_ok = self.core.updates();
            let core = &self.core;
            // Empty (no allocation) unless the listener has a fault: a refused peer, a flood.
            let listener_faults = self
                .tcp
                .as_ref()
                .map(|t| t.health().faults())
                .unwrap_or_default();
            status.send_modify(|st| {
                st.writes_ok = writes_ok;
                st.connected = !gone;
                if gone {
                    // Rewritten in place: the text allocates once per fault, not per tick.
                    let text = st.last_error.get_or_insert_with(String::new);
                    text.clear();
                    let _ = write!(
                        text,
                        "the controller has not written for {:.1} s",
                        now - last_write_s
                    );
                } else {
                    st.last_error = None;
                }
                for (a, v) in core.held_um() {
                    match st.held_um.get_mut(a) {
                        Some(held) => *held = v,
                        None => {
                            st.held_um.insert(a.to_string(), v);
                        }
                    }
                }
                // The sink's faults are rebuilt on an edge; the listener's own entries (a refused
                // peer, a flood) are replaced every tick.
                if events.is_empty() {
                    st.faults.retain(|f| !f.0.starts_with("listener."));
                } else {
                    st.faults = faults.active_by_name();
                }
                st.faults.extend(listener_faults.iter().cloned());
            });
        }
    }

    /// During a stop ramp-out: true (logged) once the controller reports holding 0 on every axis,
    /// or at `by_s`.
    fn stopped(&self, by_s: f64, now_s: f64) -> bool {
        let held: BTreeMap<&str, f64> = self.core.held_um().collect();
        if self.core.is_ramped_out() {
            tracing::info!(?held, "ramped out: the controller reports holding 0");
            return true;
        }
        if now_s >= by_s {
            tracing::warn!(
                ?held,
                "stopping before the correction is ramped out: the controller's watchdog rule must remove it"
            );
            return true;
        }
        false
    }
}

/// The server's fault source (`<SOURCE>.<axis>` per axis).
pub const SOURCE: &str = "sink.origin_shift_server";

impl Drop for OriginShiftServer {
    fn drop(&mut self) {
        if let Some(t) = self.rtu.take() {
            t.abort();
        }
    }
}

/// The origin-shift server as the run loop's [`Sink`]: [`Sink::start`] binds and waits until the
/// controller reports what it holds (the engine's start value), [`Sink::run`] serves.
#[derive(Debug)]
pub struct OriginShiftServerSink {
    cfg: ServerConfig,
    /// Clamp and per-update cap per axis.
    limits: Vec<AxisLimits>,
    /// The gateway's clock (sample and fault times are seconds since it).
    epoch: std::time::Instant,
    server: Option<OriginShiftServer>,
}

impl OriginShiftServerSink {
    pub fn new(cfg: ServerConfig, limits: Vec<AxisLimits>, epoch: std::time::Instant) -> Self {
        Self {
            cfg,
            limits,
            epoch,
            server: None,
        }
    }
}

impl Sink for OriginShiftServerSink {
    fn start<'a>(&'a mut self, io: &'a SinkIo) -> LocalFuture<'a, Result<StartValues, SinkError>> {
        Box::pin(async move {
            let mut server = OriginShiftServer::start(self.cfg.clone(), &self.limits)
                .await
                .map_err(|e| SinkError::setup("sink.origin_shift_server", e))?;
            let epoch = self.epoch;
            let clock = move || epoch.elapsed().as_secs_f64();
            let held = server.wait_seeded(&io.served, &clock).await;
            self.server = Some(server);
            Ok(held)
        })
    }

    fn run(self: Box<Self>, io: SinkIo) -> LocalFuture<'static, ()> {
        let epoch = self.epoch;
        let clock = move || epoch.elapsed().as_secs_f64();
        match self.server {
            Some(server) => Box::pin(server.run(io.out_rx, io.served, io.status, io.stop, clock)),
            None => {
                tracing::error!("origin-shift server run before it was started");
                Box::pin(async {})
            }
        }
    }
}
