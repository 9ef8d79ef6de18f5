//! The diagnose report: the JSON object of docs/diagnose-json.md (keys fixed: outside tools score it) and its
//! plain-text rendering for people.

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Mismatch {
    pub signal: String,
    #[serde(rename = "where")]
    pub where_: String,
    pub rms_um: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Evidence {
    pub delta_bic: f64,
    pub p_value: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Finding {
    pub effect: String,
    pub axis: String,
    pub signal: String,
    pub explanation: String,
    pub equation: String,
    pub params: Map<String, Value>,
    pub ci95: Map<String, Value>,
    pub evidence: Evidence,
    pub rms_after_um: f64,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    /// Thermal terms on recordings with no axis column: the driver's range fitted vs seen at the
    /// rolling origins (`regimes.rs`). An added key.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub driver_range: Option<super::regime_check::DriverRange>,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct AlternativeOut {
    pub effect: String,
    pub why_not: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub experiment: Option<String>,
}

/// The final model of one signal run forward once (`forward_check.rs`): gains and offset fitted
/// on the first `fit_rows` rows, RMS (µm) of measured − sim on the `scored_rows` after them with
/// the offset alone (`rms_sim_um`) and with the found terms (`rms_model_um`). Not a docs/diagnose-json.md
/// key: an added one (`forward_check`, absent without findings).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ForwardCheck {
    pub signal: String,
    pub fit_rows: usize,
    pub scored_rows: usize,
    pub rms_sim_um: f64,
    pub rms_model_um: f64,
    /// On recordings with no axis column: the rolling origin over the recording's regimes, the
    /// named physics against the simulation alone and a statistical compensation fit, and what
    /// `--out` writes (`regimes.rs`). An added key.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub regimes: Option<super::regime_check::RegimeCheck>,
}

/// A term selected at some step and not in the final model: replaced by the exchange step, or
/// dropped by parsimony after the final joint refit (issue 12 point 3). Not a docs/diagnose-json.md key: an
/// added one (`dropped`, absent when nothing was dropped).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Dropped {
    pub effect: String,
    pub axis: String,
    pub signal: String,
    /// The candidate as selected, e.g. `thermal_lag(T_8_C)` or `thermal_lag(rpm)`.
    pub term: String,
    /// `ci_includes_zero` (the 95 % interval of its gain includes 0 once every term is refitted
    /// jointly) or `no_heldout_gain` (removing it does not raise the held-out RMS by the
    /// acceptance bar, `Options::cv_min_gain`) or `no_forward_gain` (recordings with axes, a term
    /// that follows a changing context column: removing it lowers the forward check's RMS by more than that bar and by more, relatively,
    /// than it raises the held-out RMS) or `exchanged` (replaced by the exchange step after
    /// forward selection by the term(s) in `replaced_by`, which explain the residual better given
    /// the other terms and do not raise the held-out RMS).
    pub reason: String,
    /// Held-out RMS (µm; forward on thermal tests) with every kept term and this one, and without it
    /// (for `exchanged`: the accepted set before the exchange, and after it; for
    /// `no_forward_gain`: the forward check's RMS, `forward_check.rs`).
    pub heldout_rms_with_um: f64,
    pub heldout_rms_without_um: f64,
    /// Which error the two RMS fields hold: `heldout` (the selection's held-out error:
    /// leave-one-block-out, or forward on thermal tests) or `forward_check` (the forward check's,
    /// for `no_forward_gain`). The field names predate the second; a reader should not have to
    /// know the reason to read them.
    #[serde(default = "heldout_score")]
    pub score: String,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub replaced_by: Vec<String>,
}

fn heldout_score() -> String {
    "heldout".into()
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Report {
    pub verdict: String,
    pub rms_before_um: f64,
    pub mismatch: Vec<Mismatch>,
    /// Broken sensors, found before (and never explained as) physics: an added key, absent when
    /// there is none (`sensor_faults.rs`). Not findings: the verdict reads the findings only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sensor_faults: Vec<super::sensor_faults::SensorFault>,
    pub findings: Vec<Finding>,
    pub alternatives: Vec<AlternativeOut>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dropped: Vec<Dropped>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub forward_check: Vec<ForwardCheck>,
}

/// What each effect means, in words (the report's "explanation").
pub fn explanation(effect: &str) -> &'static str {
    match effect {
        "scale_error" => "error grows linearly with the axis' own position (scale / lead error)",
        "backlash" => "direction-dependent offset: the error jumps when the axis reverses",
        "reversal_profile" => "direction-dependent offset whose size changes along the axis",
        "cyclic_error" => "error periodic in the axis' own position (lead-screw pitch or encoder)",
        "squareness" => "error proportional to another axis' position (out-of-square axes)",
        "straightness" => "a smooth bow of this error across another axis' travel",
        "abbe" => {
            "error proportional to the tool/probe offset times an angular error along the axis"
        }
        "thermal_drift" => "error follows a temperature with no lag",
        "thermal_lag" => "error follows a temperature through a first-order lag",
        "thermal_expansion" => {
            "scale grows with temperature: error proportional to position times temperature rise"
        }
        "force_deflection" => {
            "error proportional to the measured force/strain (compliance under load)"
        }
        "servo_lag" => "error proportional to velocity (following error / servo gain mismatch)",
        "reversal_spike" => {
            "a spike after each reversal that decays with distance travelled (friction)"
        }
        "time_drift" => "slow drift in time with no measured cause",
        _ => "unknown effect",
    }
}

