//! The gateway as one sans-IO object: sources → engine → sink, with time passed in and nothing
//! spawned. [`GatewayCore`] holds the parts the runtime (`run.rs`) drives on its threads — the
//! CANopen and serial-line source cores, the [`CycleCore`] (engine, model, switch, accounting),
//! and one sink: the origin-shift [`SinkCore`] closed by `end_period`, the quadrature sink's core
//! stepped by its `step_axes`, or the origin-shift
//! server's register bank and [`ServedSink`](crate::sinks::origin_shift::served::ServedSink)
//! ([`ServedBox`], started by [`GatewayCore::start_served`]: the engine starts once the controller
//! has reported what it holds) — and composes them in the runtime's order. The closed-loop
//! harness (`hil-sim`) drives this type and wires nothing itself, so a change of the cycle's
//! order, the reseed path, the guard or the fault mapping is one change under both.
//!
//! Driving vocabulary: `handle_*` for what arrived (a CAN frame, serial bytes, a Modbus source's
//! connect or read, the controller's reply or request to the server, a stop), `poll_*` for what is
//! due at `now_s` (a cycle, a Modbus read, a sink request, quadrature edges, a server update);
//! `modbus_timeout` says when a Modbus source's next poll is due. The CANopen and serial cores are
//! polled in a cycle once their own `poll_timeout` has come, as the runtime's shells sleep until
//! it. A Modbus source runs the poller's own [`PollSchedule`] (period, timeout → stale, reconnect
//! backoff); the driver does its I/O.
//! Reseeds found by a sink period reach the engine at the next cycle, as through the runtime's
//! channel.
//!
//! Units: corrections µm (correction = −error), positions mm, time s (gateway clock) and ns on
//! the quadrature lines.

pub(crate) mod cycle;
pub(crate) mod quadrature;

use std::collections::BTreeMap;

use retrocomp_bus::can::Frame;
use retrocomp_bus::canopen::CanopenSource;
use retrocomp_bus::fault::FaultEvent;
use retrocomp_bus::modbus::{
    PollCounters, PollRequest, PollSchedule, PollStep, ReadOutcome, RegisterTable,
};
use retrocomp_bus::serial::LineSource;
use retrocomp_bus::{ChannelId, ChannelTable, Sample};
use retrocomp_model::Axis;

pub use crate::sinks::origin_shift::served::ServedBox;
pub use cycle::{CompensationTime, Control, CycleCore};
pub use quadrature::{MemoryHeld, QuadratureBox};

use crate::config::FieldConfig;
use crate::engine::ErrorModel;
use crate::engine::health::FaultLog;
use crate::engine::safety::Mode;
use crate::error::GatewayError;
use crate::sinks::origin_shift::sink_task::{SinkSources, end_period, start_values_within};
use crate::sinks::origin_shift::{Action, Reply, SinkCore};
use crate::sources::health::{SourceBoard, SourceReporter};

/// What a Modbus source asks its driver for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModbusRequest {
    /// Open the link (answer with [`GatewayCore::handle_modbus_connect`]).
    Connect,
    /// Read `count` registers of `table` from `start` (answer with
    /// [`GatewayCore::handle_modbus_outcome`]: the words, an exception, or a timeout after the
    /// source's `timeout_s`).
    Read {
        table: RegisterTable,
        start: u16,
        count: u16,
    },
}

/// A `[[modbus.source]]`: the poller's schedule and its link as the runtime reports it
/// (`modbus.<name>`: `Disconnected` while down, `Exception` after an exception reply).
#[derive(Debug)]
struct ModbusSource {
    schedule: PollSchedule,
    reporter: SourceReporter,
    /// The reporter's first state (down until the first connect) is published.
    started: bool,
}

/// The origin-shift sink: its core, fault log and the period's request in flight.
#[derive(Debug)]
struct OriginShift {
    core: SinkCore,
    sources: SinkSources,
    faults: FaultLog,
    /// The request in flight (answered by [`GatewayCore::handle_reply`]), if a period runs.
    pending: Option<Action>,
}

