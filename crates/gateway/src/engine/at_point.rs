//! The engine evaluated at a commanded point rather than at the measured one: what a DNC
//! drip-feed (`retrocomp dnc`) needs for a block about to be sent — the correction at the block's
//! nominal end point, approached in the block's directions, with the inputs the engine judges
//! healthy now. Health, substitution, thermal latching and the model's evaluation are the cycle's
//! own steps ([`Engine::cycle_in_place`]); only the machine state differs (positions and
//! approach directions are the caller's, velocities 0) and no safety step runs: the caller's
//! last-step guard is the one output limit.
//!
//! An engine used this way must not also run cycles: the commanded point replaces the measured
//! positions in its state and the direction latch is not updated.
//!
//! Signs and units: corrections µm, = −error; positions mm (machine coordinates, X radial).

use retrocomp_model::approach::Approach;

use retrocomp_bus::Health;

use super::{Engine, ErrorModel, ModelError};

/// Why [`Engine::correction_at`] has no correction now.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum AtPointError {
    /// Required model inputs are unusable (stale, out of range, stuck …), with their faults.
    #[error("no usable value of {0}")]
    Inputs(String),
    /// The model failed on healthy inputs.
    #[error("model: {0}")]
    Model(ModelError),
}

impl Engine {
    /// The correction per axis X, Y, Z (µm, = −error; None for an axis the engine does not drive)
    /// at the commanded machine position `pos_mm`, approached in `dirs`, at `now_s`, from the
    /// inputs ingested so far ([`Engine::handle_sample`]). Faults start and clear in the engine's log as
    /// in a cycle (a channel's health, the model, `compensation.<axis>` while no target can be
    /// computed); [`Engine::snapshot`] shows the targets and terms of the last call.
    pub fn correction_at(
        &mut self,
        now_s: f64,
        model: &mut dyn ErrorModel,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
    ) -> Result<[Option<f64>; 3], AtPointError> {
        self.now_s = now_s;
        self.cycles += 1;
        self.fault_events.clear();
        self.judge_channels(now_s);
        self.evaluate_at(now_s, model, pos_mm, dirs)
    }

    /// [`Self::correction_at`] another point at the time of the last call, with no sample ingested
    /// since: the channels are not judged again, so a rejected reading's fault (started at a
    /// call, cleared at the next judging) is not cleared by this one, and the model's lag states
    /// do not move (Δt = 0). What the DNC drift prediction's second point per block uses.
    pub fn correction_at_again(
        &mut self,
        model: &mut dyn ErrorModel,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
    ) -> Result<[Option<f64>; 3], AtPointError> {
        self.fault_events.clear();
        self.evaluate_at(self.now_s, model, pos_mm, dirs)
    }

    /// Steps 3–5 of [`Self::correction_at`] on the channels as last judged.
    fn evaluate_at(
        &mut self,
        now_s: f64,
        model: &mut dyn ErrorModel,
        pos_mm: [f64; 3],
        dirs: [Approach; 3],
    ) -> Result<[Option<f64>; 3], AtPointError> {
        self.state.positions_mm = pos_mm.map(Some);
        self.state.velocities_mm_per_s = [Some(0.0); 3];
        self.state.weight_forward = dirs.map(|d| match d {
            Approach::Forward => 1.0,
            Approach::Reverse => 0.0,
        });
        self.state.t_s = now_s;
        let inputs_ok = self.model_inputs(model);
        self.partial = inputs_ok && self.optional_missing();
        let evaluated = self.evaluate_model(model, inputs_ok, now_s);
        let mut out = [None; 3];
        for a in &mut self.axes {
            a.target_um = None;
            if evaluated {
                out[a.axis.index()] = Some(a.take_target(&self.errors));
            }
        }
        self.report_drops(now_s);
        if let Some(e) = &self.model_error {
            return Err(AtPointError::Model(e.clone()));
        }
        if !evaluated {
            return Err(AtPointError::Inputs(self.unusable_inputs()));
        }
        Ok(out)
    }

    /// Whether [`Engine::correction_at`] at `now_s` would find every required, not optional,
    /// model input usable, judged as a call would judge them (health, thermal latch); evaluates
    /// nothing. What a DNC transfer waits for before its first line: a block sent before then
    /// would carry no correction.
    pub fn inputs_ready(&mut self, now_s: f64, model: &dyn ErrorModel) -> Result<(), AtPointError> {
        self.now_s = now_s;
        self.judge_channels(now_s);
        if self.model_inputs(model) {
            Ok(())
        } else {
            Err(AtPointError::Inputs(self.unusable_inputs()))
        }
    }

    /// True when a model input of the last call is not a healthy reading of its own: substituted
    /// from its neighbours, or an optional one missing or faulted. A caller that extrapolates the
    /// correction over time (`retrocomp dnc`'s drift prediction) must not extrapolate from it:
    /// switching to or from a substitute is a step, not a drift.
    pub fn inputs_degraded(&self) -> bool {
        self.partial
            || self.required.iter().flatten().any(|&slot| {
                self.channels[slot]
                    .status
                    .as_ref()
                    .is_none_or(|st| st.health != Health::Ok || st.substituted)
            })
    }

    /// The required, not optional, model inputs without a usable value, with their faults:
    /// "T_spindle_C (stale)". Allocates: called only on a refusal.
    fn unusable_inputs(&self) -> String {
        let mut out = Vec::new();
        for &slot in self.required.iter().flatten() {
            let c = &self.channels[slot];
            if c.value.is_some() || self.optional.contains(&slot) {
                continue;
            }
            let faults = c.status.as_ref().map_or_else(
                || "no reading".to_string(),
                |st| {
                    let k: Vec<&str> = st.faults.iter().map(|k| k.as_str()).collect();
                    if k.is_empty() {
                        // Healthy again between two latches of a slow channel.
                        "healthy, used from the next thermal latch".to_string()
                    } else {
                        k.join(", ")
                    }
                },
            );
            out.push(format!("{} ({faults})", c.name));
        }
        out.join("; ")
    }
}