fn fmt_val(v: &Value) -> String {
    match v {
        Value::Number(n) => n.as_f64().map_or(n.to_string(), |f| format!("{f:.4}")),
        Value::Array(a) => format!("[{}]", a.iter().map(fmt_val).collect::<Vec<_>>().join(", ")),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

impl Report {
    /// Human-readable report.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "verdict: {}   (residual RMS before: {:.3} µm)\n",
            self.verdict, self.rms_before_um
        );
        if !self.mismatch.is_empty() {
            s.push_str("\nwhere the simulation and the recording disagree:\n");
            for m in &self.mismatch {
                s.push_str(&format!(
                    "  {:<6} {:>8.3} µm RMS  {}\n",
                    m.signal, m.rms_um, m.where_
                ));
            }
        }
        if !self.sensor_faults.is_empty() {
            s.push_str("\nsensor faults (left out of the physics search):\n");
            for f in &self.sensor_faults {
                s.push_str(&format!(
                    "  sensor_fault {} of {}: rows {}..{} (t_s {:.0}..{:.0}): {}\n",
                    f.kind, f.column, f.rows[0], f.rows[1], f.t_s[0], f.t_s[1], f.evidence
                ));
            }
        }
        if self.findings.is_empty() {
            s.push_str("\nno candidate effect earns its place (ΔBIC, Holm-corrected F-test, held-out blocks)\n");
        }
        for (i, f) in self.findings.iter().enumerate() {
            s.push_str(&format!(
                "\n{}. {} on {} ({}): {}\n",
                i + 1,
                f.effect,
                f.axis,
                f.signal,
                f.explanation
            ));
            s.push_str(&format!("   {}\n", f.equation));
            for (k, v) in &f.params {
                let ci = f
                    .ci95
                    .get(k)
                    .map(|c| format!("  95% CI {}", fmt_val(c)))
                    .unwrap_or_default();
                s.push_str(&format!("   {k} = {}{ci}\n", fmt_val(v)));
            }
            s.push_str(&format!(
                "   evidence: ΔBIC {:.1}, p {:.2e}; RMS after {:.3} µm; held-out RMS {:.3} → {:.3} µm\n",
                f.evidence.delta_bic, f.evidence.p_value, f.rms_after_um, f.heldout_rms_before_um, f.heldout_rms_after_um
            ));
            if let Some(d) = &f.driver_range {
                s.push_str(&super::regime_check::range_text(d));
            }
        }
        if !self.forward_check.is_empty() {
            s.push_str("\nforward check (the found terms' gains and the offset refitted on the first rows):\n");
            for f in &self.forward_check {
                s.push_str(&format!(
                    "  {}: fitted on the first {} rows, RMS on the {} after them: {:.3} µm with the offset alone, {:.3} µm with the found terms\n",
                    f.signal, f.fit_rows, f.scored_rows, f.rms_sim_um, f.rms_model_um
                ));
                if let Some(c) = &f.regimes {
                    s.push_str(&super::regime_check::to_text(&f.signal, c));
                }
            }
        }
        if !self.alternatives.is_empty() {
            s.push_str("\nalternatives:\n");
            for a in &self.alternatives {
                s.push_str(&format!("  {}: {}\n", a.effect, a.why_not));
            }
        }
        if !self.dropped.is_empty() {
            s.push_str(
                "\nselected, then dropped (exchange step or parsimony after the final refit):\n",
            );
            for d in &self.dropped {
                let by = if d.replaced_by.is_empty() {
                    String::new()
                } else {
                    format!(" by {}", d.replaced_by.join(" + "))
                };
                let score = if d.score == "forward_check" {
                    "forward-check"
                } else {
                    "held-out"
                };
                s.push_str(&format!(
                    "  {} on {}: {}{by} ({score} RMS {:.3} µm with it, {:.3} µm without)\n",
                    d.term, d.signal, d.reason, d.heldout_rms_with_um, d.heldout_rms_without_um
                ));
            }
        }
        s
    }
}
