//! The runtime's sans-IO core: samples in → health → state (positions, velocities, direction latch,
//! slow channels latched at the thermal period) → model (blends F/R by the latch weight) →
//! correction = −error → safety →
//! per-axis outputs and a status snapshot. No sockets, no clock: the async shell (`run.rs`) feeds
//! samples and time.
//!
//! Signs: the model returns errors (actual − nominal, µm); the engine outputs corrections (= −error).
//! Channels whose name starts with `T_` are slow (temperatures): their value is latched every
//! `thermal_period_s` so the thermal terms change in steps of that period, and the safety dosing cap
//! spreads each step over cycles (Spaan Ch6: 60 s tables, 15 ms evaluation, dosing).

use std::collections::BTreeMap;

use super::config::FieldConfig;
use super::direction::{Direction, DirectionLatch};
use super::health::{ChannelLimits, ChannelMonitor, ChannelStatus, FaultKind, FaultLog};
use super::recovery::NeighbourEstimate;
use super::safety::{AxisSafety, Input, Mode, SafetyError};
use super::status::{AxisStatus, StatusSnapshot};
use crate::bus::{Health, Sample};

/// The machine state the model sees.
#[derive(Clone, Debug, Default)]
pub struct MachineState {
    /// Axis positions, mm, by axis name (`x`).
    pub positions_mm: BTreeMap<String, f64>,
    /// Axis velocities, mm/s, by axis name.
    pub velocities_mm_per_s: BTreeMap<String, f64>,
    /// Every usable channel value by channel name (slow ones latched), channel units.
    pub channels: BTreeMap<String, f64>,
    /// Per axis, the forward weight of the direction latch: 1 forward, 0 reverse, ½ unknown, in
    /// between while a reversal is being blended (sin² over `switch_time_s`). The model blends its
    /// forward/reverse tables with it: e = w·e_forward + (1 − w)·e_reverse.
    pub weight_forward: BTreeMap<String, f64>,
    /// Time of this cycle, s (steps thermal lags in the model).
    pub t_s: f64,
}

/// One error term's contribution along one machine axis, µm (actual − nominal), already blended
/// for direction with [`MachineState::weight_forward`].
#[derive(Clone, Debug, PartialEq)]
pub struct TermError {
    pub term: String,
    pub error_um: f64,
}

/// What the gateway needs from a model (`model_adapter.rs` implements it for `src/models`).
pub trait ErrorModel {
    /// Channels the model reads (besides axis positions). Missing ones make the inputs stale.
    fn required_channels(&self) -> Vec<String>;
    /// Push, per machine axis, its error terms at `state` into `out` (cleared by the caller).
    /// `&mut self`: models keep evaluation state (thermal lags, scratch buffers).
    fn axis_errors(
        &mut self,
        state: &MachineState,
        out: &mut Vec<(String, Vec<TermError>)>,
    ) -> Result<(), String>;
}

struct AxisRuntime {
    name: String,
    position_channel: String,
    latch: DirectionLatch,
    safety: AxisSafety,
    last_pos: Option<(f64, f64)>,
    target_um: Option<f64>,
    terms: Vec<(String, f64)>,
}

pub struct Engine {
    axes: Vec<AxisRuntime>,
    monitors: BTreeMap<String, ChannelMonitor>,
    statuses: BTreeMap<String, ChannelStatus>,
    recoveries: Vec<NeighbourEstimate>,
    thermal_period_s: f64,
    last_slow_latch_s: Option<f64>,
    slow_latched: BTreeMap<String, f64>,
    faults: FaultLog,
    enabled: bool,
    state: MachineState,
    errors: Vec<(String, Vec<TermError>)>,
    model_error: Option<String>,
    cycles: u64,
    now_s: f64,
}

/// Limits for channels seen on a bus but not configured: anything finite, stale after 1 s.
fn default_limits() -> ChannelLimits {
    ChannelLimits {
        min: -1e12,
        max: 1e12,
        stale_after_s: 1.0,
        max_rate_per_s: None,
        stuck_after_s: None,
    }
}

fn is_slow(channel: &str) -> bool {
    channel.starts_with("T_")
}

