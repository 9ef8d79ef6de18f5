//! Cutting force from a simple process model and its effect on the tool point.
//!
//! The stock's top face is at `stock_top_z_mm`; while a feed move runs with the spindle on below it,
//! depth of cut = stock_top − z (nominal), chip thickness f_z = feed/(rpm·teeth), and the cutting
//! force is F = kc · depth · f_z (N; kc in N/mm², the specific cutting force). It deflects the tool
//! by `compliance_um_per_N` per axis (signed: error actual − nominal). Strain gauges read
//! `ue_per_N·F + ue_per_K·ΔT(node)` plus noise; the force channel `F_<force_name>_N` is a load cell
//! with its own noise.

use super::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CuttingConfig {
    pub stock_top_z_mm: f64,
    #[serde(default = "d_kc")]
    pub kc_N_per_mm2: f64,
    #[serde(default = "d_teeth")]
    pub teeth: f64,
    #[serde(default)]
    pub compliance_um_per_N: Vec3,
    /// Channel name of the force reading (`F_<name>_N`).
    #[serde(default = "d_force_name")]
    pub force_name: String,
    #[serde(default)]
    pub force_noise_N: f64,
    #[serde(default)]
    pub gauges: Vec<GaugeConfig>,
}
fn d_kc() -> f64 {
    2000.0
}
fn d_teeth() -> f64 {
    2.0
}
fn d_force_name() -> String {
    "cut".into()
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GaugeConfig {
    /// Channel becomes `strain_<name>_ue`.
    pub name: String,
    pub ue_per_N: f64,
    #[serde(default)]
    pub ue_per_K: f64,
    /// Thermal node the gauge sits on (its temperature sensitivity acts on that node's rise).
    #[serde(default)]
    pub node: Option<String>,
    #[serde(default)]
    pub noise_ue: f64,
}

impl CuttingConfig {
    pub fn validate(&self, thermal: Option<&super::thermal::ThermalConfig>) -> anyhow::Result<()> {
        use anyhow::ensure;
        ensure!(
            self.kc_N_per_mm2 >= 0.0,
            "hidden.cutting.kc_N_per_mm2 must be >= 0"
        );
        ensure!(self.teeth > 0.0, "hidden.cutting.teeth must be > 0");
        ensure!(
            self.force_noise_N >= 0.0,
            "hidden.cutting.force_noise_N must be >= 0"
        );
        for (i, g) in self.gauges.iter().enumerate() {
            ensure!(
                g.noise_ue >= 0.0,
                "hidden.cutting.gauges[{i}].noise_ue must be >= 0"
            );
            if let Some(n) = &g.node {
                ensure!(
                    thermal.and_then(|t| t.node_index(n)).is_some(),
                    "hidden.cutting.gauges[{i}] ({}): unknown thermal node `{n}`",
                    g.name
                );
            }
        }
        Ok(())
    }

    /// Cutting force for a nominal z, feed and spindle speed; 0 out of cut.
    pub fn force_N(&self, feeding: bool, z_mm: f64, feed_mm_min: f64, rpm: f64) -> f64 {
        if !feeding || rpm <= 0.0 {
            return 0.0;
        }
        let depth_mm = (self.stock_top_z_mm - z_mm).max(0.0);
        let fz_mm = feed_mm_min / (rpm * self.teeth);
        self.kc_N_per_mm2 * depth_mm * fz_mm
    }

    /// Tool-point deflection, µm per axis.
    pub fn deflection_um(&self, force_N: f64) -> [f64; 3] {
        std::array::from_fn(|k| self.compliance_um_per_N.get(k) * force_N)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn force_follows_depth_feed_speed_and_is_zero_out_of_cut() {
        let c = CuttingConfig {
            stock_top_z_mm: 0.0,
            kc_N_per_mm2: 2000.0,
            teeth: 2.0,
            compliance_um_per_N: Vec3 {
                x: 0.02,
                y: 0.0,
                z: -0.01,
            },
            force_name: "cut".into(),
            force_noise_N: 0.0,
            gauges: vec![],
        };
        // 1 mm deep, 500 mm/min at 2000 rpm with 2 teeth: f_z = 0.125 mm, F = 250 N.
        let f = c.force_N(true, -1.0, 500.0, 2000.0);
        assert!((f - 250.0).abs() < 1e-9);
        assert_eq!(c.force_N(true, 1.0, 500.0, 2000.0), 0.0, "above the stock");
        assert_eq!(c.force_N(false, -1.0, 500.0, 2000.0), 0.0, "rapid");
        assert_eq!(c.force_N(true, -1.0, 500.0, 0.0), 0.0, "spindle off");
        assert_eq!(c.deflection_um(f), [5.0, 0.0, -2.5]);
    }
}
