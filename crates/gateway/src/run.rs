//! The runtime shell around [`Engine`](crate::engine::Engine): samples arrive on a channel (from the bus sources), the
//! cycle runs once per `cycle_ms` slot (when a source delivers, see `pacer.rs`), the latest status
//! goes to the HTTP endpoint (at most 10 Hz), and a separate sink writes the outputs so a slow or
//! dead controller never stalls the cycle.
//!
//! Threads (why: issue 18.5, compensation dropped under host load when the cycle and the sink were
//! tokio tasks queued behind busy ones): the cycle runs on its own OS thread (`retrocomp-cycle`,
//! [`CycleLoop`]) and the sink on another (`retrocomp-sink`, with its own current-thread tokio
//! runtime, so its Modbus socket's wake-ups do not wait for the main runtime's workers). Both
//! optionally get `SCHED_FIFO` (`gateway.realtime_priority`, see `realtime.rs`). This async
//! function only starts them, then waits for shutdown, a dead source task, a sink that ended, or a
//! cycle thread that died; it then stops the cycle (one more status snapshot) and the sink.
//!
//! Sinks: the configured output is a [`Sink`] (`crates/gateway/src/sinks/mod.rs`; its shell lives with its core:
//! `origin_shift/sink_task.rs`, `origin_shift/server.rs`, `quadrature/sink.rs`); this file only
//! builds it from the field config (clamp and cap per axis) and drives it on the sink thread.
//!
//! Origin-shift start-up: the sink reads what the controller holds before the engine starts, and the
//! engine continues from it (no jump after a gateway restart). The sink reads the controller again
//! before every write (`origin_shift/sink.rs`); when the controller changed the value behind our back
//! (it restarted, an operator cleared it) the engine is reseeded from what it holds.
//!
//! Stop: with `[gateway] on_stop = "ramp_out"` the sink ramps the correction out within the cap
//! (client writes, served registers, quadrature counts; bounded by `stop_ramp_max_s`) before `run`
//! returns.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::sync::{mpsc, oneshot, watch};

use crate::config::{FieldConfig, OnStop};
use crate::cycle::{CycleIo, CycleLoop, CycleReport, Outputs};
use crate::engine::ErrorModel;
use crate::error::GatewayError;
use crate::northbound::http::Control;
use crate::servers::{start_endpoints, start_telemetry};
use crate::sinks::origin_shift::server::OriginShiftServerSink;
use crate::sinks::origin_shift::sink_task::OriginShiftClientSink;
use crate::sinks::quadrature::sink::QuadratureOutput;
use crate::sinks::{LocalFuture, Sink, SinkIo, StartValues};
use crate::sources::SourceFeed;
use crate::status::{SinkStatus, StatusSnapshot};
use crate::supervise::CycleCounter;
use retrocomp_bus::Sample;
use retrocomp_bus::realtime;

/// What a run reports when it stops.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    pub cycles: u64,
    pub writes_ok: u64,
    pub writes_failed: u64,
    /// Engine compute time per cycle, µs (p50, p99) over the last 65 536 cycles.
    pub compute_us_p50: f64,
    pub compute_us_p99: f64,
    /// Cycles that started more than one period late (host pauses), and the worst lateness, ms.
    pub late_cycles: u64,
    pub max_late_ms: f64,
    /// How long compensation was enabled but not applied on some axis (stale inputs, model
    /// fault), s, and in how many episodes (each also a `compensation.<axis>` fault).
    pub not_compensating_s: f64,
    pub not_compensating_episodes: u64,
    /// How long compensation ran without the terms of a lost auxiliary input (the load terms
    /// while the force is stale), s, and in how many episodes (`compensation.<axis>.partial`).
    pub partial_s: f64,
    pub partial_episodes: u64,
}

