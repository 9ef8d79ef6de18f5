//! retrocomp's model crate: the machine model and the volumetric error engine, and the vocabulary
//! every other crate shares ([`units`], [`approach`], the [`recording`] CSV and its [`decimal`]
//! writer, [`ConfigError`] for file:line:key errors, [`error`]'s cause chain). No async runtime.
//!
//! The machine model:
//!
//! A [`MachineModel`] is read from TOML (schema in `docs/model.md`), validated, converted to internal
//! units once, and evaluated without allocating:
//!
//! * **Sign**: every result is error = actual − nominal (ISO 230-2) of the tool tip relative to the
//!   workpiece, in µm, in machine X/Y/Z. Correction = −error: the axis command K gets −e_K.
//! * **Machine coordinates** are the tool's position relative to the workpiece (as an NC program
//!   states it): a workpiece-side carriage (a table) moves opposite to its coordinate.
//! * **Components** are ISO 230-1 error motions (EXK…ECK of axis K, µm and µrad) stated as the tool-
//!   relative-to-workpiece error that axis causes — what a laser between tool and workpiece reads —
//!   so a one-term model `EXX = +c` gives `ex = +c` on every axis and either branch. Rotations act
//!   about the carriage's reference point with the Abbe arm given by the chain (`kinematics.rs`).
//! * **Squareness** EC0Y/EB0Z/EA0Z tilts one axis' motion direction (`on_axis`, default the axis ISO
//!   rotates: Y for EC0Y, Z for EB0Z/EA0Z). Positive EC0Y: ex = −S·y; EB0Z: ex = +S·z (on x: ez = +S·x);
//!   EA0Z: ey = −S·z (on y: ez = −S·y) — right-hand rotations of the named axis' direction.
//! * **Chain** workpiece → tool, `F` marks the frame: lathe `Z X` (no F = F first), T-base lathe
//!   `Z F X`, mills `X F Y Z` / `F X Y Z`.
//! * **Direction** `dir` +1/−1 picks a bidirectional table's forward/reverse values, 0 their mean.
//!   Latching and ramping a reversal is the gateway's job; the model is a pure function of the input
//!   plus the thermal lag state.
//!
//! Every numeric conversion that could truncate, wrap or lose a sign is a `try_from`, or an `as`
//! after a clamp or check with its reason beside it (these lints are errors in CI).
#![warn(
    unreachable_pub,
    unnameable_types,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]
#![cfg_attr(
    test,
    allow(
        clippy::float_cmp,
        reason = "tests assert values that are exact in binary or parsed from the same decimal text"
    )
)]

// The vocabulary other crates share, by namespace (one path each): `approach::Approach`,
// `recording::Recording`, `lag::series`, … The model's own types are re-exported at the root.
pub mod approach;
pub mod decimal;
pub mod error;
pub mod kinematics;
pub mod lag;
pub mod recording;
pub mod units;

mod config_issue;
mod function;
mod lookup;
mod names;
mod parse;
mod parse_terms;
mod plan;
mod reference;
mod spec;
mod thermal;
mod toml_reader;
mod write;

use std::path::Path;

pub use config_issue::{ConfigError, ConfigIssue};
pub use function::{ErrorFunction, Interpolation, Table};
pub use names::{Axis, ComponentId, Motion, Squareness, parse_component};
pub use spec::{
    AxisSpec, Branch, ComponentSpec, ForceSpec, LagState, LoadKind, LoadSpec, ModelSpec,
    SensorSpec, SquarenessSpec, StrainSource, ThermalKind, ThermalSpec, ToolSpec,
};
pub use thermal::ThermalState;

use plan::Plan;
use reference::Compiled;

/// A loaded machine model. Cheap to share (`Clone + Send + Sync`); evaluation state lives in
/// [`ModelState`], so one model can serve many threads.
#[derive(Clone, Debug)]
pub struct MachineModel {
    spec: ModelSpec,
    compiled: Compiled,
    plan: Plan,
}

/// One evaluation's inputs. Channel vectors are indexed like the model's channel lists.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelInput {
    /// x, y, z axis positions in mm (machine coordinates); absent axes are ignored.
    pub pos_mm: [f64; 3],
    /// Approach direction per axis: +1, −1, or 0 = unknown (mean of forward and reverse).
    pub dir: [i8; 3],
    /// Time, s; steps the thermal lags. Must not decrease.
    pub t_s: f64,
    /// By [`MachineModel::temperature_sensors`] index, °C.
    pub temps_c: Vec<f64>,
    /// By [`MachineModel::force_channels`] index, N.
    pub forces_n: Vec<f64>,
    /// By [`MachineModel::strain_channels`] index, µm/m.
    pub strains_ue: Vec<f64>,
    /// Tool length along the model's `tool_axis` (replaces that component of the tool offset), mm.
    pub tool_mm: Option<f64>,
    /// Index into the model's tools (0 = first).
    pub tool: usize,
}