impl Engine {
    /// `initial_outputs_um`: what each axis' sink holds now (origin-shift registers read at start;
    /// 0 for quadrature), so the first outputs continue from there.
    pub fn new(
        cfg: &FieldConfig,
        initial_outputs_um: &BTreeMap<String, f64>,
    ) -> Result<Self, SafetyError> {
        let mut axes = Vec::new();
        for a in &cfg.axes {
            let initial = initial_outputs_um.get(&a.name).copied().unwrap_or(0.0);
            axes.push(AxisRuntime {
                name: a.name.clone(),
                position_channel: a.position_channel.clone(),
                latch: DirectionLatch::new(cfg.direction),
                safety: AxisSafety::new(cfg.safety_for(&a.name), initial)?,
                last_pos: None,
                target_um: None,
                terms: Vec::new(),
            });
        }
        let monitors = cfg
            .channels
            .iter()
            .map(|c| (c.name.clone(), ChannelMonitor::new(c.limits())))
            .collect();
        Ok(Self {
            axes,
            monitors,
            statuses: BTreeMap::new(),
            recoveries: cfg.recoveries.clone(),
            thermal_period_s: cfg.gateway.thermal_period_s,
            last_slow_latch_s: None,
            slow_latched: BTreeMap::new(),
            faults: FaultLog::default(),
            enabled: cfg.gateway.enabled,
            state: MachineState::default(),
            errors: Vec::new(),
            model_error: None,
            cycles: 0,
            now_s: 0.0,
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

    /// Take one decoded sample (any order; health is judged per channel).
    pub fn ingest(&mut self, s: &Sample) {
        // get_mut first: the hot path (a known channel) must not allocate a key.
        if let Some(m) = self.monitors.get_mut(&s.channel) {
            m.observe(s);
        } else {
            let mut m = ChannelMonitor::new(default_limits());
            m.observe(s);
            self.monitors.insert(s.channel.clone(), m);
        }
    }

    /// Run one cycle at `now_s`; returns the per-axis outputs (µm, in configured axis order).
    pub fn cycle(&mut self, now_s: f64, model: &mut dyn ErrorModel) -> Vec<(String, f64)> {
        self.now_s = now_s;
        self.cycles += 1;
        // 1. Health of every channel, with fault transitions logged once.
        self.statuses.clear();
        for (name, m) in &self.monitors {
            let st = m.status(now_s);
            self.faults.update(name, &st.faults, now_s);
            self.statuses.insert(name.clone(), st);
        }
        // 2. Substitute failed channels from their neighbours (Ni's recovery).
        for r in &self.recoveries {
            let failed = self
                .statuses
                .get(&r.target)
                .is_none_or(|s| s.health != Health::Ok);
            if !failed {
                continue;
            }
            let neighbours: Option<Vec<f64>> = r
                .neighbours
                .iter()
                .map(|n| {
                    self.statuses
                        .get(n)
                        .filter(|s| s.health == Health::Ok)
                        .and_then(|s| s.value)
                })
                .collect();
            if let Some(vals) = neighbours
                && let Ok(est) = r.estimate(&vals)
            {
                let st = self
                    .statuses
                    .entry(r.target.clone())
                    .or_insert(ChannelStatus {
                        value: None,
                        health: Health::Stale,
                        faults: vec![FaultKind::Stale],
                        substituted: false,
                    });
                st.value = Some(est);
                st.substituted = true;
            }
        }
        // 3. State: usable channel values; slow channels latched at the thermal period.
        let latch_slow = self
            .last_slow_latch_s
            .is_none_or(|t| now_s - t >= self.thermal_period_s);
        if latch_slow {
            self.last_slow_latch_s = Some(now_s);
        }
        self.state.channels.clear();
        for (name, st) in &self.statuses {
            let usable = if st.health == Health::Ok || st.substituted {
                st.value
            } else {
                None
            };
            if is_slow(name) {
                if latch_slow {
                    match usable {
                        Some(v) => self.slow_latched.insert(name.clone(), v),
                        None => self.slow_latched.remove(name),
                    };
                } else if usable.is_none() {
                    // A slow channel that fails between latches is dropped at once, not at the next latch.
                    self.slow_latched.remove(name);
                }
                if let Some(v) = self.slow_latched.get(name) {
                    self.state.channels.insert(name.clone(), *v);
                }
            } else if let Some(v) = usable {
                self.state.channels.insert(name.clone(), v);
            }
        }
        let mut positions_ok = Vec::with_capacity(self.axes.len());
        for a in &mut self.axes {
            let pos = self.state.channels.get(&a.position_channel).copied();
            if let Some(p) = pos {
                if let Some((t0, p0)) = a.last_pos
                    && now_s > t0
                {
                    self.state
                        .velocities_mm_per_s
                        .insert(a.name.clone(), (p - p0) / (now_s - t0));
                }
                a.last_pos = Some((now_s, p));
                a.latch.update(p, now_s);
                self.state.positions_mm.insert(a.name.clone(), p);
                self.state
                    .weight_forward
                    .insert(a.name.clone(), a.latch.weight_forward());
            } else {
                self.state.positions_mm.remove(&a.name);
                self.state.velocities_mm_per_s.remove(&a.name);
            }
            positions_ok.push(pos.is_some());
        }
        self.state.t_s = now_s;
        // 4. Model.
        let missing: Vec<String> = model
            .required_channels()
            .into_iter()
            .filter(|c| !self.state.channels.contains_key(c))
            .collect();
        self.errors.clear();
        let model_result = if missing.is_empty() && positions_ok.iter().all(|ok| *ok) {
            model
                .axis_errors(&self.state, &mut self.errors)
                .map(|()| true)
        } else {
            Ok(false)
        };
        let model_fault = model_result.as_ref().err().cloned();
        self.faults.update(
            "model",
            if model_fault.is_some() {
                &[FaultKind::Decode]
            } else {
                &[]
            },
            now_s,
        );
        if model_fault != self.model_error
            && let Some(e) = &model_fault
        {
            tracing::warn!(error = %e, "model evaluation failed");
        }
        self.model_error = model_fault;
        let evaluated = matches!(model_result, Ok(true));
        // 5. Correction = −error, blended by direction; then safety.
        let mut out = Vec::with_capacity(self.axes.len());
        for (i, a) in self.axes.iter_mut().enumerate() {
            let input = if self.model_error.is_some() {
                a.target_um = None;
                Input::Fault
            } else if !positions_ok[i] || !evaluated {
                a.target_um = None;
                Input::Stale
            } else {
                a.terms.clear();
                let mut total = 0.0;
                if let Some((_, terms)) = self.errors.iter().find(|(ax, _)| *ax == a.name) {
                    for t in terms {
                        let corr = -t.error_um;
                        total += corr;
                        a.terms.push((t.term.clone(), corr));
                    }
                }
                a.target_um = Some(total);
                Input::Fresh(total)
            };
            out.push((a.name.clone(), a.safety.step(now_s, self.enabled, input)));
        }
        out
    }

    /// What `retrocomp status` and `/metrics` show.
    pub fn snapshot(&self) -> StatusSnapshot {
        StatusSnapshot {
            t_s: self.now_s,
            cycles: self.cycles,
            enabled: self.enabled,
            axes: self
                .axes
                .iter()
                .map(|a| AxisStatus {
                    axis: a.name.clone(),
                    position_mm: self.state.positions_mm.get(&a.name).copied(),
                    direction: a.latch.direction(),
                    weight_forward: a.latch.weight_forward(),
                    target_um: a.target_um,
                    applied_um: a.safety.output_um(),
                    mode: a.safety.mode(),
                    terms_um: a.terms.iter().cloned().collect(),
                })
                .collect(),
            channels: self.statuses.clone(),
            active_faults: self
                .faults
                .active()
                .map(|(s, k, t)| (s.to_string(), k, t))
                .collect(),
            model_error: self.model_error.clone(),
            sink: None,
        }
    }

    /// The sink found a different value in the controller than we last wrote (controller restarted,
    /// operator cleared it): continue from that value instead of jumping back to ours.
    pub fn reseed(&mut self, axis: &str, held_um: f64) -> Result<(), SafetyError> {
        if let Some(a) = self.axes.iter_mut().find(|a| a.name == axis) {
            let cfg = *a.safety.config();
            a.safety = AxisSafety::new(cfg, held_um)?;
            tracing::warn!(
                axis,
                held_um,
                "controller holds a different value: continuing from it"
            );
        }
        Ok(())
    }

    /// Current outputs without running a cycle.
    pub fn outputs(&self) -> Vec<(String, f64)> {
        self.axes
            .iter()
            .map(|a| (a.name.clone(), a.safety.output_um()))
            .collect()
    }

    pub fn axis_mode(&self, axis: &str) -> Option<Mode> {
        self.axes
            .iter()
            .find(|a| a.name == axis)
            .map(|a| a.safety.mode())
    }

    pub fn axis_direction(&self, axis: &str) -> Option<Direction> {
        self.axes
            .iter()
            .find(|a| a.name == axis)
            .map(|a| a.latch.direction())
    }
}