/// `retrocomp run` as a service: the systemd watchdog fed from the cycle's progress
/// (`supervise::spawn_watchdog`, a no-op without `NOTIFY_SOCKET`) and [`run`] until SIGINT or
/// SIGTERM. `feed` comes from `sources::spawn_sources` on the clock `epoch`.
pub async fn run_until_signal(
    cfg: FieldConfig,
    model: Box<dyn ErrorModel + Send>,
    feed: SourceFeed,
    epoch: std::time::Instant,
) -> Result<RunSummary, GatewayError> {
    let _watchdog = crate::supervise::spawn_watchdog(feed.cycles.clone())
        .map_err(|e| GatewayError::setup("starting the watchdog thread", e))?;
    let shutdown = async {
        use tokio::signal::unix::{SignalKind, signal};
        let mut term = signal(SignalKind::terminate()).ok();
        let terminated = async {
            match term.as_mut() {
                Some(t) => {
                    t.recv().await;
                }
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            () = terminated => {}
        }
        tracing::info!("stopping");
    };
    run(cfg, model, feed, epoch, shutdown, None).await
}

/// Run until `shutdown` resolves. `epoch` is the clock the sources stamp samples with (`t_s` =
/// seconds since it); the engine runs on the same clock so staleness is judged right.
/// `status_addr` receives the bound status address (port 0 allowed).
/// `sources` is the sample channel, or a [`SourceFeed`] from `spawn_sources` (then the sources'
/// links show in the status, and the run stops with an error when a source or the sink ends).
pub async fn run(
    cfg: FieldConfig,
    model: Box<dyn ErrorModel + Send>,
    sources: impl Into<SourceFeed>,
    epoch: std::time::Instant,
    shutdown: impl Future<Output = ()>,
    status_addr: Option<oneshot::Sender<SocketAddr>>,
) -> Result<RunSummary, GatewayError> {
    let SourceFeed {
        samples,
        wake,
        board,
        mut deaths,
        cycles: counter,
    } = sources.into();
    let (status_tx, status_rx) = watch::channel::<Option<Arc<StatusSnapshot>>>(None);
    // Sparkplug B publisher: its own tasks fed from the status watch (never slows the cycle).
    let telemetry = start_telemetry(&cfg, status_rx.clone(), model.identity())?;
    // Actions from the endpoint (token-guarded) reach the cycle loop through this channel.
    let (control_tx, control_rx) = mpsc::channel::<Control>(8);
    // The OPC UA server names the model; read here, the model is not shared across threads.
    let identity = cfg.opcua.as_ref().and_then(|_| model.identity());
    let (opcua, http_task) =
        start_endpoints(&cfg, status_rx, control_tx, identity, status_addr).await?;
    if cfg.gateway.lock_memory {
        realtime::lock_memory();
    }

    // Sink first: origin shift must know what the controller holds before the engine starts.
    let (out_tx, out_rx) = watch::channel::<Outputs>(Vec::new());
    let (reseed_tx, reseed_rx) = mpsc::channel::<(retrocomp_model::Axis, f64)>(8);
    let (sink_status_tx, sink_status_rx) = watch::channel::<SinkStatus>(SinkStatus::default());
    // Positions the controller writes into a served register image (origin-shift server).
    let (served_tx, served_rx) = mpsc::channel::<Sample>(1024);
    // `Some(max_s)` asks the sink to ramp the correction out, then return.
    let (stop_tx, stop_rx) = watch::channel::<Option<f64>>(None);
    // Every sink ramps out through its guard (client writes, served registers, quadrature counts).
    let ramp_out = cfg.gateway.on_stop == OnStop::RampOut;
    let io = SinkIo {
        out_rx,
        reseed_tx,
        status: sink_status_tx,
        stop: stop_rx,
        served: served_tx,
    };
    let mut sink = SinkThread::spawn(&cfg, io, epoch)?;
    let initial = match sink.as_mut() {
        Some(s) => {
            let starting = StartingStatus {
                template: cfg.engine(&BTreeMap::new())?.snapshot(),
                status: &status_tx,
                sink: &sink_status_rx,
                board: &board,
                epoch,
            };
            starting.wait_for(s).await?
        }
        None => BTreeMap::new(),
    };

    let mut engine = cfg.engine(&initial)?;
    engine.report_undelivered(&crate::config::field_check::undelivered_optional(
        &cfg,
        model.as_ref(),
    ));
    // Fed by the cycle; during a stop ramp-out (no cycle) by `ramp_out_before_stop`.
    let watchdog = counter.clone();
    let io = CycleIo {
        samples,
        served: served_rx,
        reseed: reseed_rx,
        control: control_rx,
        outputs: out_tx,
        status: status_tx,
        sink_status: sink_status_rx.clone(),
        board,
        counter,
        wake,
        telemetry: telemetry.as_ref().map(|p| p.annotator()),
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (report_tx, mut report_rx) = oneshot::channel::<CycleReport>();
    let period = Duration::from_millis(cfg.gateway.cycle_ms);
    let stop_cycle = Arc::clone(&stop);
    let cycle_thread = realtime::spawn_thread(
        "retrocomp-cycle",
        cfg.gateway.realtime_priority,
        move || {
            let report = CycleLoop::new(engine, model, io).run(epoch, period, &stop_cycle);
            let _ = report_tx.send(report);
        },
    )
    .map_err(|e| GatewayError::setup("starting the cycle thread", e))?;

    tokio::pin!(shutdown);
    let ended: Result<(), GatewayError> = tokio::select! {
        _ = &mut shutdown => Ok(()),
        why = deaths.next() => Err(GatewayError::Stopped(format!("{why}: stopping the gateway"))),
        why = async { match sink.as_mut() { Some(s) => s.ended().await, None => std::future::pending().await } } => {
            tracing::error!(why, "the sink ended; stopping so the service manager restarts the gateway");
            Err(GatewayError::Stopped(format!("the sink task ended ({why}): stopping the gateway")))
        }
        // The report comes only after `stop`: a cycle thread that ends earlier has panicked.
        _ = &mut report_rx => Err(GatewayError::Stopped("the cycle thread died: stopping the gateway".into())),
    };
    // Stop the cycle (it publishes a last snapshot), then the sink and the endpoint.
    stop.store(true, Ordering::Release);
    let report = report_rx.await.ok();
    let _ = tokio::task::spawn_blocking(move || cycle_thread.join()).await;
    if let Some(mut s) = sink {
        if ramp_out && ended.is_ok() {
            ramp_out_before_stop(&mut s, &stop_tx, cfg.gateway.stop_ramp_max_s, &watchdog).await;
        }
        s.stop().await;
    }
    http_task.abort();
    if let Some(o) = opcua {
        o.stop();
    }
    if let Some(p) = telemetry {
        p.stop(Duration::from_secs(2)).await;
    }
    ended?;
    let report = report.ok_or_else(|| GatewayError::Stopped("the cycle thread died".into()))?;
    let st = sink_status_rx.borrow().clone();
    Ok(RunSummary::of(&report, &st))
}

impl RunSummary {
    fn of(report: &CycleReport, st: &SinkStatus) -> Self {
        let t = &report.time;
        RunSummary {
            cycles: t.cycles,
            writes_ok: st.writes_ok,
            writes_failed: st.writes_failed,
            compute_us_p50: report.compute_us_p50,
            compute_us_p99: report.compute_us_p99,
            late_cycles: report.late_cycles,
            max_late_ms: report.max_late_ms,
            not_compensating_s: t.not_compensating_s,
            not_compensating_episodes: t.not_compensating_episodes,
            partial_s: t.partial_s,
            partial_episodes: t.partial_episodes,
        }
    }
}

/// Ramp the correction out before stopping (`on_stop = "ramp_out"`): the sink writes 0
/// within the per-write cap until the controller holds 0 and then returns by itself, within `max_s`
/// (+ one period's requests). The stop is progress: the service manager's watchdog is kept fed
/// meanwhile (its WatchdogSec may be shorter than the ramp).
async fn ramp_out_before_stop(
    sink: &mut SinkThread,
    stop_tx: &watch::Sender<Option<f64>>,
    max_s: f64,
    watchdog: &CycleCounter,
) {
    let _ = stop_tx.send(Some(max_s));
    let until = tokio::time::sleep(Duration::from_secs_f64(max_s + 2.0));
    tokio::pin!(until);
    let mut alive = tokio::time::interval(Duration::from_millis(100));
    let mut n = watchdog.get();
    loop {
        tokio::select! {
            _ = sink.ended() => break,
            _ = &mut until => break,
            _ = alive.tick() => { n += 1; watchdog.set(n); }
        }
    }
}

/// What `/status`, `/metrics` and `/api/faults` show before the first cycle, while the sink waits
/// for the controller's start values (an unreachable controller is a `disconnected` fault of the
/// sink from its first failed read, and the sources' links show as in a cycle's snapshot).
struct StartingStatus<'a> {
    /// An engine's snapshot before any cycle: the axes and channels, nothing applied.
    template: StatusSnapshot,
    status: &'a watch::Sender<Option<Arc<StatusSnapshot>>>,
    sink: &'a watch::Receiver<SinkStatus>,
    board: &'a crate::sources::health::SourceBoard,
    epoch: std::time::Instant,
}

impl StartingStatus<'_> {
    /// How often the start-up snapshot is published (the cycle's status period is 0.1 s).
    const PERIOD: Duration = Duration::from_millis(200);

    /// The sink's start values; a start-up snapshot every [`Self::PERIOD`] until they come (the
    /// first after one period).
    async fn wait_for(self, sink: &mut SinkThread) -> Result<BTreeMap<String, f64>, GatewayError> {
        let initial = sink.initial();
        tokio::pin!(initial);
        // The first one after one period: a controller that answers at once publishes none (the
        // first cycle's snapshot is then the first, as before).
        let first = tokio::time::Instant::now() + Self::PERIOD;
        let mut tick = tokio::time::interval_at(first, Self::PERIOD);
        loop {
            tokio::select! {
                r = &mut initial => return r,
                _ = tick.tick() => {
                    let mut snap = self.template.clone();
                    snap.t_s = self.epoch.elapsed().as_secs_f64();
                    crate::cycle::add_links(&mut snap, &self.sink.borrow(), self.board);
                    let _ = self.status.send(Some(Arc::new(snap)));
                }
            }
        }
    }
}

