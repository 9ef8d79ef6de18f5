//! The true machine's hidden physics: everything the visible geometric model does not know.
//! Each effect is a small state machine stepped by the world; all of them are off unless configured.

pub(crate) mod cutting;
pub mod faults;
pub(crate) mod mechanics;
pub(crate) mod thermal;

pub use cutting::{CuttingConfig, GaugeConfig};
pub use mechanics::{BacklashConfig, CyclicConfig};
pub use thermal::{
    Coupling, NodeConfig, SensorConfig, ThermalConfig, ThermalEffect, ThermalNet, ThermalTerms,
};

use serde::{Deserialize, Serialize};

/// Axis name in configs (`axis = "x"`).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum AxisName {
    X,
    Y,
    Z,
}

impl AxisName {
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn as_str(self) -> &'static str {
        ["x", "y", "z"][self as usize]
    }
}

/// Three per-axis numbers in a config (`{ x = 0.01, z = 0.02 }`), missing axes are 0.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Vec3 {
    #[serde(default)]
    pub x: f64,
    #[serde(default)]
    pub y: f64,
    #[serde(default)]
    pub z: f64,
}

impl Vec3 {
    pub fn get(&self, axis: usize) -> f64 {
        [self.x, self.y, self.z][axis]
    }
}