/// Decoders → cycle → sink, sans-IO.
#[derive(Debug)]
pub struct GatewayCore {
    cfg: FieldConfig,
    cycle: CycleCore,
    canopen: Option<CanopenSource>,
    serial: Vec<LineSource>,
    modbus: Vec<ModbusSource>,
    origin_shift: Option<OriginShift>,
    quadrature: Option<QuadratureBox>,
    served: Option<ServedBox>,
    /// The engine runs: always, except for a server whose controller has not yet reported what
    /// it holds (the runtime starts its engine from that report).
    engine_started: bool,
    /// A stop was asked for; a server takes it at its next update period.
    stop_requested: bool,
    samples: Vec<Sample>,
    /// Values a sink period found in the controller, for the next cycle.
    reseeds: Vec<(Axis, f64)>,
    /// Fault edges since the last [`GatewayCore::take_edges`].
    edges: Vec<FaultEvent>,
    /// Channels whose samples are kept ([`GatewayCore::record_samples`]), and those samples.
    recorded: Vec<ChannelId>,
    sample_log: Vec<Sample>,
}

impl GatewayCore {
    /// Start as `retrocomp run` does: the sink says what the controller holds (`held_um` for the
    /// origin-shift registers, read by the driver; `held_counts` for quadrature) and the engine
    /// continues from what is within the clamp. `[sink.origin_shift]` or `[sink.quadrature]`.
    pub fn start(
        cfg: FieldConfig,
        model: Box<dyn ErrorModel + Send>,
        held_um: BTreeMap<String, f64>,
        held_counts: MemoryHeld,
    ) -> Result<Self, GatewayError> {
        let limits = cfg.sink_limits();
        let (initial, origin_shift, quadrature) =
            match (&cfg.sink.origin_shift, &cfg.sink.quadrature) {
                (Some(os), None) => {
                    let core = SinkCore::new(os.map.clone(), limits.clone());
                    let initial = start_values_within(held_um, &os.map, &limits);
                    let os = OriginShift {
                        sources: SinkSources::of(&core),
                        core,
                        faults: FaultLog::default(),
                        pending: None,
                    };
                    (initial, Some(os), None)
                }
                (None, Some(q)) => {
                    let (b, start) = QuadratureBox::new(q, &limits, held_counts)?;
                    (start, None, Some(b))
                }
                _ => {
                    return Err(GatewayError::Refused(
                        "the sans-IO gateway drives [sink.origin_shift] or [sink.quadrature]"
                            .into(),
                    ));
                }
            };
        let engine = cfg.engine(&initial)?;
        Ok(Self::build(
            cfg,
            engine,
            model,
            origin_shift,
            quadrature,
            None,
        ))
    }

    /// Start with `[sink.origin_shift_server]` at `now_s`, as `retrocomp run` does: the server
    /// answers the controller from now on ([`GatewayCore::handle_server_request`]), and the
    /// engine starts, from what the controller reports holding within the clamp, once it has
    /// reported it; until then [`GatewayCore::poll_cycle`] runs no cycle.
    pub fn start_served(
        cfg: FieldConfig,
        model: Box<dyn ErrorModel + Send>,
        now_s: f64,
    ) -> Result<Self, GatewayError> {
        let Some(srv) = cfg.sink.origin_shift_server.clone() else {
            return Err(GatewayError::Refused(
                "start_served needs [sink.origin_shift_server]".into(),
            ));
        };
        let served = ServedBox::new(&srv, &cfg.sink_limits(), &mut cfg.channel_table(), now_s);
        let engine = cfg.engine(&BTreeMap::new())?;
        let mut core = Self::build(cfg, engine, model, None, None, Some(served));
        core.engine_started = false;
        core.start_engine_if_seeded()?;
        Ok(core)
    }