/// What an evaluation had to assume. Outputs stay finite whatever the flags say.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EvalFlags {
    /// Per machine axis x/y/z: a position was outside a table or function range and was clamped to
    /// the end value.
    pub clamped: [bool; 3],
    /// Per machine axis: outside the configured travel.
    pub outside_travel: [bool; 3],
    /// A non-finite position, time or tool length: all outputs are zero.
    pub invalid_input: bool,
    /// A temperature, force or strain was missing or non-finite (held / taken as zero), or the tool
    /// index did not exist (first tool used).
    pub missing_input: bool,
    /// `t_s` went backwards: lag states were held.
    pub time_backwards: bool,
}

impl EvalFlags {
    pub fn any(&self) -> bool {
        self.clamped.iter().any(|&b| b)
            || self.outside_travel.iter().any(|&b| b)
            || self.invalid_input
            || self.missing_input
            || self.time_backwards
    }
}

/// An evaluation's result: total and per-term tool-tip errors, µm, actual − nominal.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorBreakdown {
    pub total_um: [f64; 3],
    /// By term id ([`MachineModel::term_names`]); Σ terms_um = total_um.
    pub terms_um: Vec<[f64; 3]>,
    pub flags: EvalFlags,
}

impl ErrorBreakdown {
    /// Zero everything; sizes `terms_um` (allocates only when it grows).
    pub fn reset(&mut self, n_terms: usize) {
        self.total_um = [0.0; 3];
        self.terms_um.clear();
        self.terms_um.resize(n_terms, [0.0; 3]);
        self.flags = EvalFlags::default();
    }
}

/// How [`MachineModel::new_state_at`] started the lags.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LagStart {
    /// The model stores no `[lag_state]`: every lag starts at its first reading.
    FirstReading,
    /// The stored states are of a time not before the recording's first row: not used.
    StoredNotBefore { stored_t_s: f64 },
    /// `sensors` lags continue from the states stored at `stored_t_s`.
    Resumed { stored_t_s: f64, sensors: usize },
}

/// Evaluation state: thermal lags and scratch space.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelState {
    pub thermal: ThermalState,
    forces_n: Vec<f64>,
}

