//! The `[sink.quadrature]` section of the field file: per axis the count resolution and sign, the
//! receiver's edge limits and, for the `gpio` feature, the two output lines. Units: µm per count,
//! ns, Hz. `state_file`: where the counts the controller holds are persisted ([`super::held`]);
//! `[sink.quadrature.trace]`: the edge trace ([`super::trace`]); per axis `simulated_native`: a
//! simulated scale for the simulated sink ([`super::native`]).

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Where the held counts are persisted when `state_file` is not given.
pub(crate) const DEFAULT_STATE_FILE: &str = "/var/lib/retrocomp/quadrature-held.toml";

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuadratureSink {
    #[serde(rename = "axis")]
    pub axes: Vec<QuadratureAxis>,
    /// The held-counts file (relative paths: to the config file's directory once resolved);
    /// default `DEFAULT_STATE_FILE`. Delete it after homing or power-cycling the controller.
    #[serde(default)]
    pub state_file: Option<PathBuf>,
    /// The edge trace: every level the injector threads write (absent: no trace).
    #[serde(default)]
    pub trace: Option<super::trace::TraceConfig>,
}

impl QuadratureSink {
    /// The held-counts file, relative paths taken against `base` (the config's directory).
    pub fn state_path(&self, base: &Path) -> PathBuf {
        let p = self
            .state_file
            .clone()
            .unwrap_or_else(|| PathBuf::from(DEFAULT_STATE_FILE));
        if p.is_relative() { base.join(p) } else { p }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuadratureAxis {
    pub axis: String,
    /// Slide travel per count (per A/B edge), µm.
    pub resolution_um: f64,
    /// +1 if the encoder counts up when the axis moves +.
    pub count_sign: i8,
    /// Receiver's minimum edge separation, ns (RS-422 at 400 kHz: 400).
    pub min_edge_gap_ns: u64,
    pub max_inject_rate_hz: f64,
    /// GPIO lines (chip, A offset, B offset) for the `gpio` feature; None = simulated.
    #[serde(default)]
    pub gpio: Option<GpioLines>,
    /// Simulated sink only: a simulated scale's native edges merged with the injected ones.
    #[serde(default)]
    pub simulated_native: Option<super::native::SimulatedNative>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpioLines {
    pub chip: String,
    pub line_a: u32,
    pub line_b: u32,
}