    fn build(
        cfg: FieldConfig,
        engine: crate::engine::Engine,
        model: Box<dyn ErrorModel + Send>,
        origin_shift: Option<OriginShift>,
        quadrature: Option<QuadratureBox>,
        served: Option<ServedBox>,
    ) -> Self {
        // The ids the engine gives these names (it built the same table from the same file).
        let mut channels = cfg.channel_table();
        let canopen = cfg
            .canopen
            .clone()
            .map(|co| CanopenSource::new(co, &mut channels));
        let serial = cfg
            .serial
            .iter()
            .flat_map(|s| s.source.iter().cloned())
            .map(|s| LineSource::new(s, &mut channels))
            .collect();
        let modbus = cfg
            .modbus
            .iter()
            .flat_map(|m| m.source.iter())
            .map(|m| ModbusSource {
                schedule: PollSchedule::new(m, &mut channels),
                // As the runtime starts its reporter: down until the first connect.
                reporter: SourceReporter::new(
                    &format!("modbus.{}", m.name),
                    false,
                    SourceBoard::default(),
                ),
                started: false,
            })
            .collect();
        Self {
            cycle: CycleCore::new(engine, model),
            cfg,
            canopen,
            serial,
            modbus,
            origin_shift,
            quadrature,
            served,
            engine_started: true,
            stop_requested: false,
            samples: Vec::new(),
            reseeds: Vec::new(),
            edges: Vec::new(),
            recorded: Vec::new(),
            sample_log: Vec::new(),
        }
    }

    /// A server whose controller has reported what it holds: the engine starts from it (the
    /// values within the clamp; a value beyond it leaves that axis unserved and at 0).
    fn start_engine_if_seeded(&mut self) -> Result<(), GatewayError> {
        let Some(served) = self.served.as_ref() else {
            return Ok(());
        };
        if self.engine_started || !served.sink().core().is_seeded() {
            return Ok(());
        }
        let held: BTreeMap<String, f64> = served.sink().core().start_values().into_iter().collect();
        self.cycle.replace_engine(self.cfg.engine(&held)?);
        self.engine_started = true;
        Ok(())
    }

