//! The runtime's sans-IO core: samples in → health → state (positions, velocities, direction latch,
//! slow channels latched at the thermal period) → model (blends F/R by the latch weight) →
//! correction = −error → safety →
//! per-axis outputs and a status snapshot. No sockets, no clock: the async shell (`run.rs`) feeds
//! samples and time.
//!
//! Identities: axes are [`Axis`], channels [`ChannelId`] (resolved from their names when the config
//! loads, `retrocomp_bus::ChannelId`). No name is looked up and no `String` built on the per-sample or
//! per-cycle path; names appear only in [`Engine::snapshot`] (status, metrics) and in the log lines
//! of a fault that starts or clears (fault sources are typed: [`FaultSource`]).
//!
//! Signs: the model returns errors (actual − nominal, µm); the engine outputs corrections (= −error).
//! Temperature channels (`T_<name>_C`, `ChannelKind::TemperatureC`) are slow: their value is
//! latched every `thermal_period_s` so the thermal terms change in steps of that period, and the
//! safety dosing cap spreads each step over cycles (Spaan Ch6: 60 s tables, 15 ms evaluation,
//! dosing).

pub(crate) mod at_point;
pub(crate) mod direction;
pub(crate) mod error_model;
pub(crate) mod health;
pub(crate) mod model_adapter;
pub(crate) mod model_switch;
pub(crate) mod recovery;
pub(crate) mod safety;
mod slots;
mod steps;

use std::sync::Arc;

use crate::engine::direction::{DirectionConfig, DirectionLatch};
use crate::engine::health::{ChannelLimits, ChannelMonitor, FaultEvent, FaultKind, FaultLog};
use crate::engine::recovery::NeighbourEstimate;
use crate::engine::safety::{AxisSafety, Input, Mode, SafetyConfig, SafetyError};
use crate::status::{AxisStatus, StatusSnapshot};
use retrocomp_bus::fault::FaultSource;
use retrocomp_bus::{ChannelId, ChannelTable, Sample};
use retrocomp_model::Axis;
use retrocomp_model::approach::Approach;
use slots::{Channel, Slots, default_limits};

pub use crate::engine::error_model::{AxisErrors, ErrorModel, MachineState, ModelError, TermError};
pub use at_point::AtPointError;
pub use model_adapter::MachineModelAdapter;
pub use model_switch::{Catalog, ModelSwap, SwitchError};

struct AxisRuntime {
    axis: Axis,
    /// Slot of the position channel.
    position: usize,
    position_ok: bool,
    latch: DirectionLatch,
    safety: AxisSafety,
    last_pos: Option<(f64, f64)>,
    target_um: Option<f64>,
    terms: Vec<(Arc<str>, f64)>,
    /// The axis had a fresh target at least once (before that it is starting, not dropped).
    ever_tracked: bool,
}

struct Recovery {
    estimate: NeighbourEstimate,
    target: usize,
    neighbours: Vec<usize>,
    values: Vec<f64>,
}

pub struct Engine {
    /// The gateway's channels: every id the engine and its sources' samples carry was issued
    /// here (configured channels, model inputs, recovery neighbours, the decoders' channels).
    table: ChannelTable,
    axes: Vec<AxisRuntime>,
    channels: Vec<Channel>,
    /// Channel slots, by [`ChannelId::index`] and in name order (the order faults are logged in).
    slots: Slots,
    recoveries: Vec<Recovery>,
    /// The model's required channels, resolved at the first cycle, and which of them are optional
    /// (their loss drops only their terms: [`ErrorModel::optional_channels`]).
    required: Option<Vec<usize>>,
    optional: Vec<usize>,
    /// Optional model inputs no configured source delivers ([`Engine::report_undelivered`]): a
    /// `no_source` fault each, active for the whole run.
    undelivered: Vec<ChannelId>,
    /// Ids of samples this table did not issue, already logged ([`Engine::handle_sample`]).
    foreign: Vec<ChannelId>,
    /// Some optional channel was unusable at the last cycle (its terms were left out).
    partial: bool,
    thermal_period_s: f64,
    last_slow_latch_s: Option<f64>,
    faults: FaultLog,
    /// The fault edges the last cycle (or `correction_at`) logged (cleared when one starts;
    /// capacity kept).
    fault_events: Vec<FaultEvent>,
    enabled: bool,
    state: MachineState,
    errors: AxisErrors,
    model_error: Option<ModelError>,
    cycles: u64,
    now_s: f64,
    /// Per axis (configured order) the output of the last cycle, µm.
    outputs: Vec<(Axis, f64)>,
    /// The newest sample time received from any source, s (the inputs' own clock; see
    /// [`ChannelMonitor::status_judged`]).
    newest_input_s: f64,
    /// Enabled, and at least one axis that had compensated has no fresh target this cycle.
    dropped: bool,
}

