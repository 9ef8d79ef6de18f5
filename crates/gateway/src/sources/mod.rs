//! Starts the configured bus sources and merges their samples into one channel for the runtime:
//! `[can]` + `[canopen]` (CiA 406 encoders, CiA 404 analog inputs) over any crates/bus/src backend,
//! every `[[modbus.source]]` (TCP/RTU poller: timeouts, reconnect with backoff, exceptions as
//! `DecodeError` samples) and every `[[serial.source]]` (line framer + format parser).
//!
//! All samples are timestamped in seconds since `epoch` (the runtime's clock). A source that goes
//! silent sends nothing (or `Stale` samples): the runtime's channel health turns it `Stale` after the
//! channel's `stale_after_s`, so a dead source never stops the others.
//!
//! Every source comes back by itself: a CAN backend that fails (socketcand peer hung up, SocketCAN
//! interface down or removed) is reopened, a serial port reopened, a Modbus context rebuilt, each
//! with the one [`Backoff`]. The link's state is a fault of the source (`can`, `modbus.<name>`,
//! `serial.<name>`; `SourceReporter`): `disconnected` from the failure until data flows again
//! (for CAN: until the first frame after the reopen, since a SocketCAN socket reopens fine on an
//! interface that is still down), plus `bus_off` / `error_passive` / `bus_errors` from CAN error
//! frames and `exception` while a Modbus device answers with exceptions. A source task that ends
//! while the gateway runs is reported on the feed's `deaths` (the runtime then stops).
//!
//! Threads: the CAN and serial readers run on their own OS thread (`retrocomp-sources`, a
//! current-thread tokio runtime that owns their sockets; `gateway.realtime_priority` applies to it
//! and to the Modbus pollers' threads it starts), each Modbus poller on its own thread; none
//! shares a tokio worker with the status endpoint or whatever else the caller's runtime runs (the
//! demo's in-process hubs), so a busy runtime does not leave frames and lines unread (issue 18.5).

pub(crate) mod health;

pub use health::SourceBoard;

use std::time::{Duration, Instant};

use tokio::sync::mpsc;

use crate::config::FieldConfig;
use crate::error::GatewayError;
use crate::pacer::CycleWake;
use crate::sources::health::SourceReporter;
use crate::supervise::{CycleCounter, DeathNotice, TaskDeaths};
use retrocomp_bus::can::{self, AnyCanBus, BusErrors, CanBackendConfig, CanBus, CanError};
use retrocomp_bus::canopen::{self, CanopenSource};
use retrocomp_bus::modbus::ModbusPoller;
use retrocomp_bus::serial::{self, LineSource, SerialSourceConfig};
use retrocomp_bus::{Backoff, Sample};

/// Reopen delays of a CAN backend or a serial port that closed, failed or could not be opened at
/// start (doubling up to the max). The max is 1 s so a peripheral that comes up late (a CAN daemon,
/// a USB serial adapter) is in use within ≈ 1 s of appearing; opening a local socket or device once
/// a second costs nothing.
const REOPEN_MIN: Duration = Duration::from_millis(200);
const REOPEN_MAX: Duration = Duration::from_secs(1);

/// Spawn every configured source; samples (timestamped on `epoch`) arrive on the returned feed.
/// A CAN backend, serial device or Modbus peer that cannot be opened yet is not an error: its source
/// starts `disconnected` (a fault in `/status` from the first snapshot) and is retried with the
/// backoff, as after a loss. Fails at start only for what no retry can fix (a CAN backend this
/// binary does not have, a serial setting the device refuses).
pub async fn spawn_sources(cfg: &FieldConfig, epoch: Instant) -> Result<SourceFeed, GatewayError> {
    let (tx, rx) = mpsc::channel::<Sample>(16_384);
    let wake = CycleWake::default();
    let board = SourceBoard::default();
    let (notice, deaths) = TaskDeaths::new();
    let (ready_tx, ready_rx) = tokio::sync::oneshot::channel::<Result<(), GatewayError>>();
    let (cfg, b, n, w) = (cfg.clone(), board.clone(), notice.clone(), wake.clone());
    // The readers stamp each sample when they read it: a starved reader makes fresh data look
    // late, so they share the cycle's real-time priority (the Modbus pollers' threads, started
    // from this one, inherit it).
    let prio = cfg.gateway.realtime_priority;
    retrocomp_bus::realtime::spawn_runtime_thread("retrocomp-sources", prio, move || async move {
        match start_sources(&cfg, epoch, (tx.clone(), w), b, n).await {
            Ok(()) => {
                let _ = ready_tx.send(Ok(()));
                // The readers are tasks of this thread's runtime: keep it running until the
                // gateway drops the sample channel.
                tx.closed().await;
            }
            Err(e) => {
                let _ = ready_tx.send(Err(e));
            }
        }
    })
    .map_err(|e| GatewayError::setup("starting the sources thread", e))?;
    ready_rx
        .await
        .map_err(|e| GatewayError::setup("the sources thread ended while starting", e))??;
    Ok(SourceFeed {
        samples: rx,
        wake,
        board,
        deaths,
        cycles: CycleCounter::default(),
    })
}

