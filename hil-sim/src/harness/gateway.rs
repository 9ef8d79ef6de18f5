//! The gateway side of the closed-loop harness, through a narrow adapter: the only module of the
//! harness that names retrocomp's engine, decoders and sink core, so a change of their signatures
//! (typed channel ids, typed outputs, sink shells moving) is a few lines here.
//!
//! What it holds is what `retrocomp run` holds, minus the threads and sockets: the CANopen source
//! core (CiA 406 encoders, CiA 404 temperatures), the serial line source core (weighing lines), the
//! [`Engine`] with the machine model, and either the origin-shift [`SinkCore`] (read → last-step
//! guard → write cycle, with the sink's fault episodes from the real shell's `update_faults`) or
//! the quadrature box ([`QuadratureBox`]: counts and edges). Time is the
//! harness' virtual time (s), passed in.
//!
//! Units: µm for corrections (correction = −error), mm for positions, s for time.

use std::collections::BTreeMap;

use retrocomp_bus::can::Frame;
use retrocomp_bus::canopen::source::CanopenSource;
use retrocomp_bus::serial::source::LineSource;
use retrocomp_bus::{ChannelId, Sample};
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::health::{FaultKind, FaultLog};
use retrocomp_gateway::engine::safety::Mode;
use retrocomp_gateway::engine::{Engine, ErrorModel};
use retrocomp_gateway::sinks::origin_shift::sink_task::update_faults;
use retrocomp_gateway::sinks::origin_shift::{Action, Reply, SinkAxis, SinkCore};
use retrocomp_model::Axis;

use super::quadrature::{MemoryHeld, QuadratureBox};

/// One fault edge as the gateway logs it (source, kind, started or cleared, gateway time).
#[derive(Clone, Debug, PartialEq)]
pub struct FaultEdge {
    pub t_s: f64,
    pub source: String,
    pub kind: FaultKind,
    pub started: bool,
}

/// The in-process gateway: decoders → engine → origin-shift sink core.
pub struct Gateway {
    cfg: FieldConfig,
    engine: Engine,
    model: Box<dyn ErrorModel>,
    canopen: Option<CanopenSource>,
    serial: Vec<LineSource>,
    /// The origin-shift sink core, or (`[sink.quadrature]`) the quadrature box.
    sink: Option<SinkCore>,
    quadrature: Option<QuadratureBox>,
    sink_faults: FaultLog,
    samples: Vec<Sample>,
    /// The sink's request in flight (answered at the next harness step), if a period runs.
    pending: Option<Action>,
    /// The outputs of the last cycle: what the sink writes at its next period (the shell's watch).
    outputs: Vec<(Axis, f64)>,
    /// Engine faults active after the last cycle (to turn the snapshot into edges).
    engine_active: BTreeMap<(String, FaultKind), f64>,
    /// Fault edges since the last [`Gateway::take_edges`].
    edges: Vec<FaultEdge>,
    /// Channels whose samples are kept ([`Gateway::record_samples`]), and those samples.
    recorded: Vec<ChannelId>,
    sample_log: Vec<Sample>,
}

// By hand: the model is a trait object.
impl std::fmt::Debug for Gateway {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Gateway")
            .field("engine", &self.engine)
            .field("pending", &self.pending)
            .field("outputs", &self.outputs)
            .field("edges", &self.edges)
            .finish_non_exhaustive()
    }
}

