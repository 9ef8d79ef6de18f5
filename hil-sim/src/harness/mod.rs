//! A deterministic closed loop in one process, in the manner of quinn-proto's `Pair` tests: hil-sim's
//! [`World`] ↔ retrocomp's own sans-IO gateway ([`GatewayCore`]: its source cores, cycle, engine
//! and sink cores, composed by the gateway crate, not here) ↔ the simulated PLC or the quadrature
//! receivers, all advanced by one [`ClosedLoop::step`] in virtual time. No threads, no sleeps, no sockets:
//! the same configs give the same run, bit for bit, however busy the machine is.
//!
//! Per step (the world's servo period, 1 ms by default), in this fixed order:
//! 1. the world steps (interpolator, PLC scan, servos, thermal, cutting, sensor faults);
//! 2. the transport-fault schedule of the sim config (`[[io.faults]]`) moves to the new time;
//! 3. the sim's own encoders ([`Publisher`]: CiA 406 / CiA 404 frames, weighing lines, the Modbus
//!    input registers) produce what is due; frames of a silent node are dropped (`silenced`),
//!    garbage bytes (`Garbage`, seeded) go on the serial line before the lines; the gateway decodes
//!    them with its own source cores; its `[[modbus.source]]`s poll the sim's RTU slave (`rtu.rs`:
//!    mute while `modbus_rtu_down`, a read then times out after the source's `timeout_s`);
//! 4. on a cycle tick (`gateway.cycle_ms`) the gateway's cycle runs (reseeds of the last sink
//!    period first, as through the runtime's channel); with `[sink.quadrature]` the box steps the
//!    outputs through the sink's guard and its lines' due edges reach the controller's receivers;
//! 5. the sink's request in flight (issued one step earlier: one step of latency) is answered from
//!    the PLC's registers, or fails while the Modbus link is down (the client drops the connection
//!    and waits out its [`retrocomp_bus::Backoff`], `link`); on a write-period tick
//!    (`write_period_ms`, skipped while a period still runs, as tokio's `MissedTickBehavior::Skip`)
//!    a new period begins: at once when connected, else only once the backoff's next attempt is due
//!    and the link is up.
//!
//! Process faults of the gateway: [`ClosedLoop::kill_gateway`] (SIGKILL, then
//! [`ClosedLoop::start_new_gateway`] or [`ClosedLoop::restart_gateway`]), [`ClosedLoop::freeze_gateway`]
//! (SIGSTOP/SIGCONT: it handles nothing while frozen), [`ClosedLoop::stop_gateway`] (SIGTERM with a
//! ramp-out). The PLC's own record (latches, its heartbeat watchdog's trip / ramp / re-arm) is kept
//! with the step's time ([`ClosedLoop::plc_events`]).
//!
//! Every write that reaches the PLC is logged with what the PLC applied at that moment
//! ([`PlcWrite`]), and every step's applied shift ([`StepTrace`]): the scenarios assert the clamp,
//! the cap per write and "no jump" on these, against what the controller actually holds.
//!
//! Simplifications (documented in docs/hil-sim.md): every request and every connect takes exactly
//! one step (a real timeout or refused connect takes longer, which only shifts the attempts).
//!
//! Units: µm for shifts and corrections (register = correction; + moves the slide +), s for time.

pub(crate) mod link;
mod master;
mod plc;
mod quadrature;
mod rtu;

use std::collections::BTreeMap;

use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::ErrorModel;
use retrocomp_gateway::sinks::quadrature::{DecodeError, QuadDecoder};
use retrocomp_model::Axis;

use crate::SimConfig;
use crate::controller::plc::PlcEvent;
use crate::io::publish::Publisher;
use crate::io::transport_faults::{Garbage, Schedule, Transition, silenced};
use crate::world::World;
pub use link::{ClientLink, ConnectAttempt};
pub use retrocomp_bus::fault::FaultEvent;
pub use retrocomp_gateway::gateway_core::{GatewayCore, MemoryHeld};

/// Builds a fresh model for each gateway start (a restart loads it again).
pub type ModelFactory = Box<dyn Fn() -> Box<dyn ErrorModel + Send>>;

/// One A/B edge the controller's quadrature receiver saw (`[sink.quadrature]`).
#[derive(Clone, Debug, PartialEq)]
pub struct Pulse {
    pub t_ns: u64,
    pub axis: Axis,
    /// +1 / −1 count into the servo's feedback, or the receiver's error (both lines changed).
    pub step: Result<i64, DecodeError>,
    /// Which gateway start's box drove the lines (0 = the first; +1 per restart).
    pub generation: u32,
}