/// Open and spawn every source on the current (the sources thread's) runtime.
async fn start_sources(
    cfg: &FieldConfig,
    epoch: Instant,
    tx: (mpsc::Sender<Sample>, CycleWake),
    board: SourceBoard,
    notice: DeathNotice,
) -> Result<(), GatewayError> {
    let clock = move || epoch.elapsed().as_secs_f64();
    // The ids the engine gives these names (it builds the same table from the same file).
    let mut channels = cfg.channel_table();
    if let (Some(can), Some(co)) = (cfg.can.clone(), cfg.canopen.clone()) {
        let src = CanopenSource::new(co, &mut channels);
        let opened = can::open(&can, None).await;
        let mut rep = SourceReporter::new("can", opened.is_ok(), board.clone());
        let bus = match opened {
            Ok(bus) => Some(bus),
            Err(e @ CanError::Unsupported(_)) => {
                return Err(GatewayError::setup(format!("opening CAN backend {can}"), e));
            }
            Err(e) => {
                not_yet_open(&mut rep, &format!("opening CAN backend {can}: {e}"));
                None
            }
        };
        let btx = forward(tx.clone());
        let n = notice.clone();
        tokio::spawn(async move {
            can_loop(can, src, bus, clock, btx.clone(), rep).await;
            if !btx.is_closed() {
                n.report("can", "the CAN source loop returned");
            }
        });
    }
    for m in cfg.modbus.iter().flat_map(|m| &m.source) {
        let name = format!("modbus.{}", m.name);
        let btx = forward(tx.clone());
        tracing::info!(source = %m.name, transport = ?m.transport, "starting Modbus poller");
        let rep = SourceReporter::new(&name, false, board.clone());
        spawn_modbus(
            ModbusPoller::new(m.clone(), &mut channels),
            clock,
            btx,
            rep,
            notice.clone(),
        )
        .map_err(|e| {
            GatewayError::setup(
                format!("modbus source {:?}: cannot start its thread", m.name),
                e,
            )
        })?;
    }
    for s in cfg.serial.iter().flat_map(|s| &s.source) {
        let name = format!("serial.{}", s.name);
        let what = format!(
            "serial source {:?}: cannot open device {:?} at {} baud",
            s.name,
            s.device.as_deref().unwrap_or(""),
            s.baud
        );
        let opened = serial::open(s);
        let mut rep = SourceReporter::new(&name, opened.is_ok(), board.clone());
        let port = match opened {
            Ok(port) => Some(port),
            Err(e) if e.kind == tokio_serial::ErrorKind::InvalidInput => {
                return Err(GatewayError::setup(what, e));
            }
            Err(e) => {
                not_yet_open(&mut rep, &format!("{what}: {e}"));
                None
            }
        };
        let btx = forward(tx.clone());
        let (cfg, n) = (s.clone(), notice.clone());
        let src = LineSource::new(s.clone(), &mut channels);
        tokio::spawn(async move {
            serial_loop(cfg, src, port, clock, btx.clone(), rep).await;
            if !btx.is_closed() {
                n.report(&name, "the serial source loop returned");
            }
        });
    }
    Ok(())
}

/// A source whose link cannot be opened at start: one WARN line now (the fault log adds the
/// `disconnected` fault at the source's first publish), then its loop retries with the backoff.
fn not_yet_open(rep: &mut SourceReporter, why: &str) {
    tracing::warn!(
        source = rep.name(),
        "{why}; retrying (the source is a `disconnected` fault until it opens)"
    );
    rep.handle_link_down(why);
}

/// A batch sender whose batches are unpacked into `tx` by a forwarding task; each batch (one
/// frame's, one poll's, one line's samples) wakes the cycle, which may then run at once.
fn forward((tx, wake): (mpsc::Sender<Sample>, CycleWake)) -> mpsc::Sender<Vec<Sample>> {
    let (btx, mut brx) = mpsc::channel::<Vec<Sample>>(1024);
    tokio::spawn(async move {
        while let Some(batch) = brx.recv().await {
            for s in batch {
                if tx.send(s).await.is_err() {
                    return;
                }
            }
            wake.notify();
        }
    });
    btx
}

