//! The box as a Modbus server for origin-shift corrections: the tokio-modbus shell (TCP or RTU)
//! around [`ServedBox`]. Config `[sink.origin_shift_server]`; register image and safety in
//! [`super::server_core`]. The register image is a
//! [`RegisterBank`](retrocomp_bus::modbus::RegisterBank): reads of registers not yet
//! served get exception 02, the controller may write only the position and held registers, and a
//! multi-register write is applied all-or-nothing.
//!
//! Flow: [`OriginShiftServer::start`] binds; [`OriginShiftServer::wait_seeded`] waits (logging) until
//! the controller has written what it holds (only when held registers are configured), which is the
//! engine's start value; [`OriginShiftServer::run`] then updates the image every `update_period_ms`
//! from the engine's outputs and turns each controller write into position samples (`x_mm`).
//! What each write and period decides is the sans-IO [`ServedBox`] (its sink and register bank); this shell moves registers
//! between it and the bank, sends the samples and publishes the status.
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

use super::served::{ServedBox, StopEnd};
use super::server_map::ServerMap;
use crate::sinks::guard::AxisLimits;
use crate::sinks::{LocalFuture, Sink, SinkError, SinkIo, SinkStatus, StartValues};
use retrocomp_bus::modbus::{TcpServer, spawn_rtu};
use retrocomp_bus::{ChannelTable, Health, Sample};

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

/// The running server (listener or RTU task) and its sans-IO register image and sink.
#[derive(Debug)]
pub struct OriginShiftServer {
    cfg: ServerConfig,
    served: ServedBox,
    writes: watch::Receiver<u64>,
    tcp: Option<TcpServer>,
    rtu: Option<JoinHandle<std::io::Result<()>>>,
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
    /// Bind the TCP listener or open the serial device. `limits`: clamp and per-update cap per axis;
    /// `channels`: the gateway's table (the position channels' ids); `now_s`: the gateway clock
    /// (the controller's silence counts from here).
    pub async fn start(
        cfg: ServerConfig,
        limits: &[AxisLimits],
        channels: &mut ChannelTable,
        now_s: f64,
    ) -> Result<Self, ServerStartError> {
        let served = ServedBox::new(&cfg, limits, channels, now_s);
        let bank = served.bank().clone();
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
            cfg,
            served,
            writes,
            tcp,
            rtu,
        })
    }

    /// The bound TCP address (None on RTU).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.tcp.as_ref().map(TcpServer::local_addr)
    }

    /// Handle one controller write: positions out as samples, held values into the core.
    async fn handle_write(&mut self, samples: &mpsc::Sender<Sample>, t_s: f64) {
        for &(channel, value) in self.served.handle_bank_write(t_s) {
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
        while !self.served.sink().core().is_seeded() {
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
        let core = self.served.sink().core();
        let reported: BTreeMap<&str, f64> = core.held_um().collect();
        let held: BTreeMap<String, f64> = core.start_values().into_iter().collect();
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
        status.send_replace(SinkStatus {
            kind: "origin_shift_server".into(),
            connected: true,
            ..Default::default()
        });
        loop {
            tokio::select! {
                _ = tick.tick() => {}
                r = self.writes.changed() => {
                    if r.is_err() { return; }
                    self.handle_write(&samples, clock()).await;
                    continue;
                }
            }
            if let (false, Some(max_s)) = (self.served.sink().is_stopping(), *stop.borrow()) {
                self.served.sink_mut().handle_stop(max_s, clock());
                tracing::info!(
                    max_s,
                    "stopping: serving a ramp to 0 within the per-update cap until the controller reports holding 0"
                );
            }
            let now = clock();
            // The borrow (a read lock on the engine's outputs) ends before the next await.
            let period = self.served.poll_period(&out_rx.borrow(), now);
            let core = self.served.sink().core();
            if let Some(end) = period.stopped {
                let held: BTreeMap<&str, f64> = core.held_um().collect();
                match end {
                    StopEnd::RampedOut => {
                        tracing::info!(?held, "ramped out: the controller reports holding 0");
                    }
                    StopEnd::Deadline => tracing::warn!(
                        ?held,
                        "stopping before the correction is ramped out: the controller's watchdog rule must remove it"
                    ),
                }
                return;
            }
            for e in period.events.iter().filter(|e| e.started) {
                let held: BTreeMap<&str, f64> = core.held_um().collect();
                tracing::warn!(
                    source = e.source.as_str(),
                    kind = e.kind.as_str(),
                    ?held,
                    "origin-shift server fault"
                );
            }
            // Empty (no allocation) unless the listener has a fault: a refused peer, a flood.
            let listener_faults = self
                .tcp
                .as_ref()
                .map(|t| t.health().faults())
                .unwrap_or_default();
            let active = (!period.events.is_empty()).then(|| self.served.sink().active_faults());
            publish_status(&status, core, period.silent_s, active, &listener_faults);
        }
    }
}

/// One period's status, edited in place: a server allocates nothing per period, steady or faulted
/// (the "has not written" text is rewritten in its buffer). `active`: the sink's faults when they
/// changed this period; the listener's own entries (a refused peer, a flood) are replaced every
/// period.
fn publish_status(
    status: &watch::Sender<SinkStatus>,
    core: &super::server_core::ServerCore,
    silent_s: Option<f64>,
    active: Option<Vec<(String, retrocomp_bus::fault::FaultKind, f64)>>,
    listener_faults: &[(String, retrocomp_bus::fault::FaultKind, f64)],
) {
    status.send_modify(|st| {
        st.writes_ok = core.updates();
        st.connected = silent_s.is_none();
        if let Some(silent) = silent_s {
            let text = st.last_error.get_or_insert_with(String::new);
            text.clear();
            let _ = write!(text, "the controller has not written for {silent:.1} s");
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
        match active {
            Some(faults) => st.faults = faults,
            None => st.faults.retain(|f| !f.0.starts_with("listener.")),
        }
        st.faults.extend(listener_faults.iter().cloned());
    });
}

/// The server's fault source (`<SOURCE>.<axis>` per axis).
pub(crate) const SOURCE: &str = "sink.origin_shift_server";

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
pub(crate) struct OriginShiftServerSink {
    cfg: ServerConfig,
    /// Clamp and per-update cap per axis.
    limits: Vec<AxisLimits>,
    /// The gateway's channel table (the ids of the positions the controller writes).
    channels: ChannelTable,
    /// The gateway's clock (sample and fault times are seconds since it).
    epoch: std::time::Instant,
    server: Option<OriginShiftServer>,
}

impl OriginShiftServerSink {
    pub(crate) fn new(
        cfg: ServerConfig,
        limits: Vec<AxisLimits>,
        channels: ChannelTable,
        epoch: std::time::Instant,
    ) -> Self {
        Self {
            cfg,
            limits,
            channels,
            epoch,
            server: None,
        }
    }
}

impl Sink for OriginShiftServerSink {
    fn start<'a>(&'a mut self, io: &'a SinkIo) -> LocalFuture<'a, Result<StartValues, SinkError>> {
        Box::pin(async move {
            let epoch = self.epoch;
            let clock = move || epoch.elapsed().as_secs_f64();
            let mut server = OriginShiftServer::start(
                self.cfg.clone(),
                &self.limits,
                &mut self.channels,
                clock(),
            )
            .await
            .map_err(|e| SinkError::setup("sink.origin_shift_server", e))?;
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