// By hand: the per-axis and per-channel runtime is internal; this is what a log line needs.
impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("axes", &self.axes.len())
            .field("channels", &self.channels.len())
            .field("enabled", &self.enabled)
            .field("partial", &self.partial)
            .field("cycles", &self.cycles)
            .field("now_s", &self.now_s)
            .field("model_error", &self.model_error)
            .finish_non_exhaustive()
    }
}

/// What the engine is built from (`FieldConfig::engine_config`): the part of the field file about compensation (channels and
/// their limits, axes with their position channel and safety, recoveries, direction latch, thermal
/// period), with names resolved to [`Axis`] and [`ChannelId`]. Transports and sinks are not in it.
#[derive(Clone, Debug, PartialEq)]
pub struct EngineConfig {
    pub axes: Vec<EngineAxis>,
    pub channels: Vec<(ChannelId, ChannelLimits)>,
    pub recoveries: Vec<NeighbourEstimate>,
    pub direction: DirectionConfig,
    /// Slow channels (temperatures, `T_<name>_C`) are latched at this period, s.
    pub thermal_period_s: f64,
    /// Compensation enabled at start.
    pub enabled: bool,
}

/// One driven axis of an [`EngineConfig`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EngineAxis {
    pub axis: Axis,
    /// The channel carrying its position, mm.
    pub position: ChannelId,
    /// Its safety settings (the axis' override or the global `[safety]`).
    pub safety: SafetyConfig,
}

impl Engine {
    /// The engine of `cfg`, whose ids `table` issued (the engine keeps it: model inputs and
    /// recovery neighbours are resolved in it too); `initial_outputs_um`: what each axis' sink
    /// holds now, so the first outputs continue from there (axes not given start at 0). Panics
    /// on an id of `cfg` that `table` did not issue (build both with
    /// [`FieldConfig::engine`](crate::config::FieldConfig::engine)).
    pub fn from_config(
        cfg: &EngineConfig,
        mut table: ChannelTable,
        initial_outputs_um: &[(Axis, f64)],
    ) -> Result<Self, SafetyError> {
        let mut channels = Vec::new();
        let mut slots = Slots::default();
        for (id, limits) in &cfg.channels {
            let slot = slots.get_or_add(&mut channels, &table, *id);
            channels[slot].monitor = Some(ChannelMonitor::new(limits.clone()));
        }
        let mut axes = Vec::new();
        for a in &cfg.axes {
            let initial = initial_outputs_um
                .iter()
                .find(|(x, _)| *x == a.axis)
                .map_or(0.0, |(_, v)| *v);
            axes.push(AxisRuntime {
                axis: a.axis,
                position: slots.get_or_add(&mut channels, &table, a.position),
                position_ok: false,
                latch: DirectionLatch::new(cfg.direction),
                safety: AxisSafety::new(a.safety, initial)?,
                last_pos: None,
                target_um: None,
                terms: Vec::new(),
                ever_tracked: false,
            });
        }
        let mut slot_of = |name: &str| {
            let id = table.resolve(name);
            slots.get_or_add(&mut channels, &table, id)
        };
        let recoveries = cfg
            .recoveries
            .iter()
            .map(|r| Recovery {
                target: slot_of(&r.target),
                neighbours: r.neighbours.iter().map(|n| slot_of(n)).collect(),
                values: Vec::with_capacity(r.neighbours.len()),
                estimate: r.clone(),
            })
            .collect();
        let outputs = axes
            .iter()
            .map(|a| (a.axis, a.safety.output_um()))
            .collect();
        Ok(Self {
            table,
            errors: AxisErrors::with_axes(axes.iter().map(|a| a.axis)),
            axes,
            channels,
            slots,
            recoveries,
            required: None,
            optional: Vec::new(),
            undelivered: Vec::new(),
            foreign: Vec::new(),
            partial: false,
            thermal_period_s: cfg.thermal_period_s,
            last_slow_latch_s: None,
            faults: FaultLog::default(),
            fault_events: Vec::new(),
            enabled: cfg.enabled,
            state: MachineState::default(),
            model_error: None,
            cycles: 0,
            now_s: 0.0,
            outputs,
            newest_input_s: f64::NEG_INFINITY,
            dropped: false,
        })
    }