/// The CANopen source over a CAN backend that is reopened whenever it fails. Ends only when `out`
/// closes (the gateway stopped).
async fn can_loop(
    can: CanBackendConfig,
    mut src: CanopenSource,
    first: Option<AnyCanBus>,
    clock: impl Fn() -> f64 + Copy,
    out: mpsc::Sender<Vec<Sample>>,
    mut rep: SourceReporter,
) {
    let mut bus = first;
    let mut backoff = Backoff::new(REOPEN_MIN, REOPEN_MAX);
    // Error-frame totals of the backends closed so far (a reopened backend counts from zero).
    let mut base = BusErrors::default();
    rep.publish(clock());
    loop {
        if let Some(mut b) = bus.take() {
            let result =
                canopen::run_observed(&mut b, &mut src, clock, out.clone(), |b, frames| {
                    if frames > 0 && !rep.is_connected() {
                        rep.handle_link_up();
                        tracing::info!(source = rep.name(), "CAN frames flow again");
                    }
                    rep.handle_can_bus(b.bus_errors(), &base, clock());
                    rep.publish(clock());
                    rep.poll_timeout()
                })
                .await;
            let seen = b.bus_errors();
            base.error_frames += seen.error_frames;
            base.bus_off_events += seen.bus_off_events;
            match result {
                Ok(()) => return, // `out` closed: the gateway stopped
                Err(e) => {
                    rep.handle_link_down(&e.to_string());
                    rep.publish(clock());
                    tracing::debug!(%e, "CAN backend failed; reopening");
                }
            }
            // A link that carried frames starts the next reopen at the shortest delay.
            if rep.is_connected() {
                backoff.reset();
            }
        }
        if out.is_closed() {
            return;
        }
        tokio::time::sleep(backoff.next_delay()).await;
        match can::open(&can, None).await {
            Ok(b) => {
                tracing::debug!(backend = %can, "CAN backend reopened; waiting for frames");
                bus = Some(b);
            }
            Err(e) => {
                rep.handle_link_down(&e.to_string());
                rep.publish(clock());
                tracing::debug!(%e, "CAN reopen failed");
            }
        }
    }
}

/// Run one Modbus poller on its own thread and current-thread runtime: its future is not `Send`
/// (tokio-modbus's client context is not `Sync` and the poller holds `&self` across the connect
/// await), so it cannot go on the multi-thread runtime. It ends when `out` closes.
fn spawn_modbus(
    poller: ModbusPoller,
    clock: impl Fn() -> f64 + Send + 'static,
    out: mpsc::Sender<Vec<Sample>>,
    mut rep: SourceReporter,
    notice: DeathNotice,
) -> std::io::Result<()> {
    let name = rep.name().to_string();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rep.publish(clock());
    std::thread::Builder::new()
        .name(name.clone())
        .spawn(move || {
            let closed = out.clone();
            rt.block_on(
                poller.run_observed(&clock, out, |before, after, connected| {
                    rep.handle_modbus_poll(before, after, connected);
                    rep.publish(clock());
                }),
            );
            if !closed.is_closed() {
                notice.report(&name, "the Modbus poller returned");
            }
        })?;
    Ok(())
}

/// Run one serial source; when the port closes or fails (USB adapter unplugged), reopen it with the
/// backoff. Meanwhile its channels get no samples and go `Stale` in the runtime. `src` is the
/// source as built (channels resolved); each opened port reads with a fresh copy of it.
async fn serial_loop(
    cfg: SerialSourceConfig,
    src: LineSource,
    first: Option<tokio_serial::SerialStream>,
    clock: impl Fn() -> f64 + Copy,
    out: mpsc::Sender<Vec<Sample>>,
    mut rep: SourceReporter,
) {
    let mut port = first;
    let mut backoff = Backoff::new(REOPEN_MIN, REOPEN_MAX);
    rep.publish(clock());
    loop {
        if let Some(p) = port.take() {
            rep.handle_link_up();
            rep.publish(clock());
            let why = match serial::run(p, src.clone(), clock, out.clone()).await {
                Ok(c) => format!("serial port closed ({c:?})"),
                Err(e) => format!("serial port failed: {e}"),
            };
            rep.handle_link_down(&why);
            rep.publish(clock());
            backoff.reset();
        }
        if out.is_closed() {
            return;
        }
        tokio::time::sleep(backoff.next_delay()).await;
        match serial::open(&cfg) {
            Ok(p) => port = Some(p),
            Err(e) => {
                tracing::debug!(source = %cfg.name, %e, "serial reopen failed");
                rep.handle_link_down(&format!("cannot open device: {e}"));
                rep.publish(clock());
            }
        }
    }
}

/// What the runtime gets from the sources: the samples, their links' status, and word of any
/// source task that ended, plus the counter the cycle publishes its progress on.
#[derive(Debug)]
pub struct SourceFeed {
    pub samples: mpsc::Receiver<Sample>,
    /// Notified after each batch of samples is in `samples` (the cycle's [`crate::pacer`]).
    pub wake: CycleWake,
    pub board: SourceBoard,
    pub deaths: TaskDeaths,
    pub cycles: CycleCounter,
}

/// A bare sample channel (tests, the demo, benches): no links to show, no tasks to watch.
impl From<mpsc::Receiver<Sample>> for SourceFeed {
    fn from(samples: mpsc::Receiver<Sample>) -> Self {
        SourceFeed {
            samples,
            wake: CycleWake::default(),
            board: SourceBoard::default(),
            deaths: TaskDeaths::new().1,
            cycles: CycleCounter::default(),
        }
    }
}
