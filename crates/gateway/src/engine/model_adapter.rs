//! Adapter from the machine model (`crates/model/src`, [`MachineModel`]) to the gateway's [`ErrorModel`].
//!
//! Channel names follow docs/recording-csv.md: temperature sensor `s` is channel `T_<s>_C`, force `F_<f>_N`,
//! strain `strain_<g>_ue`. Direction: the model picks forward/reverse tables by `dir` (+1/−1, 0 = mean).
//! The gateway latches each axis' direction and blends a reversal over time; for an axis mid-blend
//! (0 < w < 1) the model is evaluated with that axis forward and reverse and the results mixed
//! w·e₊ + (1 − w)·e₋, so a reversal never steps the output. Errors are actual − nominal, µm.

use std::sync::Arc;

use crate::engine::{AxisErrors, ErrorModel, MachineState, ModelError};
use crate::status::ModelIdentity;
use retrocomp_model::{Axis, ErrorBreakdown, MachineModel, ModelInput, ModelState};

#[derive(Debug)]
pub struct MachineModelAdapter {
    model: MachineModel,
    state: ModelState,
    input: ModelInput,
    main: ErrorBreakdown,
    plus: ErrorBreakdown,
    minus: ErrorBreakdown,
    /// Per-term errors after the reversal blend, µm.
    acc: Vec<[f64; 3]>,
    /// The model's channels, resolved once; [`ErrorModel::required_channels`] lists them in this
    /// order (temperatures, forces, strains), so `MachineState::inputs` follows it too.
    temp_channels: Vec<Arc<str>>,
    force_channels: Vec<Arc<str>>,
    strain_channels: Vec<Arc<str>>,
    /// The model's term names, shared with the engine's per-axis breakdown (no allocation per cycle).
    term_names: Vec<Arc<str>>,
    /// Use the first-order closed form (cheaper) instead of the exact 4×4 chain.
    pub first_order: bool,
    identity: ModelIdentity,
}

fn dir_of(w: f64) -> i8 {
    if w >= 1.0 {
        1
    } else if w <= 0.0 {
        -1
    } else {
        0
    }
}

impl MachineModelAdapter {
    pub fn new(model: MachineModel) -> Self {
        let identity = identity_of(&model);
        Self {
            identity,
            state: model.new_state(),
            input: model.new_input(),
            main: model.new_breakdown(),
            plus: model.new_breakdown(),
            minus: model.new_breakdown(),
            acc: Vec::new(),
            temp_channels: model
                .sensor_columns()
                .iter()
                .map(|c| Arc::from(c.as_str()))
                .collect(),
            force_channels: model
                .force_channels()
                .iter()
                .map(|s| Arc::from(format!("F_{s}_N")))
                .collect(),
            strain_channels: model
                .strain_channels()
                .iter()
                .map(|s| Arc::from(format!("strain_{s}_ue")))
                .collect(),
            term_names: model
                .term_names()
                .iter()
                .map(|n| Arc::from(n.as_str()))
                .collect(),
            model,
            first_order: false,
        }
    }

    pub fn model(&self) -> &MachineModel {
        &self.model
    }

    fn eval(&mut self, which: u8) {
        let out = match which {
            0 => &mut self.main,
            1 => &mut self.plus,
            _ => &mut self.minus,
        };
        if self.first_order {
            self.model
                .evaluate_first_order(&self.input, &mut self.state, out);
        } else {
            self.model.evaluate(&self.input, &mut self.state, out);
        }
    }
}

impl ErrorModel for MachineModelAdapter {
    fn identity(&self) -> Option<ModelIdentity> {
        Some(self.identity.clone())
    }

    fn required_channels(&self) -> Vec<Arc<str>> {
        self.temp_channels
            .iter()
            .chain(&self.force_channels)
            .chain(&self.strain_channels)
            .cloned()
            .collect()
    }