impl Gateway {
    /// Start as `retrocomp run` does: the sink reads what the controller holds first (`held_um`,
    /// per axis, origin shift: values beyond the clamp are not start values; `held_counts`,
    /// quadrature: a count beyond the clamp refuses the start) and the engine continues from it.
    pub fn start(
        cfg: FieldConfig,
        model: Box<dyn ErrorModel>,
        held_um: &BTreeMap<String, f64>,
        held_counts: MemoryHeld,
    ) -> anyhow::Result<Self> {
        // The controller's registers: a value beyond the clamp is not a start value (the real
        // origin-shift sink reports it as a fault and ramps from the clamp side).
        let mut initial: BTreeMap<String, f64> = held_um
            .iter()
            .filter(|(axis, v)| v.is_finite() && v.abs() <= cfg.safety_for(axis).max_correction_um)
            .map(|(a, v)| (a.clone(), *v))
            .collect();
        // The persisted quadrature counts go in as they are: beyond the clamp, `Engine::new`
        // refuses the start, as `retrocomp run` does.
        let quadrature = match cfg.sink.quadrature.as_ref() {
            Some(q) => {
                let (b, start) = QuadratureBox::new(q, held_counts)?;
                initial.extend(start);
                Some(b)
            }
            None => None,
        };
        let map = match (&cfg.sink.origin_shift, &quadrature) {
            (Some(os), None) => Some(os.map.clone()),
            (None, Some(_)) => None,
            _ => anyhow::bail!("the harness drives [sink.origin_shift] or [sink.quadrature]"),
        };
        let engine = cfg.engine(&initial)?;
        let axes = cfg
            .axes
            .iter()
            .map(|a| {
                let s = cfg.safety_for(&a.name);
                SinkAxis {
                    axis: a.name.clone(),
                    max_correction_um: s.max_correction_um,
                    max_change_um_per_write: s.max_change_um_per_cycle,
                }
            })
            .collect();
        let canopen = cfg.canopen.clone().map(CanopenSource::new);
        let serial = cfg
            .serial
            .iter()
            .flat_map(|s| s.source.iter().cloned())
            .map(LineSource::new)
            .collect();
        Ok(Self {
            outputs: engine.outputs(),
            sink: map.map(|m| SinkCore::new(m, axes)),
            quadrature,
            cfg,
            engine,
            model,
            canopen,
            serial,
            sink_faults: FaultLog::default(),
            samples: Vec::new(),
            pending: None,
            engine_active: BTreeMap::new(),
            edges: Vec::new(),
            recorded: Vec::new(),
            sample_log: Vec::new(),
        })
    }

    pub fn config(&self) -> &FieldConfig {
        &self.cfg
    }

    /// A CAN frame arrived at `t_s`.
    pub fn on_frame(&mut self, f: &Frame, t_s: f64) {
        if let Some(c) = self.canopen.as_mut() {
            c.on_frame(f, t_s, &mut self.samples);
        }
    }

    /// Bytes arrived on serial source `i` at `t_s`.
    pub fn on_serial(&mut self, i: usize, bytes: &[u8], t_s: f64) {
        if let Some(s) = self.serial.get_mut(i) {
            s.push(bytes, t_s, &mut self.samples);
        }
    }

    /// Keep every sample of `channel` the engine ingests from now on (in arrival order).
    pub fn record_samples(&mut self, channel: &str) {
        self.recorded.push(ChannelId::of(channel));
    }

    /// The samples of the recorded channels, in the order the engine ingested them.
    pub fn recorded_samples(&self) -> &[Sample] {
        &self.sample_log
    }

    /// Garbage lines the serial sources counted so far.
    pub fn serial_garbage_lines(&self) -> u64 {
        self.serial.iter().map(|s| s.counters().garbage_lines).sum()
    }

    /// One engine cycle at `now_s`: the sources' freshness checks, every sample in arrival order,
    /// the cycle, and the fault edges of the engine. Returns the outputs (µm, axis order).
    pub fn cycle(&mut self, now_s: f64) -> &[(Axis, f64)] {
        if let Some(c) = self.canopen.as_mut() {
            c.poll(now_s, &mut self.samples);
        }
        for s in &self.serial {
            s.poll(now_s, &mut self.samples);
        }
        for s in self.samples.drain(..) {
            if self.recorded.contains(&s.channel) {
                self.sample_log.push(s);
            }
            self.engine.ingest(&s);
        }
        let outs = self.engine.cycle_in_place(now_s, self.model.as_mut());
        self.outputs.clone_from_slice(outs);
        let now: BTreeMap<(String, FaultKind), f64> = self
            .engine
            .snapshot()
            .active_faults
            .into_iter()
            .map(|(s, k, t)| ((s, k), t))
            .collect();
        for ((source, kind), t) in &now {
            if !self.engine_active.contains_key(&(source.clone(), *kind)) {
                self.edges.push(FaultEdge {
                    t_s: *t,
                    source: source.clone(),
                    kind: *kind,
                    started: true,
                });
            }
        }
        for (source, kind) in self.engine_active.keys() {
            if !now.contains_key(&(source.clone(), *kind)) {
                self.edges.push(FaultEdge {
                    t_s: now_s,
                    source: source.clone(),
                    kind: *kind,
                    started: false,
                });
            }
        }
        self.engine_active = now;
        &self.outputs
    }