/// The controller's ×4 quadrature receiver of one axis: the counts it took into the feedback.
#[derive(Clone, Debug)]
struct Receiver {
    decoder: QuadDecoder,
    count: i64,
}

impl Receiver {
    /// The lines now show (a, b): the count this adds (±1), nothing, or the receiver's error
    /// (both lines changed: the receiver resyncs to the lines, a count is lost).
    fn see(&mut self, a: bool, b: bool) -> Option<Result<i64, DecodeError>> {
        match self.decoder.update(a, b) {
            Ok(None) => None,
            Ok(Some(s)) => {
                self.count += s.sign();
                Some(Ok(s.sign()))
            }
            Err(e) => {
                self.decoder = QuadDecoder::new(a, b);
                Some(Err(e))
            }
        }
    }
}

/// One write the sink made into the PLC window.
#[derive(Clone, Debug, PartialEq)]
pub struct PlcWrite {
    pub t_s: f64,
    pub address: u16,
    pub words: Vec<u16>,
    /// The shifts the PLC applied when the write arrived, µm (x, y, z).
    pub applied_um: [f64; 3],
    /// The shift registers after the write, µm.
    pub registers_um: [f64; 3],
    /// Which gateway start made it (0 = the first; +1 per restart).
    pub generation: u32,
}

/// The loop's state after one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepTrace {
    pub t_s: f64,
    /// The shifts the PLC applies, µm.
    pub applied_um: [f64; 3],
    /// The engine's outputs after its last cycle, µm (NaN while no gateway runs).
    pub output_um: [f64; 3],
}

pub struct ClosedLoop {
    world: World,
    publisher: Publisher,
    schedule: Schedule,
    garbage: Garbage,
    field: FieldConfig,
    model: ModelFactory,
    gateway: Option<GatewayCore>,
    generation: u32,
    cycle_ticks: u64,
    /// The sink's write period (`[sink.origin_shift]`) or the server's update period
    /// (`[sink.origin_shift_server]`), in steps.
    write_ticks: u64,
    /// `[sink.origin_shift_server]`: the controller's master polls the box every this many steps.
    master_ticks: u64,
    /// Modbus link state after the last step (the schedule's `modbus_down`).
    link_up: bool,
    /// The sink's client connection (one per gateway start) and the attempts of earlier starts.
    client: ClientLink,
    attempts: Vec<ConnectAttempt>,
    /// One world step, ns (the harness clock is whole steps).
    dt_ns: u64,
    writes: Vec<PlcWrite>,
    trace: Vec<StepTrace>,
    edges: Vec<FaultEvent>,
    transitions: Vec<Transition>,
    /// Bytes put on the serial line so far (lines and garbage).
    serial_bytes: u64,
    /// `[sink.quadrature]`: the controller's ×4 receiver per axis (x, y, z), and every edge seen.
    receivers: Option<[Receiver; 3]>,
    pulses: Vec<Pulse>,
    /// `[sink.quadrature]`: the box's held-counts store, surviving its restarts (the state file).
    held_counts: MemoryHeld,
    /// The sim's Modbus RTU slave for the gateway's `[[modbus.source]]`s.
    rtu: rtu::RtuSlave,
    /// The gateway process is stopped (SIGSTOP).
    frozen: bool,
    plc_events: Vec<(f64, PlcEvent)>,
}

// By hand: the model factory is a closure.
impl std::fmt::Debug for ClosedLoop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClosedLoop")
            .field("world", &self.world)
            .field("gateway", &self.gateway)
            .field("generation", &self.generation)
            .field("link_up", &self.link_up)
            .field("serial_bytes", &self.serial_bytes)
            .finish_non_exhaustive()
    }
}

/// Ticks of `period_ms` at `dt_s` per tick; the harness refuses periods that are not whole ticks.
fn ticks(period_ms: u64, dt_s: f64, key: &str) -> anyhow::Result<u64> {
    let n = period_ms as f64 / 1e3 / dt_s;
    anyhow::ensure!(
        n >= 1.0 && (n - n.round()).abs() < 1e-9,
        "{key} = {period_ms} ms is not a whole number of {dt_s} s steps"
    );
    Ok(retrocomp_analysis::numeric::round_u64(n))
}

