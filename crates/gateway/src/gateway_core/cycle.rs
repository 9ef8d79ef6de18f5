//! The cycle's sans-IO core: what happens between two cycles and in one, with time passed in.
//! Every driver of the gateway runs its cycles through this one type: the runtime's cycle thread
//! ([`crate::cycle::CycleLoop`], which only drains channels into it, times it and publishes) and
//! the closed-loop harness ([`super::GatewayCore`]). So the order of a cycle (samples, reseeds,
//! actions, a model switch, the engine) and its accounting of dropped compensation are written
//! once.
//!
//! Driving vocabulary: `handle_*` for what arrived (a sample, a reseed from the sink, an action
//! from the API), [`CycleCore::poll_cycle`] to run one cycle at `now_s` (gateway clock, s).
//!
//! Units: corrections µm (correction = −error), time s.

use retrocomp_bus::Sample;
use retrocomp_model::Axis;

pub use crate::engine::model_switch::Control;
use crate::engine::model_switch::Switcher;
use crate::engine::safety::SafetyError;
use crate::engine::{Engine, ErrorModel};
use crate::status::{ModelIdentity, StatusSnapshot};

/// Time without compensation, summed over the cycles (what a run's summary reports).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CompensationTime {
    /// Cycles run.
    pub cycles: u64,
    /// Time during which compensation was enabled but at least one axis did not track, s.
    pub not_compensating_s: f64,
    /// Separate episodes of that.
    pub not_compensating_episodes: u64,
    /// Time during which compensation ran without the terms of an unusable optional channel
    /// (e.g. the load terms while the force is stale), s, and its episodes.
    pub partial_s: f64,
    pub partial_episodes: u64,
}

/// The engine, its model, a model switch in progress and the compensation accounting.
pub struct CycleCore {
    engine: Engine,
    model: Box<dyn ErrorModel + Send>,
    /// Which model runs (name, hash, loaded when), copied into every snapshot.
    model_identity: Option<ModelIdentity>,
    /// A model switch in progress (`POST /api/model`).
    switcher: Switcher,
    last_cycle_s: Option<f64>,
    dropped: bool,
    partial: bool,
    time: CompensationTime,
}

// By hand: the model is a trait object.
impl std::fmt::Debug for CycleCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CycleCore")
            .field("engine", &self.engine)
            .field("model_identity", &self.model_identity)
            .field("time", &self.time)
            .finish_non_exhaustive()
    }
}

impl CycleCore {
    pub fn new(engine: Engine, model: Box<dyn ErrorModel + Send>) -> Self {
        Self {
            engine,
            model_identity: model.identity(),
            model,
            switcher: Switcher::default(),
            last_cycle_s: None,
            dropped: false,
            partial: false,
            time: CompensationTime::default(),
        }
    }

    /// Start over with `engine` (before any cycle ran: a server's engine starts once the
    /// controller has reported what it holds).
    pub fn replace_engine(&mut self, engine: Engine) {
        self.engine = engine;
    }

    /// A decoded sample from a source (any order; the engine judges health per channel).
    pub fn handle_sample(&mut self, s: &Sample) {
        self.engine.handle_sample(s);
    }

    /// The sink found another value in the controller: continue from it. A refusal (a value the
    /// safety layer cannot start from) is logged and the axis holds.
    pub fn handle_reseed(&mut self, axis: Axis, held_um: f64) -> Result<(), SafetyError> {
        let r = self.engine.reseed(axis, held_um);
        if let Err(err) = &r {
            let axis = axis.name();
            tracing::error!(%err, axis, "cannot continue from the controller's value; holding");
        }
        r
    }

    /// An action from the API. Disabling ramps each axis to zero through the safety ramps
    /// (`Engine::set_enabled`); a model switch ramps out, swaps between two cycles, ramps in.
    pub fn handle_control(&mut self, c: Control) {
        match c {
            Control::SetCompensation { enabled } => {
                self.switcher.set_enabled(enabled, &mut self.engine);
            }
            Control::SwitchModel(swap) => self.switcher.request(*swap, &mut self.engine),
        }
    }

    /// Run one cycle at `now_s`: a pending model swap first (between two cycles), then the engine.
    /// Returns the outputs (axis, correction µm) in configured axis order. Allocates nothing in
    /// steady state.
    pub fn poll_cycle(&mut self, now_s: f64) -> &[(Axis, f64)] {
        if let Some(swap) = self.switcher.poll(&mut self.engine) {
            self.model = swap.model;
            self.model_identity = Some(swap.identity);
        }
        self.engine.cycle_in_place(now_s, self.model.as_mut());
        self.account(now_s);
        self.engine.last_outputs()
    }

    fn account(&mut self, now_s: f64) {
        let t = &mut self.time;
        let since = self.last_cycle_s.map_or(0.0, |s| (now_s - s).max(0.0));
        let dropped = self.engine.compensation_dropped();
        if self.dropped {
            t.not_compensating_s += since;
        }
        if dropped && !self.dropped {
            t.not_compensating_episodes += 1;
        }
        self.dropped = dropped;
        let partial = self.engine.compensation_partial();
        if self.partial {
            t.partial_s += since;
        }
        if partial && !self.partial {
            t.partial_episodes += 1;
        }
        self.partial = partial;
        self.last_cycle_s = Some(now_s);
        t.cycles += 1;
    }

    /// The outputs of the last cycle (axis, correction µm).
    pub fn outputs(&self) -> &[(Axis, f64)] {
        self.engine.last_outputs()
    }

    pub fn engine(&self) -> &Engine {
        &self.engine
    }

    /// The engine's snapshot with the running model's identity (allocates: at most every
    /// `cycle::STATUS_PERIOD_S` on the runtime).
    pub fn snapshot(&self) -> StatusSnapshot {
        let mut snap = self.engine.snapshot();
        snap.model.clone_from(&self.model_identity);
        snap
    }

    pub fn compensation_time(&self) -> CompensationTime {
        self.time
    }
}