    pub fn set_enabled(&mut self, enabled: bool) {
        if enabled != self.enabled {
            tracing::info!(
                enabled,
                "compensation {}",
                if enabled { "enabled" } else { "disabled" }
            );
        }
        self.enabled = enabled;
    }

    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// True when every axis' last output is exactly 0 µm (a model switch waits for it).
    pub fn outputs_at_zero(&self) -> bool {
        self.outputs.iter().all(|(_, v)| *v == 0.0)
    }

    /// The caller replaced the model (`model_switch.rs`): its channels are resolved again at the
    /// next cycle and its terms replace the old ones.
    pub fn model_replaced(&mut self) {
        self.required = None;
        for a in &mut self.axes {
            a.terms.clear();
        }
    }

    /// Take one decoded sample (any order; health is judged per channel). A known channel costs
    /// one index and no allocation. A sample whose id this engine's table did not issue (a
    /// decoder built on another table: a wiring bug) is dropped with one ERROR line per id, not
    /// judged under another channel's name.
    pub fn handle_sample(&mut self, s: &Sample) {
        if s.channel.index() >= self.table.len() {
            self.reject_foreign(s.channel);
            return;
        }
        if s.t_s > self.newest_input_s {
            self.newest_input_s = s.t_s;
        }
        let slot = self
            .slots
            .get_or_add(&mut self.channels, &self.table, s.channel);
        self.channels[slot]
            .monitor
            .get_or_insert_with(|| ChannelMonitor::new(default_limits()))
            .observe(s);
    }

    /// Run one cycle at `now_s`; returns the per-axis outputs (µm, in configured axis order) as a
    /// new vector, for callers that hand them to another task. [`Engine::cycle_in_place`] is the
    /// same without the copy.
    pub fn cycle(&mut self, now_s: f64, model: &mut dyn ErrorModel) -> Vec<(Axis, f64)> {
        self.cycle_in_place(now_s, model).to_vec()
    }

    /// Run one cycle at `now_s`; the per-axis outputs (µm, in configured axis order) are borrowed
    /// from the engine. In steady state (same channels healthy, model terms unchanged) this
    /// allocates nothing: channels are ids resolved at start, buffers are reused.
    /// Kept as one function over the ~100-line rule: its five numbered steps are the cycle's
    /// order (health, substitution, state, model, correction and safety last), read top to bottom.
    pub fn cycle_in_place(&mut self, now_s: f64, model: &mut dyn ErrorModel) -> &[(Axis, f64)] {
        self.now_s = now_s;
        self.cycles += 1;
        self.fault_events.clear();
        // 1.–3. Health (faults logged once), substitution, usable values (slow ones latched).
        self.judge_channels(now_s);
        // 3. State: positions, velocities and direction latch from the position channels.
        for a in &mut self.axes {
            let pos = self.channels[a.position].value;
            let i = a.axis.index();
            if let Some(p) = pos {
                if let Some((t0, p0)) = a.last_pos
                    && now_s > t0
                {
                    self.state.velocities_mm_per_s[i] = Some((p - p0) / (now_s - t0));
                }
                a.last_pos = Some((now_s, p));
                a.latch.update(p, now_s);
                self.state.positions_mm[i] = Some(p);
                self.state.weight_forward[i] = a.latch.weight_forward();
            } else {
                self.state.positions_mm[i] = None;
                self.state.velocities_mm_per_s[i] = None;
            }
            a.position_ok = pos.is_some();
        }
        self.state.t_s = now_s;
        // 4. Model, on its inputs in its order.
        let inputs_ok = self.model_inputs(model) && self.axes.iter().all(|a| a.position_ok);
        // An unusable optional channel leaves its terms out (the model sees it missing). Either
        // edge of that changes the target's make-up: every axis ramps to the new target.
        let partial = inputs_ok && self.optional_missing();
        if partial != self.partial {
            for a in &mut self.axes {
                a.safety.ramp_to_next_target();
            }
            self.partial = partial;
        }
        let evaluated = self.evaluate_model(model, inputs_ok, now_s);
        // 5. Correction = −error, blended by direction; then safety.
        for (a, out) in self.axes.iter_mut().zip(&mut self.outputs) {
            let input = if self.model_error.is_some() {
                a.target_um = None;
                Input::Fault
            } else if !a.position_ok || !evaluated {
                a.target_um = None;
                Input::Stale
            } else {
                Input::Fresh(a.take_target(&self.errors))
            };
            out.1 = a.safety.step(now_s, self.enabled, input);
        }
        self.report_drops(now_s);
        &self.outputs
    }