impl ClosedLoop {
    /// The world of `sim` and a gateway started from `field` (its `[sink.origin_shift]` map must
    /// address the PLC window), with a fresh model from `model` at every start.
    pub fn new(sim: SimConfig, field: FieldConfig, model: ModelFactory) -> anyhow::Result<Self> {
        let world = World::new(sim)?;
        let dt = world.config().dt_s();
        let cycle_ticks = ticks(field.gateway.cycle_ms, dt, "gateway.cycle_ms")?;
        let (write_ticks, client) = match (
            &field.sink.origin_shift,
            &field.sink.origin_shift_server,
        ) {
            (Some(os), _) => (
                ticks(os.write_period_ms, dt, "sink.origin_shift.write_period_ms")?,
                ClientLink::connected(os.reconnect_min_ms, os.reconnect_max_ms),
            ),
            (None, Some(srv)) => {
                let lsb = world.config().plc.lsb_um;
                anyhow::ensure!(
                    srv.map
                        .axes
                        .iter()
                        .all(|r| (r.lsb_um - lsb).abs() < 1e-12 && r.sign == 1),
                    "sink.origin_shift_server.map: every axis needs the PLC's lsb_um {lsb} and sign 1"
                );
                (
                    ticks(
                        srv.update_period_ms,
                        dt,
                        "sink.origin_shift_server.update_period_ms",
                    )?,
                    ClientLink::connected(0, 0),
                )
            }
            (None, None) => (0, ClientLink::connected(0, 0)),
        };
        let master_ticks = ticks(master::MASTER_PERIOD_MS, dt, "the master's period")?;
        // One injected count is one count of the controller's feedback (`servo.count_um`).
        let receivers = match &field.sink.quadrature {
            Some(q) => {
                let count = world.config().servo.count_um;
                for a in &q.axes {
                    anyhow::ensure!(
                        (a.resolution_um - count).abs() < 1e-12 && a.count_sign == 1,
                        "sink.quadrature axis {}: resolution_um {} and count_sign {} must be the \
                         sim's servo.count_um {count} and +1",
                        a.axis,
                        a.resolution_um,
                        a.count_sign
                    );
                }
                // The box starts at phase 0: both lines low.
                Some(std::array::from_fn(|_| Receiver {
                    decoder: QuadDecoder::new(false, false),
                    count: 0,
                }))
            }
            None => None,
        };
        let io = world.config().io.clone();
        let publisher = Publisher::new(io.clone(), &world);
        let rtu = rtu::RtuSlave::new(&field);
        // As `hil-sim serve`: mean 30 ms between bursts.
        let garbage = Garbage::new(world.config().seed, 0.03);
        let mut h = Self {
            publisher,
            schedule: Schedule::new(io.faults),
            garbage,
            field,
            model,
            gateway: None,
            generation: 0,
            cycle_ticks,
            write_ticks,
            master_ticks,
            link_up: true,
            client,
            attempts: Vec::new(),
            dt_ns: retrocomp_analysis::numeric::round_u64(dt * 1e9),
            writes: Vec::new(),
            trace: Vec::new(),
            edges: Vec::new(),
            transitions: Vec::new(),
            serial_bytes: 0,
            receivers,
            pulses: Vec::new(),
            held_counts: Default::default(),
            rtu,
            frozen: false,
            plc_events: Vec::new(),
            world,
        };
        h.start_gateway()?;
        Ok(h)
    }

    /// Start a gateway as `retrocomp run` does: read what the PLC's registers hold, continue from it.
    fn start_gateway(&mut self) -> anyhow::Result<()> {
        let held = self.registers_held_um();
        if let Some(os) = &self.field.sink.origin_shift {
            let fresh = ClientLink::connected(os.reconnect_min_ms, os.reconnect_max_ms);
            let old = std::mem::replace(&mut self.client, fresh);
            self.attempts.extend_from_slice(old.attempts());
        }
        let gw = if self.field.sink.origin_shift_server.is_some() {
            GatewayCore::start_served(self.field.clone(), (self.model)(), self.world.t_s())?
        } else {
            GatewayCore::start(
                self.field.clone(),
                (self.model)(),
                held,
                self.held_counts.clone(),
            )?
        };
        // A new box takes the lines at its scheduler's levels (the held count's phase): the
        // controller's receiver sees whatever change that is from the levels the old box left.
        if let Some(q) = gw.quadrature() {
            let t_ns = self.world.ticks() * self.dt_ns;
            let levels: Vec<_> = Axis::ALL
                .into_iter()
                .filter_map(|axis| Some((axis, t_ns, q.levels(axis)?)))
                .collect();
            self.receive(&levels);
        }
        self.gateway = Some(gw);
        Ok(())
    }

