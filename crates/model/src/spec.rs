//! The machine model as data: what a model file says, already validated and in internal units
//! (positions mm, translations µm, rotations µrad, compliances µm/N or µrad/N, temperatures °C).
//!
//! `parse.rs` builds a [`ModelSpec`] from TOML; `write.rs` writes one back (canonical units), so fit
//! and diagnose can edit a spec and save it. Conventions (chain, frames, signs) are in `mod.rs`.

use super::function::ErrorFunction;
use super::names::{Axis, ComponentId, Squareness};

/// Which side of the frame an axis sits on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Branch {
    /// Between the workpiece and the frame (e.g. a moving table).
    Workpiece,
    /// Between the frame and the tool (e.g. a column, a ram, a tool slide).
    Tool,
}

#[derive(Clone, Debug, PartialEq)]
pub struct AxisSpec {
    pub axis: Axis,
    pub branch: Branch,
    /// Where this carriage's reference point sits at q = 0, relative to the previous element of the
    /// chain (workpiece side: relative to the next element toward the frame), in mm.
    pub offset_mm: [f64; 3],
    /// Travel limits, informational; positions outside are flagged.
    pub travel_mm: Option<(f64, f64)>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ToolSpec {
    pub name: String,
    /// Nominal tool tip relative to the last tool-branch carriage (or the frame), mm.
    pub offset_mm: [f64; 3],
}

#[derive(Clone, Debug, PartialEq)]
pub struct ComponentSpec {
    pub id: ComponentId,
    /// Values in µm (translation) or µrad (rotation), argument = the component's axis position.
    pub function: ErrorFunction,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SquarenessSpec {
    pub kind: Squareness,
    /// The axis whose motion direction carries the tilt (either axis of the pair).
    pub on_axis: Axis,
    pub value_urad: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct SensorSpec {
    /// Column `T_<name>_C`.
    pub name: String,
    /// ΔT = T − reference, °C.
    pub reference_c: f64,
    /// First-order lag time constant (term d); `None` = the sensor is used as read.
    pub tau_s: Option<f64>,
    /// The recording/bus column read instead of `T_<name>_C`: a lag state driven by another
    /// context signal (e.g. `rpm`: heat input ∝ spindle speed, no sensor near the source). Its
    /// "ΔT" is then in that column's unit and the terms' per-K gains are per that unit.
    pub column: Option<String>,
    /// The lag's input is |reading|^exponent instead of the reading (`None` = 1): e.g. `rpm` with
    /// exponent 2, a heat input ∝ n² (bearing friction). Reference and gains are then per that
    /// power of the column's unit (rpm², µm/rpm²).
    pub exponent: Option<f64>,
}

impl SensorSpec {
    /// The value the lag state follows for `reading`: |reading|^exponent, or the reading itself.
    #[inline]
    pub fn input(&self, reading: f64) -> f64 {
        power_input(self.exponent, reading)
    }
    /// The column this sensor reads: `column`, else `T_<name>_C`.
    pub fn column_name(&self) -> String {
        self.column
            .clone()
            .unwrap_or_else(|| format!("T_{}_C", self.name))
    }
}

/// |reading|^exponent (`Some`), or the reading (`None`): the lag input of a sensor.
#[inline]
pub(crate) fn power_input(exponent: Option<f64>, reading: f64) -> f64 {
    match exponent {
        Some(p) => reading.abs().powf(p),
        None => reading,
    }
}

/// How a term's value is computed. Coefficients are in the target's unit (µm or µrad) per K, per
/// K², or per mm of travel, as named.
#[derive(Clone, Debug, PartialEq)]
pub enum ThermalKind {
    /// (a) Ni 1996 eq. 2: v = e0 + Σ b_i ΔT_i + Σ_i Σ_j c_ij ΔT_i ΔT_j.
    PolynomialDt {
        sensors: Vec<String>,
        e0: f64,
        b_per_k: Vec<f64>,
        c_per_k2: Vec<Vec<f64>>,
    },
    /// (b) Ni 1996 eq. 3, thermal part: v = q · (s0 + Σ s_i ΔT_i + Σ Σ d_jk ΔT_j ΔT_k), q = the
    /// target axis' position in mm; the geometric profile stays a separate component.
    Slope {
        sensors: Vec<String>,
        s0_per_mm: f64,
        s_per_mm_k: Vec<f64>,
        d_per_mm_k2: Vec<Vec<f64>>,
    },
    /// (c) Scale expansion: v = α · (q − origin) · (T − reference), α in ppm/K (1 ppm = 1e-3 µm/mm).
    Expansion {
        sensor: String,
        alpha_ppm_per_k: f64,
        origin_mm: f64,
        reference_c: f64,
    },
    /// (e) Spaan 1995 Ch5: one (e0, b) set per station along an axis, interpolated linearly in that
    /// axis' position and clamped (flagged) outside the stations.
    Stations {
        along: Axis,
        sensors: Vec<String>,
        stations_mm: Vec<f64>,
        e0: Vec<f64>,
        b_per_k: Vec<Vec<f64>>,
    },
}

#[derive(Clone, Debug, PartialEq)]
pub struct ThermalSpec {
    /// Term name, unique; CSV column `term_<name>_um`.
    pub name: String,
    /// The error motion the term adds to (its axis' chain position gives the Abbe arm).
    pub target: ComponentId,
    pub kind: ThermalKind,
}

#[derive(Clone, Debug, PartialEq)]
pub struct StrainSource {
    /// Column `strain_<name>_ue`.
    pub strain: String,
    pub gain_n_per_ue: f64,
    pub offset_ue: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ForceSpec {
    /// Column `F_<name>_N` (read directly unless `from_strain`).
    pub name: String,
    /// F = gain · (strain − offset) instead of reading `F_<name>_N`.
    pub from_strain: Option<StrainSource>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum LoadKind {
    /// v = compliance(q) · F, compliance in µm/N (µrad/N for a rotation target), q = the target
    /// component's axis position.
    Compliance {
        force: String,
        compliance: ErrorFunction,
    },
    /// Spaan 1995 eq. 4.1: v = ref(q) · F / F_ref · (lever − load_height) / lever.
    WeightAngular {
        force: String,
        reference: ErrorFunction,
        reference_force_n: f64,
        lever_mm: f64,
        load_height_mm: f64,
    },
}

#[derive(Clone, Debug, PartialEq)]
pub struct LoadSpec {
    pub name: String,
    pub target: ComponentId,
    pub kind: LoadKind,
}

/// A whole machine model.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelSpec {
    pub name: String,
    pub description: String,
    /// Data not measured on a real machine (examples shaped to a seed's reported ranges).
    pub synthetic: bool,
    /// Axes in chain order, workpiece → tool; the frame sits between the last workpiece-branch axis
    /// and the first tool-branch axis.
    pub axes: Vec<AxisSpec>,
    /// Axis and sign along which `tool_mm` sets the tool offset (mill: −z).
    pub tool_axis: (Axis, f64),
    pub tools: Vec<ToolSpec>,
    pub components: Vec<ComponentSpec>,
    pub squareness: Vec<SquarenessSpec>,
    pub sensors: Vec<SensorSpec>,
    pub thermal: Vec<ThermalSpec>,
    pub forces: Vec<ForceSpec>,
    pub load: Vec<LoadSpec>,
    /// Where the lags stood at the last row of the recording the model was fitted on (written by
    /// `diagnose --out`); read only by `retrocomp eval`, to continue that recording.
    pub lag_state: Option<LagState>,
}

/// The lag states at one time of a recording (`[lag_state]`): `retrocomp eval` starts each named
/// sensor's lag from its stored value when the new recording begins after `t_s` (the same
/// recording continued, or a later one: the first row's reading is held over the gap, so a gap
/// of many τ ends at that reading, as a fresh start would). The gateway starts from the readings.
#[derive(Clone, Debug, PartialEq)]
pub struct LagState {
    /// Recording time of the stored states, s.
    pub t_s: f64,
    /// (sensor name, lagged input) for sensors with a lag, in the sensor's input unit (°C, or the
    /// column's unit to its `exponent`).
    pub lagged: Vec<(String, f64)>,
}

impl ModelSpec {
    /// The chain as written in a file, e.g. `X F Y Z`.
    pub fn chain_string(&self) -> String {
        let mut parts: Vec<String> = Vec::new();
        let mut frame_done = false;
        for a in &self.axes {
            if a.branch == Branch::Tool && !frame_done {
                parts.push("F".into());
                frame_done = true;
            }
            parts.push(a.axis.upper().to_string());
        }
        if !frame_done {
            parts.push("F".into());
        }
        parts.join(" ")
    }

    /// Default name of a squareness term: ISO name, plus `_<axis>` when it is not on the axis ISO
    /// rotates (so two entries of one kind, as in Graves' lathe, get distinct names).
    pub fn squareness_term_name(s: &SquarenessSpec) -> String {
        if s.on_axis == s.kind.axes().1 {
            s.kind.iso_name().to_string()
        } else {
            format!("{}_{}", s.kind.iso_name(), s.on_axis)
        }
    }
}