    /// The engine's outputs after the last cycle, µm (axis order).
    pub fn outputs(&self) -> &[(Axis, f64)] {
        &self.outputs
    }

    /// The engine's mode of `axis`.
    pub fn mode(&self, axis: &str) -> Option<Mode> {
        self.engine.axis_mode(Axis::from_name(axis)?)
    }

    /// The value the engine's state holds for `channel` this cycle (None: unusable).
    pub fn channel_value(&self, channel: &str) -> Option<f64> {
        let snap = self.engine.snapshot();
        let st = snap.channels.iter().find(|(n, _)| *n == channel)?;
        let usable = st.1.health == retrocomp_bus::Health::Ok || st.1.substituted;
        st.1.value.filter(|_| usable)
    }

    /// Compensation enabled but some axis is not tracking (the `compensation.<axis>` fault).
    pub fn compensation_dropped(&self) -> bool {
        self.engine.compensation_dropped()
    }

    /// Start a sink write period at `now_s`. `connected`: the client is connected (else the period
    /// fails at once, as the client's `ensure_connected` does). Returns the first request.
    pub fn begin_period(&mut self, now_s: f64, connected: bool) -> Option<&Action> {
        if !connected {
            self.sink.as_mut()?.not_connected("link down (harness)");
            self.pending = None;
            self.end_period(now_s, false);
            return None;
        }
        let a = self.sink.as_mut()?.begin_at(&self.outputs, now_s);
        self.settle(a, now_s, connected)
    }

    /// The request in flight, if any.
    pub fn pending(&self) -> Option<&Action> {
        self.pending.as_ref()
    }

    /// The controller's reply to the request in flight; `connected`: the client's connection after
    /// it (a transport failure drops it, a Modbus exception does not). Returns the next request.
    pub fn reply(&mut self, reply: Reply, now_s: f64, connected: bool) -> Option<&Action> {
        self.pending = None;
        let a = self.sink.as_mut()?.on_reply(reply, now_s);
        self.settle(a, now_s, connected)
    }

    fn settle(&mut self, a: Action, now_s: f64, connected: bool) -> Option<&Action> {
        match a {
            Action::Done(_) => {
                // The shell's fault update after the period: `client.is_connected()`.
                self.end_period(now_s, connected);
                self.pending = None;
            }
            a => self.pending = Some(a),
        }
        self.pending.as_ref()
    }

    /// The end of a period: reseeds back to the engine (as the shell sends them), fault edges.
    fn end_period(&mut self, now_s: f64, connected: bool) {
        let Some(sink) = self.sink.as_mut() else {
            return;
        };
        for (axis, held) in sink.take_reseeds() {
            // An in-clamp value always gives a valid safety state; a refusal is a harness bug.
            self.engine
                .reseed(axis, held)
                .expect("reseed with an in-clamp value");
        }
        let before: Vec<(String, FaultKind)> = self
            .sink_faults
            .active()
            .map(|(s, k, _)| (s.to_string(), k))
            .collect();
        update_faults(&mut self.sink_faults, sink, connected, now_s);
        let after: Vec<(String, FaultKind)> = self
            .sink_faults
            .active()
            .map(|(s, k, _)| (s.to_string(), k))
            .collect();
        for (source, kind) in &after {
            if !before.contains(&(source.clone(), *kind)) {
                self.edges.push(FaultEdge {
                    t_s: now_s,
                    source: source.clone(),
                    kind: *kind,
                    started: true,
                });
            }
        }
        for (source, kind) in before {
            if !after.contains(&(source.clone(), kind)) {
                self.edges.push(FaultEdge {
                    t_s: now_s,
                    source,
                    kind,
                    started: false,
                });
            }
        }
    }

    /// The sink core's writes so far (ok, failed).
    pub fn sink_writes(&self) -> (u64, u64) {
        self.sink
            .as_ref()
            .map_or((0, 0), |s| (s.writes_ok, s.writes_failed))
    }

    /// The quadrature box (`[sink.quadrature]`), if that is the sink.
    pub fn quadrature_mut(&mut self) -> Option<&mut QuadratureBox> {
        self.quadrature.as_mut()
    }

    pub fn quadrature(&self) -> Option<&QuadratureBox> {
        self.quadrature.as_ref()
    }

    /// Fault edges (engine and sink) since the last call.
    pub fn take_edges(&mut self) -> Vec<FaultEdge> {
        std::mem::take(&mut self.edges)
    }
}