    /// `[sink.quadrature]`: the box's persisted held counts (its state file, in memory).
    pub fn held_counts(&self) -> &MemoryHeld {
        &self.held_counts
    }

    /// The gateway process dies (SIGKILL: nothing more is sent) and starts again at once.
    pub fn restart_gateway(&mut self) -> anyhow::Result<()> {
        self.kill_gateway();
        self.start_new_gateway()
    }

    /// The gateway process dies (SIGKILL): nothing more is sent until [`Self::start_new_gateway`].
    pub fn kill_gateway(&mut self) {
        self.collect_edges();
        self.gateway = None;
        self.frozen = false;
        self.rtu.restart();
        self.generation += 1;
    }

    /// A new gateway process starts (after [`Self::kill_gateway`]).
    pub fn start_new_gateway(&mut self) -> anyhow::Result<()> {
        anyhow::ensure!(self.gateway.is_none(), "a gateway runs");
        self.start_gateway()
    }

    /// The gateway process is frozen (SIGSTOP) or runs again (SIGCONT): frozen, it reads nothing,
    /// cycles nothing and sends nothing (what the sources sent meanwhile is lost to it, and a
    /// request in flight is answered when it runs again); its clock goes on.
    pub fn freeze_gateway(&mut self, frozen: bool) {
        self.frozen = frozen;
    }

    /// The PLC's record: every change of what it applies and every watchdog edge, at the step
    /// that made it (`plc_latches.csv` of `hil-sim serve`).
    pub fn plc_events(&self) -> &[(f64, PlcEvent)] {
        &self.plc_events
    }

    /// The gateway is asked to stop (SIGTERM with `on_stop = "ramp_out"`): its sink ramps the
    /// controller's correction out within the cap while the harness keeps stepping (the cycles go
    /// on; the sink no longer follows them).
    pub fn stop_gateway(&mut self) {
        if let Some(gw) = self.gateway.as_mut() {
            gw.handle_stop();
        }
    }

    /// The stopping gateway's sink has ramped the controller out to 0 on every axis.
    pub fn is_ramped_out(&self) -> bool {
        self.gateway
            .as_ref()
            .is_some_and(GatewayCore::is_ramped_out)
    }

    /// What the PLC's value registers hold per map axis, µm (decoded with the sink's own map).
    pub fn registers_held_um(&self) -> BTreeMap<String, f64> {
        let Some(os) = self.field.sink.origin_shift.as_ref() else {
            return BTreeMap::new();
        };
        let map = &os.map;
        let plc = self.world.plc();
        map.axes
            .iter()
            .filter_map(|r| {
                let words = plc.read(r.address, r.data_type.words() as usize).ok()?;
                Some((r.axis.clone(), map.decode(&r.axis, words).ok()?))
            })
            .collect()
    }

    /// Someone else (an operator, another writer) sets the shift of `axis` (0..3) to `um` and
    /// strobes it in: the PLC applies it at its next scan.
    pub fn foreign_write(&mut self, axis: usize, um: f64) -> anyhow::Result<()> {
        let plc = self.world.plc_mut();
        let counts = retrocomp_analysis::numeric::round_i64(um / plc.config().lsb_um);
        let words = plc.encode(counts)?;
        plc.write(plc.shift_register(axis), &words)?;
        if let Some(h) = plc.config().handshake.clone() {
            let strobe = plc.read(h.strobe_register, 1)?[0];
            plc.write(h.strobe_register, &[u16::from(strobe == 0)])?;
        }
        Ok(())
    }

    /// Advance everything by one world step.
    pub fn step(&mut self) {
        self.world.tick();
        let tick = self.world.ticks();
        let t = self.world.t_s();
        let events = self.world.plc_mut().take_events();
        self.plc_events.extend(events.into_iter().map(|e| (t, e)));
        let (active, changes) = self.schedule.advance(t);
        self.transitions.extend(changes);
        self.link_up = !active.modbus_down;
        self.rtu.set_answers(active.rtu_answers());
        let out = self.publisher.poll(&mut self.world);
        self.rtu.publish(&out.input_regs);
        let junk = self.garbage.poll(t, active.serial_garbage);
        if self.frozen {
            self.trace_step(t);
            return;
        }
        if let Some(gw) = self.gateway.as_mut() {
            for f in out.frames.iter().filter(|f| !silenced(f, &active)) {
                gw.handle_frame(f, t);
            }
            self.serial_bytes += junk.len() as u64;
            gw.handle_serial(0, &junk, t);
            for l in &out.lines {
                self.serial_bytes += l.len() as u64;
                gw.handle_serial(0, l.as_bytes(), t);
            }
            self.rtu.drive(gw, t);
            if tick.is_multiple_of(self.cycle_ticks) {
                gw.poll_cycle(t);
            }
        }
        if self.receivers.is_some() {
            self.run_quadrature(tick);
        } else if self.field.sink.origin_shift_server.is_some() {
            self.run_server(tick, t);
        } else {
            self.run_sink(tick, t);
        }
        self.trace_step(t);
    }