/// The sink on its own thread and runtime: it reports the controller's start values once, then
/// runs until it ends by itself (a failure: reported by [`SinkThread::ended`]) or is stopped.
struct SinkThread {
    initial: Option<oneshot::Receiver<Result<BTreeMap<String, f64>, GatewayError>>>,
    ended: oneshot::Receiver<String>,
    stop: Option<oneshot::Sender<()>>,
    join: std::thread::JoinHandle<()>,
}

impl SinkThread {
    /// Start the configured sink (None: no sink configured, a dry run).
    fn spawn(
        cfg: &FieldConfig,
        io: SinkIo,
        epoch: std::time::Instant,
    ) -> Result<Option<Self>, GatewayError> {
        let s = &cfg.sink;
        if s.origin_shift_server.is_none() && s.origin_shift.is_none() && s.quadrature.is_none() {
            return Ok(None);
        }
        let (initial_tx, initial_rx) = oneshot::channel();
        let (ended_tx, ended_rx) = oneshot::channel::<String>();
        let (stop_tx, stop_rx) = oneshot::channel::<()>();
        let cfg = cfg.clone();
        let join = realtime::spawn_runtime_thread(
            "retrocomp-sink",
            cfg.gateway.realtime_priority,
            move || async move {
                let (initial, task) = match start_sink(&cfg, io, epoch).await {
                    Ok(started) => started,
                    Err(e) => {
                        let _ = initial_tx.send(Err(e));
                        return;
                    }
                };
                let _ = initial_tx.send(Ok(initial));
                tokio::select! {
                    () = task => { let _ = ended_tx.send("returned".into()); }
                    _ = stop_rx => {}
                }
            },
        )
        .map_err(|e| GatewayError::setup("starting the sink thread", e))?;
        Ok(Some(Self {
            initial: Some(initial_rx),
            ended: ended_rx,
            stop: Some(stop_tx),
            join,
        }))
    }