    /// Forces and strains feed only the `[[load]]` terms, which are linear in the force (compliance
    /// × F, reference × F / F_ref): without them those terms are zero and the geometric and thermal
    /// terms are unchanged, so a stale force drops only the load terms.
    fn optional_channels(&self) -> Vec<Arc<str>> {
        self.force_channels
            .iter()
            .chain(&self.strain_channels)
            .cloned()
            .collect()
    }

    fn axis_errors(&mut self, s: &MachineState, out: &mut AxisErrors) -> Result<(), ModelError> {
        self.input.t_s = s.t_s;
        let mut weights = [1.0f64; 3];
        for ax in Axis::ALL {
            let i = ax.index();
            self.input.pos_mm[i] = s.position_mm(ax).unwrap_or(0.0);
            weights[i] = s.forward_weight(ax);
            self.input.dir[i] = dir_of(weights[i]);
        }
        // `s.inputs` follows `required_channels`: temperatures, then forces, then strains.
        let (nt, nf) = (self.temp_channels.len(), self.force_channels.len());
        for (k, ch) in self.temp_channels.iter().enumerate() {
            self.input.temps_c[k] = s
                .input(k)
                .ok_or_else(|| ModelError::MissingInput(Arc::clone(ch)))?;
        }
        // A missing force or strain (optional, see above) is NaN: the model then takes the force
        // as absent and its load terms are zero.
        for k in 0..nf {
            self.input.forces_n[k] = s.input(nt + k).unwrap_or(f64::NAN);
        }
        for k in 0..self.strain_channels.len() {
            self.input.strains_ue[k] = s.input(nt + nf + k).unwrap_or(f64::NAN);
        }
        self.eval(0);
        if self.main.flags.invalid_input {
            return Err(ModelError::InvalidInput);
        }
        // Axes mid-reversal: the base evaluation used dir 0 (mean of F/R) for them; add, per such
        // axis, w·e₊ + (1 − w)·e₋ − e_base. Exact when each table's F/R choice follows its own axis'
        // direction (terms are additive), which is how the model defines bidirectional tables.
        self.acc.clone_from(&self.main.terms_um);
        for (i, &w) in weights.iter().enumerate() {
            if w > 0.0 && w < 1.0 && (w - 0.5).abs() > 1e-12 {
                self.input.dir[i] = 1;
                self.eval(1);
                self.input.dir[i] = -1;
                self.eval(2);
                self.input.dir[i] = 0;
                for ((a, b), (p, n)) in self
                    .acc
                    .iter_mut()
                    .zip(&self.main.terms_um)
                    .zip(self.plus.terms_um.iter().zip(&self.minus.terms_um))
                {
                    for k in 0..3 {
                        a[k] += w * p[k] + (1.0 - w) * n[k] - b[k];
                    }
                }
            }
        }
        for ax in Axis::ALL {
            let i = ax.index();
            if s.position_mm(ax).is_none() {
                continue;
            }
            for (v, n) in self.acc.iter().zip(&self.term_names) {
                if v[i] != 0.0 {
                    out.push(ax, n.clone(), v[i]);
                }
            }
        }
        Ok(())
    }
}

/// Name, SHA-256 of the canonical TOML, when it was loaded (now), and each term's group
/// (components, squareness: geometric; `[[thermal]]` terms: thermal; `[[load]]` terms: load; the
/// chain's cross terms: other).
pub(crate) fn identity_of(model: &MachineModel) -> ModelIdentity {
    use sha2::Digest as _;
    let spec = model.spec();
    let hash = sha2::Sha256::digest(model.to_toml_string().as_bytes());
    let term_groups = model
        .term_names()
        .iter()
        .map(|t| {
            let group = if spec.thermal.iter().any(|s| &s.name == t) {
                "thermal"
            } else if spec.load.iter().any(|s| &s.name == t) {
                "load"
            } else if t == "higher_order" {
                "other"
            } else {
                "geometric"
            };
            (t.clone(), group)
        })
        .collect();
    ModelIdentity {
        name: model.name().to_string(),
        sha256: hash.iter().map(|b| format!("{b:02x}")).collect(),
        loaded_unix_s: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64()),
        term_groups,
    }
}
