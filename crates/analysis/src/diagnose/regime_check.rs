//! What the regime check reports (JSON `forward_check[].regimes` and `findings[].driver_range`,
//! docs/diagnose-json.md) and its lines in the text report. The check itself is `regimes.rs`;
//! these are plain data, below both it and `report.rs`. Units: µm for RMS, the driver's own unit
//! for its ranges, s for origins.

use serde::{Deserialize, Serialize};

/// The regime check of one signal (JSON: `forward_check[].regimes`, docs/diagnose-json.md).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct RegimeCheck {
    /// What the origins follow: `rpm` (spindle speed steps) or `time` (forward time blocks).
    pub regimes_by: String,
    /// t_s of each origin.
    pub origins_t_s: Vec<f64>,
    /// Forward RMS (µm) of the simulation alone (offset), of the named terms, of the statistical fit.
    pub rms_sim_um: f64,
    pub rms_named_um: f64,
    pub rms_statistical_um: f64,
    /// What `--out` writes for this signal: `named`, `statistical` or `simulation` (no term).
    pub written: String,
    /// Named terms left out of the model: their driver left its fitted range and their forward
    /// error grew there.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub left_out: Vec<String>,
    /// The statistical fit on every row (as written when `written` is `statistical`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub statistical_terms: Vec<String>,
}

/// Where a finding's driver was fitted and where the rolling origin drove it (JSON:
/// `findings[].driver_range`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DriverRange {
    pub driver: String,
    /// Range of the driver over the whole recording (what the written gains were fitted on).
    pub fitted: [f64; 2],
    /// The origin where the driver went furthest beyond the range of the rows before it, with
    /// that range (`fitted_before`) and the range seen after it; absent when it never left it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub worst: Option<Excursion>,
    /// Forward RMS (µm) over the origins where it left its range, with and without the term.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_with_um: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms_without_um: Option<f64>,
    /// Left out of `model.toml` (its forward error grew where it extrapolated).
    pub left_out: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Excursion {
    pub origin_t_s: f64,
    pub fitted_before: [f64; 2],
    pub seen_after: [f64; 2],
}

/// The report's lines for one signal's check.
pub(super) fn to_text(signal: &str, c: &RegimeCheck) -> String {
    let mut s = format!(
        "  {signal}: rolling origin over {} regimes ({} origins): forward RMS {:.3} µm simulation alone, {:.3} µm named physics, {:.3} µm statistical compensation fit; model.toml holds the {}\n",
        c.regimes_by,
        c.origins_t_s.len(),
        c.rms_sim_um,
        c.rms_named_um,
        c.rms_statistical_um,
        match c.written.as_str() {
            "statistical" => "statistical fit",
            "simulation" => "simulation alone",
            _ => "named physics",
        }
    );
    if c.rms_statistical_um < c.rms_named_um {
        s.push_str(&format!(
            "  {signal}: the named physics does NOT beat a purely statistical compensation fit forward ({:.3} against {:.3} µm)\n",
            c.rms_named_um, c.rms_statistical_um
        ));
    }
    for l in &c.left_out {
        s.push_str(&format!(
            "  {signal}: {l} left out of model.toml: its driver left the range it was fitted on and its forward error grew there\n"
        ));
    }
    s
}

/// The report's line for a finding's driver range.
pub(super) fn range_text(d: &DriverRange) -> String {
    let [lo, hi] = d.fitted;
    let mut s = format!("   driver {} fitted over [{lo:.3}, {hi:.3}]", d.driver);
    if let Some(w) = &d.worst {
        s.push_str(&format!(
            "; at t_s {:.0} fitted over [{:.3}, {:.3}], then seen over [{:.3}, {:.3}]",
            w.origin_t_s, w.fitted_before[0], w.fitted_before[1], w.seen_after[0], w.seen_after[1]
        ));
    }
    if let (Some(a), Some(b)) = (d.rms_with_um, d.rms_without_um) {
        s.push_str(&format!(
            "; forward RMS where it left its range {a:.3} µm with the term, {b:.3} µm without{}",
            if d.left_out {
                ": left out of model.toml"
            } else {
                ""
            }
        ));
    }
    s.push('\n');
    s
}