    /// "Compensation dropped" per axis: enabled, the axis had compensated, and now has no fresh
    /// target (stale inputs → holding, then ramping out; a model fault). A fault of source
    /// `compensation.<axis>` (kind `stale`, or `decode` for a model fault), logged at start and
    /// clear like every fault. Allocates only while such a fault is active.
    fn report_drops(&mut self, now_s: f64) {
        // A channel with limits reports it with its health (step 1); one without, here. Steady
        // state: an unchanged active fault is not logged again and allocates nothing.
        for id in &self.undelivered {
            let monitored = self
                .slots
                .by_id
                .get(id.index())
                .and_then(|&slot| self.channels.get(slot))
                .is_some_and(|c| c.monitor.is_some());
            if !monitored {
                self.fault_events.extend(self.faults.update(
                    &FaultSource::Channel(*id, self.table.shared_name(*id)),
                    &[FaultKind::NoSource],
                    now_s,
                ));
            }
        }
        let mut any = false;
        for a in &mut self.axes {
            let fresh = a.target_um.is_some();
            a.ever_tracked |= fresh && self.enabled;
            let kind = if !self.enabled || fresh || !a.ever_tracked {
                None
            } else if self.model_error.is_some() {
                Some(FaultKind::Decode)
            } else {
                Some(FaultKind::Stale)
            };
            any |= kind.is_some();
            let kinds = kind.as_slice();
            self.fault_events.extend(self.faults.update(
                &FaultSource::Compensation(a.axis),
                kinds,
                now_s,
            ));
            // Compensating, but without the terms of a lost auxiliary input.
            let partial = self.enabled && fresh && self.partial;
            let kinds: &[FaultKind] = if partial { &[FaultKind::Stale] } else { &[] };
            self.fault_events.extend(self.faults.update(
                &FaultSource::CompensationPartial(a.axis),
                kinds,
                now_s,
            ));
        }
        self.dropped = any;
    }

    /// Optional model inputs that no configured source delivers (the field check's list): each is
    /// a `no_source` fault on its channel from the next cycle on, for as long as the box runs, so a
    /// model that leaves its load terms out says which input is missing.
    pub fn report_undelivered(&mut self, channels: &[Arc<str>]) {
        self.undelivered = channels.iter().map(|n| self.table.resolve(n)).collect();
    }

    /// A sample of an id beyond the table: logged once per id (setup bug, never per sample).
    fn reject_foreign(&mut self, id: ChannelId) {
        if !self.foreign.contains(&id) {
            tracing::error!(
                index = id.index(),
                known = self.table.len(),
                "a sample's channel id is not in the engine's channel table: dropped"
            );
            self.foreign.push(id);
        }
    }

    /// The slot of the channel `name`, resolved in the engine's table and added when new (setup:
    /// the model's inputs at the first cycle and after a model switch).
    fn slot_of(&mut self, name: &str) -> usize {
        let id = self.table.resolve(name);
        self.slots.get_or_add(&mut self.channels, &self.table, id)
    }