    /// The step's trace row and the gateway's fault edges.
    fn trace_step(&mut self, t: f64) {
        let output_um = self.gateway.as_ref().map_or([f64::NAN; 3], |gw| {
            let o = gw.outputs();
            std::array::from_fn(|k| o.get(k).map_or(f64::NAN, |(_, v)| *v))
        });
        self.trace.push(StepTrace {
            t_s: t,
            applied_um: self.applied_um(),
            output_um,
        });
        self.collect_edges();
    }

    /// Step until the world's time reaches `t_s` (or the program ends).
    pub fn run_until(&mut self, t_s: f64) {
        while self.world.t_s() + 1e-9 < t_s && !self.world.done() {
            self.step();
        }
    }

    /// Step until the program ends (M30 or the duration guard).
    pub fn run_to_end(&mut self) {
        while !self.world.done() {
            self.step();
        }
    }

    fn collect_edges(&mut self) {
        if let Some(gw) = self.gateway.as_mut() {
            self.edges.extend(gw.take_edges());
        }
    }

    /// The correction the controller applies, µm: the PLC's shifts (origin shift), or the counts
    /// its quadrature receiver took (`[sink.quadrature]`: +n counts move the slide −n counts).
    pub fn applied_um(&self) -> [f64; 3] {
        match &self.receivers {
            Some(rx) => {
                let count = self.world.config().servo.count_um;
                std::array::from_fn(|k| -(rx[k].count as f64) * count)
            }
            None => std::array::from_fn(|k| self.world.plc().shift_um(k)),
        }
    }

    /// Every edge the controller's quadrature receivers saw, in order (`[sink.quadrature]`).
    pub fn pulses(&self) -> &[Pulse] {
        &self.pulses
    }

    /// The counts each receiver took so far (x, y, z), if the sink is `[sink.quadrature]`.
    pub fn received_counts(&self) -> Option<[i64; 3]> {
        self.receivers
            .as_ref()
            .map(|rx| std::array::from_fn(|k| rx[k].count))
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn world_mut(&mut self) -> &mut World {
        &mut self.world
    }

    pub fn gateway(&self) -> Option<&GatewayCore> {
        self.gateway.as_ref()
    }

    pub fn gateway_mut(&mut self) -> Option<&mut GatewayCore> {
        self.gateway.as_mut()
    }

    pub fn t_s(&self) -> f64 {
        self.world.t_s()
    }

    /// Every write the sinks made into the PLC, in order.
    pub fn writes(&self) -> &[PlcWrite] {
        &self.writes
    }

    /// One row per step.
    pub fn trace(&self) -> &[StepTrace] {
        &self.trace
    }

    /// Every fault edge the gateways logged (engine and sink), in order.
    pub fn fault_edges(&self) -> &[FaultEvent] {
        &self.edges
    }

    /// Every connection attempt of the sink's client after a lost link (all gateway starts), in
    /// order.
    pub fn connect_attempts(&self) -> Vec<ConnectAttempt> {
        let mut all = self.attempts.clone();
        all.extend_from_slice(self.client.attempts());
        all
    }

    /// Every transport-fault start and clear the schedule made.
    pub fn transitions(&self) -> &[Transition] {
        &self.transitions
    }

    /// Modbus requests the sim's RTU slave left unanswered so far (muted).
    pub fn rtu_unanswered(&self) -> u64 {
        self.rtu.unanswered
    }

    /// Bytes put on the serial line so far.
    pub fn serial_bytes(&self) -> u64 {
        self.serial_bytes
    }

    /// The gateway's engine cycle period and the sink's write period, s.
    pub fn periods_s(&self) -> (f64, f64) {
        let dt = self.world.config().dt_s();
        (self.cycle_ticks as f64 * dt, self.write_ticks as f64 * dt)
    }
}
