//! The seam between the engine and a model: the machine state the model reads ([`MachineState`],
//! indexed by [`Axis`] and by the order of [`ErrorModel::required_channels`]), the per-axis error
//! terms it writes ([`AxisErrors`]), and the [`ErrorModel`] trait (`model_adapter.rs` implements it
//! for `crates/model/src`), and its one error, [`ModelError`].
//!
//! Signs and units: the model returns errors (actual − nominal) in µm, per axis and term; positions
//! are mm, velocities mm/s, forward weights 0…1 (1 = approaching forward). The engine negates errors
//! into corrections.

use std::sync::Arc;

use crate::status::ModelIdentity;
use retrocomp_model::Axis;

/// Why a model could not evaluate a cycle: the engine holds the cycle's outputs (an `Input::Fault`
/// to the safety layer) and reports a `decode` fault on the model while it lasts.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ModelError {
    /// A required input channel (its name) has no value this cycle.
    #[error("missing {0}")]
    MissingInput(Arc<str>),
    /// The model refused its input (a non-finite position or time).
    #[error("model rejected the input (non-finite position or time)")]
    InvalidInput,
    /// Any other failure of a model the engine does not know (the message says what).
    #[error("{0}")]
    Other(String),
}

impl From<&str> for ModelError {
    fn from(why: &str) -> Self {
        ModelError::Other(why.to_string())
    }
}

impl From<String> for ModelError {
    fn from(why: String) -> Self {
        ModelError::Other(why)
    }
}

/// The machine state the model sees, indexed by [`Axis::index`] and by the position of a channel in
/// [`ErrorModel::required_channels`]. Updated in place: a cycle allocates nothing.
#[derive(Clone, Debug)]
pub struct MachineState {
    /// Axis positions, mm (None: the axis is not driven or its position is unusable).
    pub positions_mm: [Option<f64>; 3],
    /// Axis velocities, mm/s.
    pub velocities_mm_per_s: [Option<f64>; 3],
    /// Per axis, the forward weight of the direction latch: 1 forward, 0 reverse, ½ unknown (also
    /// for an axis that never had a position), in between while a reversal is being blended (sin²
    /// over `switch_time_s`). The model blends its forward/reverse tables with it:
    /// e = w·e_forward + (1 − w)·e_reverse.
    pub weight_forward: [f64; 3],
    /// The values of the model's [`ErrorModel::required_channels`], in that order (slow ones
    /// latched), channel units; None while unusable.
    pub inputs: Vec<Option<f64>>,
    /// Time of this cycle, s (steps thermal lags in the model).
    pub t_s: f64,
}

impl Default for MachineState {
    fn default() -> Self {
        Self {
            positions_mm: [None; 3],
            velocities_mm_per_s: [None; 3],
            weight_forward: [0.5; 3],
            inputs: Vec::new(),
            t_s: 0.0,
        }
    }
}

impl MachineState {
    /// Position of `axis`, mm.
    pub fn position_mm(&self, axis: Axis) -> Option<f64> {
        self.positions_mm[axis.index()]
    }

    /// Forward weight of `axis` (see [`MachineState::weight_forward`]).
    pub fn forward_weight(&self, axis: Axis) -> f64 {
        self.weight_forward[axis.index()]
    }

    /// Value of the `k`-th required channel (None if unusable or out of range).
    pub fn input(&self, k: usize) -> Option<f64> {
        self.inputs.get(k).copied().flatten()
    }
}

/// One error term's contribution along one machine axis, µm (actual − nominal), already blended
/// for direction with [`MachineState::weight_forward`]. The name is shared (`Arc`), so a model
/// that names its terms once hands them out every cycle without allocating.
#[derive(Clone, Debug, PartialEq)]
pub struct TermError {
    pub term: Arc<str>,
    pub error_um: f64,
}

/// Error terms per machine axis, filled by [`ErrorModel::axis_errors`]. Holds one term list per
/// axis the engine drives (indexed by [`Axis::index`]); the lists keep their capacity across cycles.
#[derive(Clone, Debug, Default)]
pub struct AxisErrors {
    axes: [Option<Vec<TermError>>; 3],
}

impl AxisErrors {
    /// Term lists for these axes.
    pub fn with_axes(axes: impl IntoIterator<Item = Axis>) -> Self {
        let mut e = Self::default();
        for a in axes {
            e.axes[a.index()] = Some(Vec::new());
        }
        e
    }

    /// Empties every axis' list (keeps the capacity).
    pub fn clear(&mut self) {
        for t in self.axes.iter_mut().flatten() {
            t.clear();
        }
    }

    /// Adds one term to `axis`; returns false (and drops it) when the engine does not drive it.
    pub fn push(&mut self, axis: Axis, term: Arc<str>, error_um: f64) -> bool {
        match &mut self.axes[axis.index()] {
            Some(t) => {
                t.push(TermError { term, error_um });
                true
            }
            None => false,
        }
    }

    /// The terms of `axis` (empty for an axis not driven or one the model left out).
    pub fn axis(&self, axis: Axis) -> &[TermError] {
        self.axes[axis.index()].as_deref().unwrap_or(&[])
    }
}

/// What the gateway needs from a model (`model_adapter.rs` implements it for `crates/model/src`).
pub trait ErrorModel {
    /// Channels the model reads (besides axis positions), by name; their values reach the model
    /// as [`MachineState::inputs`], in this order. Missing ones make the inputs stale. Called at
    /// the engine's first cycle, and again after `Engine::model_replaced` (never per cycle): the
    /// engine resolves the names in its channel table then.
    fn required_channels(&self) -> Vec<Arc<str>>;
    /// Those of [`ErrorModel::required_channels`] whose loss removes only the terms that use them
    /// (the model is evaluated without them and those terms are zero), not the whole correction:
    /// auxiliary inputs such as a cutting force. Default: none.
    fn optional_channels(&self) -> Vec<Arc<str>> {
        Vec::new()
    }
    /// Push, per machine axis, its error terms at `state` into `out` (cleared by the caller).
    /// `&mut self`: models keep evaluation state (thermal lags, scratch buffers).
    fn axis_errors(&mut self, state: &MachineState, out: &mut AxisErrors)
    -> Result<(), ModelError>;
    /// Which model this is (name, content hash, when loaded), for the status page; None if unknown.
    fn identity(&self) -> Option<ModelIdentity> {
        None
    }
}