    /// The gateway's channel table (names of the ids in samples, status and faults).
    pub fn channels(&self) -> &ChannelTable {
        &self.table
    }

    /// The table lent to a decoder built after the engine, so that the ids in its samples are
    /// this engine's (the table is append-only: adding a name changes no existing id).
    pub fn channels_mut(&mut self) -> &mut ChannelTable {
        &mut self.table
    }

    /// True when, this cycle, compensation is enabled and tracking without the terms of an unusable
    /// optional channel ([`ErrorModel::optional_channels`]; fault `compensation.<axis>.partial`).
    pub fn compensation_partial(&self) -> bool {
        self.enabled && self.partial && self.axes.iter().any(|a| a.target_um.is_some())
    }

    /// True when, this cycle, compensation is enabled but some axis that had compensated is not
    /// tracking its target (see `report_drops`).
    pub fn compensation_dropped(&self) -> bool {
        self.dropped
    }

    /// What `retrocomp status` and `/metrics` show.
    /// Built on demand (it allocates: names, term lists); the cycle loop publishes one at most
    /// every `cycle::STATUS_PERIOD_S`.
    pub fn snapshot(&self) -> StatusSnapshot {
        StatusSnapshot {
            t_s: self.now_s,
            cycles: self.cycles,
            enabled: self.enabled,
            axes: self
                .axes
                .iter()
                .map(|a| AxisStatus {
                    axis: a.axis.to_string(),
                    position_mm: self.state.position_mm(a.axis),
                    direction: a.latch.direction(),
                    weight_forward: a.latch.weight_forward(),
                    target_um: a.target_um,
                    applied_um: a.safety.output_um(),
                    mode: a.safety.mode(),
                    terms_um: a.terms.iter().map(|(n, v)| (n.to_string(), *v)).collect(),
                    clamp_hits: a.safety.hits().0,
                    cap_hits: a.safety.hits().1,
                })
                .collect(),
            channels: self
                .slots
                .by_name
                .iter()
                .filter_map(|&slot| {
                    let c = &self.channels[slot];
                    Some((c.name.to_string(), c.status.clone()?))
                })
                .collect(),
            active_faults: self.faults.active_by_name(),
            model_error: self.model_error.as_ref().map(ToString::to_string),
            sink: None,
            sources: Vec::new(),
            model: None,
            telemetry: None,
            timing: Default::default(),
        }
    }

    /// The sink found a different value in the controller than we last wrote (controller restarted,
    /// operator cleared it): continue from that value instead of jumping back to ours.
    pub fn reseed(&mut self, axis: Axis, held_um: f64) -> Result<(), SafetyError> {
        if let Some(a) = self.axes.iter_mut().find(|a| a.axis == axis) {
            a.safety.reseed(held_um)?;
            tracing::warn!(
                axis = axis.name(),
                held_um,
                "controller holds a different value: continuing from it"
            );
        }
        Ok(())
    }

    /// The fault edges (started / cleared, once each) the last cycle logged, in the order it
    /// logged them: what the runtime's log says, for a driver without one (hil-sim's harness).
    pub fn fault_events(&self) -> &[FaultEvent] {
        &self.fault_events
    }

    /// The outputs as of the last cycle (before the first: the start values), borrowed.
    pub fn last_outputs(&self) -> &[(Axis, f64)] {
        &self.outputs
    }

    /// Current outputs without running a cycle.
    pub fn outputs(&self) -> Vec<(Axis, f64)> {
        self.axes
            .iter()
            .map(|a| (a.axis, a.safety.output_um()))
            .collect()
    }

    pub fn axis_mode(&self, axis: Axis) -> Option<Mode> {
        self.axes
            .iter()
            .find(|a| a.axis == axis)
            .map(|a| a.safety.mode())
    }

    /// The latched direction of approach of `axis` (None: not latched yet, or not driven).
    pub fn axis_direction(&self, axis: Axis) -> Option<Approach> {
        self.axes
            .iter()
            .find(|a| a.axis == axis)
            .and_then(|a| a.latch.direction())
    }
}