    /// The controller's Modbus request to the served image at `now_s` (`[sink.origin_shift_server]`),
    /// answered as the server answers it; an accepted write is the controller's report (held
    /// values, positions as samples for the next cycle). `IllegalFunction` without a server.
    pub fn handle_server_request(
        &mut self,
        req: &tokio_modbus::prelude::Request<'_>,
        now_s: f64,
    ) -> Result<tokio_modbus::prelude::Response, tokio_modbus::prelude::ExceptionCode> {
        use tokio_modbus::prelude::Request;
        let Some(served) = self.served.as_mut() else {
            return Err(tokio_modbus::prelude::ExceptionCode::IllegalFunction);
        };
        let answer = served.bank().handle(req);
        let wrote = matches!(
            req,
            Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..)
        );
        if wrote && answer.is_ok() {
            // As the server's shell: positions go to the cycle as samples.
            for &(channel, value) in served.handle_bank_write(now_s) {
                self.samples.push(Sample {
                    channel,
                    t_s: now_s,
                    value,
                    health: retrocomp_bus::Health::Ok,
                });
            }
        }
        if let Err(e) = self.start_engine_if_seeded() {
            tracing::error!(%e, "cannot start the engine from the controller's report");
        }
        answer
    }

    /// One update period of the server at `now_s` (every `update_period_ms`): the image moves
    /// toward the last cycle's outputs through the guard; a stop asked for is taken here. Its
    /// fault edges join the gateway's. Returns how a stop ramp-out ended, if it did.
    pub fn poll_served(
        &mut self,
        now_s: f64,
    ) -> Option<crate::sinks::origin_shift::served::StopEnd> {
        let max_s = self.cfg.gateway.stop_ramp_max_s;
        let served = self.served.as_mut()?;
        if self.stop_requested && !served.sink().is_stopping() {
            served.sink_mut().handle_stop(max_s, now_s);
        }
        let period = served.poll_period(self.cycle.outputs(), now_s);
        self.edges.extend(period.events);
        period.stopped
    }

    /// The server (`[sink.origin_shift_server]`), if that is the sink.
    pub fn served(&self) -> Option<&ServedBox> {
        self.served.as_ref()
    }

    pub fn config(&self) -> &FieldConfig {
        &self.cfg
    }

    /// A CAN frame arrived at `t_s`.
    pub fn handle_frame(&mut self, f: &Frame, t_s: f64) {
        if let Some(c) = self.canopen.as_mut() {
            c.handle_frame(f, t_s, &mut self.samples);
        }
    }

    /// Bytes arrived on serial source `i` at `t_s`.
    pub fn handle_serial(&mut self, i: usize, bytes: &[u8], t_s: f64) {
        if let Some(s) = self.serial.get_mut(i) {
            s.push(bytes, t_s, &mut self.samples);
        }
    }

    /// Keep every sample of `channel` the engine ingests from now on (in arrival order). A name
    /// the box does not know has no samples to keep.
    pub fn record_samples(&mut self, channel: &str) {
        if let Some(id) = self.channels().get(channel) {
            self.recorded.push(id);
        }
    }

    /// The box's channel table: the names of the ids in its samples.
    pub fn channels(&self) -> &ChannelTable {
        self.cycle.engine().channels()
    }

    /// The samples of the recorded channels, in the order the engine ingested them.
    pub fn recorded_samples(&self) -> &[Sample] {
        &self.sample_log
    }

    /// Garbage lines the serial sources counted so far.
    pub fn serial_garbage_lines(&self) -> u64 {
        self.serial.iter().map(|s| s.counters().garbage_lines).sum()
    }

    /// When Modbus source `i`'s next poll is due (None: it waits for its I/O, or no such source).
    pub fn modbus_timeout(&self, i: usize) -> Option<f64> {
        self.modbus.get(i)?.schedule.poll_timeout()
    }

    /// Modbus source `i`'s poll due at `now_s` starts: its first request, if it needs I/O (a poll
    /// while the link may not be retried yet only stales its channels).
    pub fn poll_modbus(&mut self, i: usize, now_s: f64) -> Option<ModbusRequest> {
        let m = self.modbus.get_mut(i)?;
        if !m.started {
            m.started = true;
            let events = m.reporter.publish(now_s);
            self.edges.extend(events);
        }
        let step = m.schedule.poll(now_s, now_s, &mut self.samples);
        self.modbus_step(i, step, now_s)
    }

    /// Modbus source `i`'s connect succeeded (`ok`) or failed at `now_s`; its next request.
    pub fn handle_modbus_connect(
        &mut self,
        i: usize,
        ok: bool,
        now_s: f64,
    ) -> Option<ModbusRequest> {
        let m = self.modbus.get_mut(i)?;
        let step = m.schedule.handle_connect(ok, now_s, &mut self.samples);
        self.modbus_step(i, step, now_s)
    }

    /// Modbus source `i`'s read came back with `outcome` at `now_s`; its next request. The
    /// samples reach the engine at the next cycle.
    pub fn handle_modbus_outcome(
        &mut self,
        i: usize,
        outcome: &ReadOutcome,
        now_s: f64,
    ) -> Option<ModbusRequest> {
        let m = self.modbus.get_mut(i)?;
        let step = m.schedule.handle_outcome(outcome, now_s, &mut self.samples);
        self.modbus_step(i, step, now_s)
    }

    /// Modbus source `i`'s counters (requests, timeouts, connects…).
    pub fn modbus_counters(&self, i: usize) -> Option<PollCounters> {
        Some(self.modbus.get(i)?.schedule.counters())
    }

    /// The request a step asks for; a finished poll goes to the source's reporter, as the
    /// runtime's poller thread hands it over, and its fault edges join the gateway's.
    fn modbus_step(&mut self, i: usize, step: PollStep, now_s: f64) -> Option<ModbusRequest> {
        let m = self.modbus.get_mut(i)?;
        match step {
            PollStep::Request(PollRequest::Connect) => Some(ModbusRequest::Connect),
            PollStep::Request(PollRequest::Read(b)) => {
                let blk = &m.schedule.core.plan[b];
                Some(ModbusRequest::Read {
                    table: blk.kind,
                    start: blk.start,
                    count: blk.count,
                })
            }
            PollStep::Done {
                before,
                after,
                connected,
            } => {
                m.reporter.handle_modbus_poll(&before, &after, connected);
                let events = m.reporter.publish(now_s);
                self.edges.extend(events);
                None
            }
            PollStep::Idle => None,
        }
    }

    /// One cycle at `now_s`: the sources' freshness checks, every sample in arrival order, the
    /// reseeds of the last sink period, the cycle, and the engine's fault edges. Returns the
    /// outputs (µm, axis order).
    pub fn poll_cycle(&mut self, now_s: f64) -> &[(Axis, f64)] {
        if !self.engine_started {
            return self.cycle.outputs();
        }
        // Each source is polled when it says so, as the runtime's shells do (an earlier deadline
        // waits for this cycle: the cycle is the harness's step).
        if let Some(c) = self.canopen.as_mut()
            && c.poll_timeout().is_some_and(|due| due <= now_s)
        {
            c.poll(now_s, &mut self.samples);
        }
        for s in &mut self.serial {
            if s.poll_timeout() <= now_s {
                s.poll(now_s, &mut self.samples);
            }
        }
        for s in self.samples.drain(..) {
            if self.recorded.contains(&s.channel) {
                self.sample_log.push(s);
            }
            self.cycle.handle_sample(&s);
        }
        for (axis, held_um) in self.reseeds.drain(..) {
            // The sink hands over in-clamp values only; a refusal is logged and the axis holds.
            let _ = self.cycle.handle_reseed(axis, held_um);
        }
        self.cycle.poll_cycle(now_s);
        self.engine_edges();
        self.cycle.outputs()
    }

    /// An action from the API, applied by the next cycle.
    pub fn handle_control(&mut self, c: Control) {
        self.cycle.handle_control(c);
    }

    /// The engine's fault edges of the cycle just run: the events its fault log logged, as the
    /// runtime's log shows them.
    fn engine_edges(&mut self) {
        let events = self.cycle.engine().fault_events();
        self.edges.extend(events.iter().cloned());
    }

    /// The engine's outputs after the last cycle (before the first: the start values), µm.
    pub fn outputs(&self) -> &[(Axis, f64)] {
        self.cycle.outputs()
    }

    pub fn cycle_core(&self) -> &CycleCore {
        &self.cycle
    }

    /// The engine's mode of `axis`.
    pub fn mode(&self, axis: &str) -> Option<Mode> {
        self.cycle.engine().axis_mode(Axis::from_name(axis)?)
    }

    /// The value the engine's state holds for `channel` this cycle (None: unusable).
    pub fn channel_value(&self, channel: &str) -> Option<f64> {
        let snap = self.cycle.engine().snapshot();
        let st = snap.channels.iter().find(|(n, _)| *n == channel)?;
        let usable = st.1.health == retrocomp_bus::Health::Ok || st.1.substituted;
        st.1.value.filter(|_| usable)
    }

    /// Compensation enabled but some axis is not tracking (the `compensation.<axis>` fault).
    pub fn compensation_dropped(&self) -> bool {
        self.cycle.engine().compensation_dropped()
    }

    /// Start an origin-shift write period at `now_s`. `connected`: the client is connected (else
    /// the period fails at once, as the client's `ensure_connected` does). Returns the first
    /// request.
    pub fn poll_period(&mut self, now_s: f64, connected: bool) -> Option<&Action> {
        let os = self.origin_shift.as_mut()?;
        if !connected {
            os.core.not_connected("link down");
            os.pending = None;
            self.end_period(now_s, false);
            return None;
        }
        let a = os.core.begin_at(self.cycle.outputs(), now_s);
        self.settle(a, now_s, connected)
    }

    /// The request in flight, if any.
    pub fn pending(&self) -> Option<&Action> {
        self.origin_shift.as_ref()?.pending.as_ref()
    }

    /// The controller's reply to the request in flight; `connected`: the client's connection after
    /// it (a transport failure drops it, a Modbus exception does not). Returns the next request.
    pub fn handle_reply(&mut self, reply: Reply, now_s: f64, connected: bool) -> Option<&Action> {
        let os = self.origin_shift.as_mut()?;
        os.pending = None;
        let a = os.core.handle_reply(reply, now_s);
        self.settle(a, now_s, connected)
    }

    fn settle(&mut self, a: Action, now_s: f64, connected: bool) -> Option<&Action> {
        if matches!(a, Action::Done(_)) {
            // The shell's fault update after the period: `client.is_connected()`.
            self.end_period(now_s, connected);
            return None;
        }
        let os = self.origin_shift.as_mut()?;
        os.pending = Some(a);
        os.pending.as_ref()
    }

    /// The end of a period, as the sink task ends one: reseeds for the next cycle, fault edges.
    fn end_period(&mut self, now_s: f64, connected: bool) {
        let Some(os) = self.origin_shift.as_mut() else {
            return;
        };
        os.pending = None;
        let end = end_period(&mut os.core, &mut os.faults, &os.sources, connected, now_s);
        self.reseeds.extend(end.reseeds);
        self.edges.extend(end.events);
    }

    /// The origin-shift sink core's writes so far (ok, failed).
    pub fn sink_writes(&self) -> (u64, u64) {
        self.origin_shift
            .as_ref()
            .map_or((0, 0), |s| (s.core.writes_ok, s.core.writes_failed))
    }

    /// The quadrature box takes the last cycle's outputs at `now_ns` (= `now_s`), through the
    /// sink's guard. Its fault edges join the gateway's.
    pub fn poll_quadrature(&mut self, now_ns: u64, now_s: f64) {
        let outs = self.cycle.outputs();
        if let Some(q) = self.quadrature.as_mut() {
            let events = q.handle_outputs(outs, now_ns, now_s);
            self.edges.extend(events);
        }
    }

    /// Stop with `on_stop = "ramp_out"` (the runtime's SIGTERM/SIGINT): from now on the sink wants
    /// 0 on every axis whatever the cycle's outputs, at most one cap per write period (origin
    /// shift), per quadrature step or per server update (taken at the next `poll_served`, with the
    /// `stop_ramp_max_s` deadline), and never ramps an axis whose controller value is beyond the
    /// clamp. Keep driving `poll_period` / `poll_quadrature` / `poll_served` until
    /// [`GatewayCore::is_ramped_out`].
    pub fn handle_stop(&mut self) {
        self.stop_requested = true;
        if let Some(os) = self.origin_shift.as_mut() {
            os.core.begin_ramp_out();
        }
        if let Some(q) = self.quadrature.as_mut() {
            q.begin_ramp_out();
        }
    }

    /// Stopping, and the controller holds 0 on every axis (origin shift: a period's read showed
    /// it; quadrature: 0 counts, every edge out).
    pub fn is_ramped_out(&self) -> bool {
        self.origin_shift
            .as_ref()
            .is_none_or(|os| os.core.is_ramped_out())
            && self
                .quadrature
                .as_ref()
                .is_none_or(QuadratureBox::is_ramped_out)
            && self
                .served
                .as_ref()
                .is_none_or(|s| s.sink().core().is_ramped_out())
    }

    /// The quadrature box (`[sink.quadrature]`), if that is the sink.
    pub fn quadrature_mut(&mut self) -> Option<&mut QuadratureBox> {
        self.quadrature.as_mut()
    }

    pub fn quadrature(&self) -> Option<&QuadratureBox> {
        self.quadrature.as_ref()
    }

    /// Fault edges (engine and sink) since the last call.
    pub fn take_edges(&mut self) -> Vec<FaultEvent> {
        std::mem::take(&mut self.edges)
    }
}