    /// The values the controller holds at start (waits for the first successful read).
    async fn initial(&mut self) -> Result<BTreeMap<String, f64>, GatewayError> {
        let rx = self
            .initial
            .take()
            .ok_or_else(|| GatewayError::Refused("the sink's start values were taken".into()))?;
        rx.await
            .map_err(|e| GatewayError::setup("the sink thread ended before it started", e))?
    }

    /// Why the sink ended; pending while it runs.
    async fn ended(&mut self) -> String {
        match (&mut self.ended).await {
            Ok(why) => why,
            // The sender is dropped only when the thread ends without a reason: a panic.
            Err(_) => "the sink thread died".into(),
        }
    }

    async fn stop(mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        let join = self.join;
        let _ = tokio::task::spawn_blocking(move || join.join()).await;
    }
}

/// Build the configured sink on the sink thread: the controller's start values and the task.
async fn start_sink(
    cfg: &FieldConfig,
    io: SinkIo,
    epoch: std::time::Instant,
) -> Result<(StartValues, LocalFuture<'static, ()>), GatewayError> {
    let mut sink = build_sink(cfg, epoch)?;
    let initial = sink.start(&io).await?;
    Ok((initial, sink.run(io)))
}

/// The configured sink, its clamp and per-write cap per axis from the field config's safety (the
/// limits of the one last-step guard every sink passes its outputs through, `crates/gateway/src/sinks/guard.rs`).
fn build_sink(cfg: &FieldConfig, epoch: std::time::Instant) -> Result<Box<dyn Sink>, GatewayError> {
    let limits = cfg.sink_limits();
    if let Some(srv) = cfg.sink.origin_shift_server.clone() {
        return Ok(Box::new(OriginShiftServerSink::new(
            srv,
            limits,
            cfg.channel_table(),
            epoch,
        )));
    }
    if let Some(q) = cfg.sink.quadrature.clone() {
        return Ok(Box::new(QuadratureOutput::new(q, limits, epoch)));
    }
    let os = cfg
        .sink
        .origin_shift
        .clone()
        .ok_or_else(|| GatewayError::Refused("no sink configured".into()))?;
    let sink = OriginShiftClientSink::new(os, limits, epoch)?;
    Ok(Box::new(sink))
}

/// Refuse to run a config that would correct nothing in a field deployment.
pub fn require_sink(cfg: &FieldConfig) -> Result<(), GatewayError> {
    if cfg.sink.origin_shift.is_none()
        && cfg.sink.quadrature.is_none()
        && cfg.sink.origin_shift_server.is_none()
    {
        return Err(GatewayError::Refused(
            "no [sink.origin_shift], [sink.origin_shift_server] or [sink.quadrature] in the config: nothing would be corrected".into(),
        ));
    }
    Ok(())
}
