//! Thermal network of the true machine: lumped nodes (spindle housing, column, screw nut, …), each a
//! first-order element heated by spindle speed and by axis motion, cooled toward ambient, and coupled
//! to other nodes. Ambient drifts linearly and swings daily. Sensors read a node (or ambient) through
//! their own first-order lag plus an offset; noise is added when they are sampled.
//!
//! `dT/dt = (T_amb + rise_C_per_krpm·rpm/1000 + Σ_k rise_C_per_mm_s[k]·|v_k| − T)/tau_s + Σ_c (T_c − T)/tau_c`
//! (so `rise_*` is the steady-state rise in °C). Effects act relative to each node's start temperature
//! (thermal terms are zeroed at job start, as in Spaan Ch5):
//! - `growth`:    e_axis += um_per_K · ΔT                     (drift of the tool point)
//! - `expansion`: slide_axis += ppm_per_K · ΔT · motor_mm·1e-3 (screw/scale expansion, µm)

use super::{AxisName, Vec3};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalConfig {
    #[serde(default = "d_ambient")]
    pub ambient_C: f64,
    #[serde(default)]
    pub ambient_drift_C_per_h: f64,
    #[serde(default)]
    pub ambient_swing_C: f64,
    #[serde(default = "d_day")]
    pub ambient_period_s: f64,
    pub nodes: Vec<NodeConfig>,
    #[serde(default)]
    pub sensors: Vec<SensorConfig>,
    #[serde(default)]
    pub effects: Vec<ThermalEffect>,
}
fn d_ambient() -> f64 {
    20.0
}
fn d_day() -> f64 {
    86400.0
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct NodeConfig {
    pub name: String,
    pub tau_s: f64,
    #[serde(default)]
    pub rise_C_per_krpm: f64,
    #[serde(default)]
    pub rise_C_per_mm_s: Vec3,
    #[serde(default)]
    pub couple: Vec<Coupling>,
    /// Start temperature (default: ambient at t = 0).
    #[serde(default)]
    pub start_C: Option<f64>,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Coupling {
    pub node: String,
    pub tau_s: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SensorConfig {
    /// Channel becomes `T_<name>_C`.
    pub name: String,
    /// Node name, or `ambient`.
    pub node: String,
    #[serde(default)]
    pub tau_s: f64,
    #[serde(default)]
    pub noise_C: f64,
    #[serde(default)]
    pub offset_C: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ThermalEffect {
    Growth {
        node: String,
        axis: AxisName,
        um_per_K: f64,
    },
    Expansion {
        node: String,
        axis: AxisName,
        ppm_per_K: f64,
    },
}

impl ThermalConfig {
    pub fn validate(&self) -> anyhow::Result<()> {
        use anyhow::ensure;
        ensure!(
            !self.nodes.is_empty(),
            "hidden.thermal.nodes: at least one node"
        );
        ensure!(
            self.ambient_period_s > 0.0,
            "hidden.thermal.ambient_period_s must be > 0"
        );
        for (i, n) in self.nodes.iter().enumerate() {
            ensure!(
                n.tau_s > 0.0,
                "hidden.thermal.nodes[{i}] ({}): tau_s must be > 0",
                n.name
            );
            ensure!(
                n.name != "ambient",
                "hidden.thermal.nodes[{i}]: `ambient` is reserved"
            );
            ensure!(
                self.nodes[..i].iter().all(|m| m.name != n.name),
                "hidden.thermal.nodes[{i}]: duplicate node name `{}`",
                n.name
            );
            for c in &n.couple {
                ensure!(
                    c.tau_s > 0.0,
                    "hidden.thermal.nodes[{i}].couple: tau_s must be > 0"
                );
                ensure!(
                    self.node_index(&c.node).is_some(),
                    "hidden.thermal.nodes[{i}].couple: unknown node `{}`",
                    c.node
                );
            }
        }
        for (i, s) in self.sensors.iter().enumerate() {
            ensure!(
                s.tau_s >= 0.0 && s.noise_C >= 0.0,
                "hidden.thermal.sensors[{i}]: tau_s, noise_C must be >= 0"
            );
            ensure!(
                s.node == "ambient" || self.node_index(&s.node).is_some(),
                "hidden.thermal.sensors[{i}] ({}): unknown node `{}`",
                s.name,
                s.node
            );
        }
        for (i, e) in self.effects.iter().enumerate() {
            let node = match e {
                ThermalEffect::Growth { node, .. } | ThermalEffect::Expansion { node, .. } => node,
            };
            ensure!(
                self.node_index(node).is_some(),
                "hidden.thermal.effects[{i}]: unknown node `{node}`"
            );
        }
        Ok(())
    }

    pub fn node_index(&self, name: &str) -> Option<usize> {
        self.nodes.iter().position(|n| n.name == name)
    }
}

/// Per-axis thermal contributions at one instant, µm.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ThermalTerms {
    pub growth_um: [f64; 3],
    /// Expansion per mm of motor position (ppm·ΔT·1e-3, µm/mm): multiplied by the position by the world.
    pub expansion_um_per_mm: [f64; 3],
}

#[derive(Clone, Debug)]
pub struct ThermalNet {
    cfg: ThermalConfig,
    temps_C: Vec<f64>,
    start_C: Vec<f64>,
    sensor_state_C: Vec<f64>,
    couple_idx: Vec<Vec<(usize, f64)>>,
    effects: Vec<(usize, usize, bool, f64)>, // (node, axis, is_expansion, coefficient)
    t_s: f64,
}

impl ThermalNet {
    pub fn new(cfg: ThermalConfig) -> Self {
        let amb = cfg.ambient_C;
        let temps_C: Vec<f64> = cfg.nodes.iter().map(|n| n.start_C.unwrap_or(amb)).collect();
        let couple_idx = cfg
            .nodes
            .iter()
            .map(|n| {
                n.couple
                    .iter()
                    .map(|c| (cfg.node_index(&c.node).expect("validated"), c.tau_s))
                    .collect()
            })
            .collect();
        let effects = cfg
            .effects
            .iter()
            .map(|e| match e {
                ThermalEffect::Growth {
                    node,
                    axis,
                    um_per_K,
                } => (
                    cfg.node_index(node).expect("validated"),
                    axis.index(),
                    false,
                    *um_per_K,
                ),
                ThermalEffect::Expansion {
                    node,
                    axis,
                    ppm_per_K,
                } => (
                    cfg.node_index(node).expect("validated"),
                    axis.index(),
                    true,
                    *ppm_per_K,
                ),
            })
            .collect();
        let mut net = Self {
            start_C: temps_C.clone(),
            temps_C,
            sensor_state_C: vec![],
            couple_idx,
            effects,
            cfg,
            t_s: 0.0,
        };
        net.sensor_state_C = (0..net.cfg.sensors.len())
            .map(|i| net.sensor_true_C(i))
            .collect();
        net
    }

    pub fn config(&self) -> &ThermalConfig {
        &self.cfg
    }

    pub fn ambient_C(&self) -> f64 {
        let c = &self.cfg;
        c.ambient_C
            + c.ambient_drift_C_per_h * self.t_s / 3600.0
            + c.ambient_swing_C * (std::f64::consts::TAU * self.t_s / c.ambient_period_s).sin()
    }

    pub fn node_C(&self, i: usize) -> f64 {
        self.temps_C[i]
    }

    fn sensor_true_C(&self, i: usize) -> f64 {
        let s = &self.cfg.sensors[i];
        match self.cfg.node_index(&s.node) {
            Some(n) => self.temps_C[n],
            None => self.ambient_C(),
        }
    }

    /// Advance by `dt_s` with the spindle at `rpm` and the axes at `vel_mm_s` (explicit Euler: dt ≪ tau).
    pub fn step(&mut self, dt_s: f64, rpm: f64, vel_mm_s: [f64; 3]) {
        let amb = self.ambient_C();
        let old = self.temps_C.clone();
        for (i, n) in self.cfg.nodes.iter().enumerate() {
            let drive = amb
                + n.rise_C_per_krpm * rpm.abs() / 1000.0
                + (0..3)
                    .map(|k| n.rise_C_per_mm_s.get(k) * vel_mm_s[k].abs())
                    .sum::<f64>();
            let mut d = (drive - old[i]) / n.tau_s;
            for &(j, tau) in &self.couple_idx[i] {
                d += (old[j] - old[i]) / tau;
            }
            self.temps_C[i] = old[i] + d * dt_s;
        }
        self.t_s += dt_s;
        for i in 0..self.cfg.sensors.len() {
            let target = self.sensor_true_C(i);
            let tau = self.cfg.sensors[i].tau_s;
            let a = if tau > 0.0 {
                (dt_s / tau).min(1.0)
            } else {
                1.0
            };
            self.sensor_state_C[i] += (target - self.sensor_state_C[i]) * a;
        }
    }

    /// Noise-free sensor reading (lagged node temperature + offset).
    pub fn sensor_C(&self, i: usize) -> f64 {
        self.sensor_state_C[i] + self.cfg.sensors[i].offset_C
    }

    pub fn terms(&self) -> ThermalTerms {
        let mut t = ThermalTerms::default();
        for &(node, axis, expansion, coef) in &self.effects {
            let dt = self.temps_C[node] - self.start_C[node];
            if expansion {
                t.expansion_um_per_mm[axis] += coef * dt * 1e-3;
            } else {
                t.growth_um[axis] += coef * dt;
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_node(rise: f64, tau: f64) -> ThermalConfig {
        ThermalConfig {
            ambient_C: 20.0,
            ambient_drift_C_per_h: 0.0,
            ambient_swing_C: 0.0,
            ambient_period_s: 86400.0,
            nodes: vec![NodeConfig {
                name: "spindle".into(),
                tau_s: tau,
                rise_C_per_krpm: rise,
                rise_C_per_mm_s: Vec3::default(),
                couple: vec![],
                start_C: None,
            }],
            sensors: vec![SensorConfig {
                name: "s".into(),
                node: "spindle".into(),
                tau_s: 30.0,
                noise_C: 0.0,
                offset_C: 0.0,
            }],
            effects: vec![ThermalEffect::Growth {
                node: "spindle".into(),
                axis: AxisName::Z,
                um_per_K: 2.0,
            }],
        }
    }

    #[test]
    fn node_follows_first_order_step_response_and_sensor_lags() {
        let mut net = ThermalNet::new(one_node(1.5, 100.0));
        // 4000 rpm → steady rise 6 °C; after one tau: 6·(1 − e⁻¹).
        let dt = 0.01;
        for _ in 0..10_000 {
            net.step(dt, 4000.0, [0.0; 3]);
        }
        let expect = 20.0 + 6.0 * (1.0 - (-1.0f64).exp());
        assert!(
            (net.node_C(0) - expect).abs() < 0.01,
            "{} vs {expect}",
            net.node_C(0)
        );
        assert!(
            net.sensor_C(0) < net.node_C(0) - 0.5,
            "sensor lags the node"
        );
        assert!((net.terms().growth_um[2] - 2.0 * (net.node_C(0) - 20.0)).abs() < 1e-12);
    }

    #[test]
    fn validation_names_the_bad_key() {
        let mut c = one_node(1.0, 10.0);
        c.sensors[0].node = "nope".into();
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("sensors[0]") && e.contains("nope"), "{e}");
    }
}