impl MachineModel {
    /// Read and validate a model file. Errors name the file, line, key and what was expected.
    pub fn from_toml_path(path: &Path) -> Result<Self, ConfigError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path)
            .map_err(|e| ConfigError::single(&origin, "", format!("cannot read: {e}")))?;
        Self::from_toml_str(&text, &origin)
    }

    /// Read and validate model text; `origin` names it in messages.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self, ConfigError> {
        Ok(Self::from_spec(parse::parse_model(text, origin)?))
    }

    /// Build from a spec (e.g. one edited by a fitting tool). The spec must satisfy what the parser
    /// checks; `to_toml_string` + `from_toml_str` is the checked path.
    pub fn from_spec(spec: ModelSpec) -> Self {
        let compiled = Compiled::new(&spec);
        let plan = Plan::new(&spec, &compiled);
        MachineModel {
            spec,
            compiled,
            plan,
        }
    }

    pub fn spec(&self) -> &ModelSpec {
        &self.spec
    }

    /// Whether any term depends on an axis position or direction (components, squareness,
    /// position-scaled thermal terms, load terms). A model without one — e.g. a thermal-only
    /// model found by `diagnose` — can be evaluated over a recording with no axis columns.
    pub fn is_position_dependent(&self) -> bool {
        let s = &self.spec;
        !s.components.is_empty()
            || !s.squareness.is_empty()
            || !s.load.is_empty()
            || s.thermal
                .iter()
                .any(|t| !matches!(t.kind, ThermalKind::PolynomialDt { .. }))
            || s.tools
                .iter()
                .any(|t| t.offset_mm.iter().any(|c| *c != 0.0))
    }

    /// Canonical TOML (µm, µrad, mm); reading it back gives an identical model.
    pub fn to_toml_string(&self) -> String {
        write::write_model(&self.spec)
    }

    pub fn name(&self) -> &str {
        &self.spec.name
    }

    /// The axes, in chain order (workpiece → tool).
    pub fn axes(&self) -> &[Axis] {
        &self.compiled.axes
    }

    /// Names as in `T_<name>_C` columns; index = position in [`ModelInput::temps_c`].
    pub fn temperature_sensors(&self) -> &[String] {
        &self.compiled.temperature_sensors
    }

    /// The column each sensor reads (`T_<name>_C`, or the sensor's `column`, e.g. `rpm`); index =
    /// position in [`ModelInput::temps_c`].
    pub fn sensor_columns(&self) -> &[String] {
        &self.compiled.sensor_columns
    }

    /// Names as in `F_<name>_N` columns; index = position in [`ModelInput::forces_n`].
    pub fn force_channels(&self) -> &[String] {
        &self.compiled.force_channels
    }

    /// Names as in `strain_<name>_ue` columns; index = position in [`ModelInput::strains_ue`].
    pub fn strain_channels(&self) -> &[String] {
        &self.compiled.strain_channels
    }

    /// One name per contribution; index = term id in [`ErrorBreakdown::terms_um`].
    pub fn term_names(&self) -> &[String] {
        &self.compiled.term_names
    }

    /// Where each lag of `state` stands, as `[lag_state]` stores it: `state` was last stepped at
    /// recording time `t_s`. Sensors without a lag, or never read, are left out.
    pub fn lag_state_of(&self, state: &ModelState, t_s: f64) -> LagState {
        let lagged = self
            .spec
            .sensors
            .iter()
            .enumerate()
            .filter(|(_, s)| s.tau_s.is_some())
            .filter_map(|(i, s)| Some((s.name.clone(), state.thermal.lagged_c(i)?)))
            .collect();
        LagState { t_s, lagged }
    }

    /// A fresh state for a recording whose first row is at `first_t_s`: each lag the model's
    /// `[lag_state]` names starts from its stored value when the recording begins after the stored
    /// time (a continuation of the recording the model was fitted on); otherwise every lag starts
    /// at its first reading, as [`Self::new_state`].
    pub fn new_state_at(&self, first_t_s: f64) -> (ModelState, LagStart) {
        let mut state = self.new_state();
        let Some(ls) = &self.spec.lag_state else {
            return (state, LagStart::FirstReading);
        };
        // NaN (no time) counts as not after.
        if first_t_s.partial_cmp(&ls.t_s) != Some(std::cmp::Ordering::Greater) {
            return (state, LagStart::StoredNotBefore { stored_t_s: ls.t_s });
        }
        let mut n = 0;
        for (name, v) in &ls.lagged {
            if let Some(i) = self.spec.sensors.iter().position(|s| &s.name == name) {
                state.thermal.resume(i, *v, ls.t_s);
                n += 1;
            }
        }
        (
            state,
            LagStart::Resumed {
                stored_t_s: ls.t_s,
                sensors: n,
            },
        )
    }

    pub fn new_state(&self) -> ModelState {
        ModelState {
            thermal: ThermalState::new(self.spec.sensors.len()),
            forces_n: vec![0.0; self.spec.forces.len()],
        }
    }

    /// A breakdown sized for this model (so `evaluate` never allocates).
    pub fn new_breakdown(&self) -> ErrorBreakdown {
        let mut b = ErrorBreakdown::default();
        b.reset(self.compiled.term_names.len());
        b
    }

    /// An input with the right channel vector lengths, temperatures at their references.
    pub fn new_input(&self) -> ModelInput {
        ModelInput {
            temps_c: self.spec.sensors.iter().map(|s| s.reference_c).collect(),
            forces_n: vec![0.0; self.compiled.force_channels.len()],
            strains_ue: vec![0.0; self.compiled.strain_channels.len()],
            ..ModelInput::default()
        }
    }

    /// Exact (4×4 HTM) tool-tip error, µm, actual − nominal, in machine X/Y/Z; steps lag states
    /// to `input.t_s`. Writes every term of `out` in place (no allocation once `out` is sized, e.g.
    /// by [`new_breakdown`](Self::new_breakdown)).
    pub fn evaluate(&self, input: &ModelInput, state: &mut ModelState, out: &mut ErrorBreakdown) {
        self.plan.run(input, state, out, true);
    }

    /// First-order closed form Σ δ_K + ε_K × arm_K + squareness · q (+ thermal, load); agrees with
    /// [`evaluate`](Self::evaluate) to second order in the errors.
    pub fn evaluate_first_order(
        &self,
        input: &ModelInput,
        state: &mut ModelState,
        out: &mut ErrorBreakdown,
    ) {
        self.plan.run(input, state, out, false);
    }

    /// [`evaluate`](Self::evaluate) over `inputs` in time order with one state: `each(i, out)` sees
    /// point i's full breakdown in the reused buffer `out` (nothing allocated per point).
    pub fn evaluate_batch<F: FnMut(usize, &ErrorBreakdown)>(
        &self,
        inputs: &[ModelInput],
        state: &mut ModelState,
        out: &mut ErrorBreakdown,
        mut each: F,
    ) {
        for (i, input) in inputs.iter().enumerate() {
            self.plan.run(input, state, out, true);
            each(i, out);
        }
    }

    /// The straightforward evaluator (`reference.rs`) the fast plan is checked against: the same
    /// results within rounding (`tests/models/fastpath.rs`), slower. `exact` picks the HTM chain.
    #[doc(hidden)]
    pub fn evaluate_reference(
        &self,
        input: &ModelInput,
        state: &mut ModelState,
        out: &mut ErrorBreakdown,
        exact: bool,
    ) {
        reference::run(&self.spec, &self.compiled, input, state, out, exact);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_types_are_send_sync_clone() {
        fn check<T: Clone + Send + Sync>() {}
        check::<MachineModel>();
        check::<ModelState>();
        check::<ErrorBreakdown>();
        check::<ModelInput>();
    }
}
