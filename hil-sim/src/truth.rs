//! The visible part of the true machine: its static geometric error, behind a small trait so the
//! simulator can use either the built-in stand-in below or the project's `VolumetricModel`.
//!
//! Sign: error = actual − nominal (ISO 230-2), µm, per tool-tip direction (x, y, z).

use serde::{Deserialize, Serialize};

/// A static geometric error model of the machine.
pub trait TruthModel: Send {
    /// Tool-tip error (µm, actual − nominal) with the slides at `q_mm`, approached in direction
    /// `dir` (+1/−1 per axis, 0 unknown), and the tool `tool_mm` long.
    fn static_error_um(&mut self, q_mm: [f64; 3], dir: [i8; 3], tool_mm: f64) -> [f64; 3];
    /// Parameters for the manifest of hidden truth.
    fn describe(&self) -> serde_json::Value;
}

/// Built-in first-order stand-in: scale (EXX/EYY/EZZ), squareness, a straightness bow of X, and the
/// Abbe effect of X pitch on a tool of length `tool_mm`.
///
/// ex = exx_ppm·x·1e-3 + ec0y_urad·y·1e-3 + eb0z_urad·z·1e-3 + ebx_urad_per_m·(x/1000)·tool·1e-3
/// ey = eyy_ppm·y·1e-3 + eyx_um_per_m2·(x/1000)² + ea0z_urad·z·1e-3
/// ez = ezz_ppm·z·1e-3
/// (ppm·mm and µrad·mm are nm, hence ·1e-3 for µm.) Squareness signs are this stand-in's own
/// convention (a positive value adds error proportional to the other axis' position).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BuiltinGeometry {
    #[serde(default)]
    pub exx_ppm: f64,
    #[serde(default)]
    pub eyy_ppm: f64,
    #[serde(default)]
    pub ezz_ppm: f64,
    #[serde(default)]
    pub ec0y_urad: f64,
    #[serde(default)]
    pub eb0z_urad: f64,
    #[serde(default)]
    pub ea0z_urad: f64,
    #[serde(default)]
    pub eyx_um_per_m2: f64,
    #[serde(default)]
    pub ebx_urad_per_m: f64,
}

impl TruthModel for BuiltinGeometry {
    fn static_error_um(&mut self, q: [f64; 3], _dir: [i8; 3], tool_mm: f64) -> [f64; 3] {
        let [x, y, z] = q;
        [
            self.exx_ppm * x * 1e-3
                + self.ec0y_urad * y * 1e-3
                + self.eb0z_urad * z * 1e-3
                + self.ebx_urad_per_m * (x / 1000.0) * tool_mm * 1e-3,
            self.eyy_ppm * y * 1e-3
                + self.eyx_um_per_m2 * (x / 1000.0).powi(2)
                + self.ea0z_urad * z * 1e-3,
            self.ezz_ppm * z * 1e-3,
        ]
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "kind": "builtin_first_order", "params": self })
    }
}

/// The project's volumetric model (`retrocomp_model::MachineModel`, exact 4×4 evaluation) as the
/// true machine's geometry. Temperatures, forces and strains stay at the model's references: the
/// hidden physics adds those effects itself.
#[derive(Debug)]
pub struct VolumetricTruth {
    path: String,
    model: retrocomp_model::MachineModel,
    state: retrocomp_model::ModelState,
    input: retrocomp_model::ModelInput,
    out: retrocomp_model::ErrorBreakdown,
}

impl VolumetricTruth {
    pub fn from_toml_path(path: &std::path::Path) -> anyhow::Result<Self> {
        let model = retrocomp_model::MachineModel::from_toml_path(path)
            .map_err(|e| anyhow::anyhow!("truth.model_path: {e}"))?;
        Ok(Self::new(model, path.display().to_string()))
    }

    pub fn new(model: retrocomp_model::MachineModel, origin: String) -> Self {
        Self {
            path: origin,
            state: model.new_state(),
            input: model.new_input(),
            out: model.new_breakdown(),
            model,
        }
    }
}

impl TruthModel for VolumetricTruth {
    fn static_error_um(&mut self, q_mm: [f64; 3], dir: [i8; 3], tool_mm: f64) -> [f64; 3] {
        self.input.pos_mm = q_mm;
        self.input.dir = dir;
        self.input.tool_mm = Some(tool_mm);
        self.model
            .evaluate(&self.input, &mut self.state, &mut self.out);
        self.out.total_um
    }

    fn describe(&self) -> serde_json::Value {
        serde_json::json!({ "kind": "volumetric_model", "path": self.path, "name": self.model.name(),
            "model_toml": self.model.to_toml_string() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_term_models_lock_the_signs() {
        let mut m = BuiltinGeometry {
            exx_ppm: 10.0,
            ..Default::default()
        };
        assert_eq!(
            m.static_error_um([100.0, 0.0, 0.0], [0; 3], 0.0),
            [1.0, 0.0, 0.0],
            "10 ppm over 100 mm = +1 µm"
        );
        let mut m = BuiltinGeometry {
            ec0y_urad: 20.0,
            ..Default::default()
        };
        assert_eq!(
            m.static_error_um([0.0, 50.0, 0.0], [0; 3], 0.0),
            [1.0, 0.0, 0.0]
        );
        let mut m = BuiltinGeometry {
            ebx_urad_per_m: 50.0,
            ..Default::default()
        };
        let e = m.static_error_um([200.0, 0.0, 0.0], [0; 3], 100.0);
        assert!(
            (e[0] - 1.0).abs() < 1e-12,
            "10 µrad pitch at 200 mm × 100 mm arm = 1 µm: {e:?}"
        );
    }
}
