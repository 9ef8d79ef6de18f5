//! Model drift per machine (issue 17 point 3): `retrocomp fleet` runs `diagnose` (the library,
//! [`retrocomp_analysis::diagnose`]) on a schedule over each machine's latest collected recording against that
//! machine's own model, and flags the machine whose residual against its model has grown.
//!
//! A machine's model was identified on that machine, so its residual (measured − model, µm, over
//! every error signal: docs/diagnose-json.md `rms_before_um`) starts at the measurement noise. The machine is
//! flagged **drifted** when that residual reaches `min_residual_um` *and* diagnose names the
//! physics that explains it (verdict `found` or `ambiguous`; the first finding is shown): a large
//! residual nobody can explain is reported as `unexplained`, not as drift of a known effect. The
//! first diagnosis of a machine is kept as its baseline, so the view shows how far the residual
//! grew. Files: the recording is the newest `*.csv` under `<collect dir>/<group>/<edge node>/`
//! ([`retrocomp_gateway::northbound::telemetry::recordings`] layout), the model is `<models dir>/<edge node>.toml`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Deserializer, Serialize};

use retrocomp_analysis::diagnose::report::{Finding, Report};
use retrocomp_analysis::diagnose::{self, select::Options};
use retrocomp_gateway::northbound::telemetry::TelemetryError;
use retrocomp_model::MachineModel;
use retrocomp_model::recording::Recording;

/// Diagnose a recording against a machine model (what `retrocomp diagnose --model` does).
/// Errors name the recording or the model file; the cause is their `source()`.
pub fn diagnose_against(recording: &Path, model: &Path) -> Result<Report, TelemetryError> {
    let rec = Recording::read_path(recording)
        .map_err(TelemetryError::setup(recording.display().to_string()))?;
    let m = MachineModel::from_toml_path(model)
        .map_err(|e| TelemetryError::Invalid(format!("{}: {e}", model.display())))?;
    let sims = diagnose::model_sim::simulate(&m, &rec)
        .map_err(TelemetryError::setup(model.display().to_string()))?;
    let d = diagnose::diagnose_with_sim(&rec, &sims, &Options::default())
        .map_err(TelemetryError::setup(recording.display().to_string()))?;
    Ok(d.report)
}

/// The newest complete recording (`*.csv`, by modification time) of a machine, if any.
pub fn latest_recording(collect_dir: &Path, group: &str, edge_node: &str) -> Option<PathBuf> {
    let dir = collect_dir.join(group).join(edge_node);
    std::fs::read_dir(dir)
        .ok()?
        .filter_map(Result::ok)
        .filter(|e| e.path().extension().is_some_and(|x| x == "csv"))
        .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
        .max()
        .map(|(_, p)| p)
}

/// Every machine with a collection directory: (group, edge node).
pub fn machines(collect_dir: &Path) -> Vec<(String, String)> {
    let mut out = vec![];
    let subdirs = |p: &Path| -> Vec<String> {
        std::fs::read_dir(p)
            .map(|rd| {
                rd.filter_map(Result::ok)
                    .filter(|e| e.path().is_dir())
                    .filter_map(|e| e.file_name().into_string().ok())
                    .collect()
            })
            .unwrap_or_default()
    };
    for g in subdirs(collect_dir) {
        for n in subdirs(&collect_dir.join(&g)) {
            out.push((g.clone(), n));
        }
    }
    out.sort();
    out
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DriftState {
    /// Residual below the threshold: the model still describes the machine.
    Ok,
    /// Residual at or above the threshold and diagnose names the effect: the model drifted.
    Drifted,
    /// Residual at or above the threshold, no effect explains it.
    Unexplained,
    /// No model for this machine, or diagnose failed (see `error`).
    Error,
}

impl DriftState {
    /// The state's one spelling (the JSON's, the table's).
    pub fn as_str(self) -> &'static str {
        match self {
            DriftState::Ok => "ok",
            DriftState::Drifted => "drifted",
            DriftState::Unexplained => "unexplained",
            DriftState::Error => "error",
        }
    }
}

/// The latest scheduled diagnosis of one machine (shown in the fleet view and its JSON; a
/// worker's result, `crate::dispatch`, carries it back to the host).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MachineDrift {
    pub state: DriftState,
    pub recording: String,
    pub model: String,
    /// Residual against the model, µm RMS over the error signals (docs/diagnose-json.md `rms_before_um`).
    /// NaN when there is none (JSON null).
    #[serde(deserialize_with = "nan_if_null")]
    pub rms_um: f64,
    /// The first diagnosis' residual of this machine, µm (NaN/null before one succeeded).
    #[serde(deserialize_with = "nan_if_null")]
    pub baseline_rms_um: f64,
    pub verdict: String,
    /// What explains the residual (diagnose's most important finding), when drifted. Read back
    /// leniently: a finding with a NaN (written as null) is dropped, not the whole result.
    #[serde(deserialize_with = "finding_or_none")]
    pub finding: Option<Finding>,
    pub diagnoses: u64,
    pub error: Option<String>,
}

/// Judge one diagnosis; `prev` is the machine's previous result (for its baseline and count).
pub fn judge(
    report: &Report,
    recording: &Path,
    model: &Path,
    min_residual_um: f64,
    prev: Option<&MachineDrift>,
) -> MachineDrift {
    let explained = matches!(report.verdict.as_str(), "found" | "ambiguous");
    let state = if report.rms_before_um < min_residual_um {
        DriftState::Ok
    } else if explained {
        DriftState::Drifted
    } else {
        DriftState::Unexplained
    };
    let baseline = prev
        .filter(|p| p.state != DriftState::Error)
        .map_or(report.rms_before_um, |p| p.baseline_rms_um);
    MachineDrift {
        state,
        recording: recording.display().to_string(),
        model: model.display().to_string(),
        rms_um: report.rms_before_um,
        baseline_rms_um: baseline,
        verdict: report.verdict.clone(),
        finding: (state == DriftState::Drifted)
            .then(|| report.findings.first().cloned())
            .flatten(),
        diagnoses: prev.map_or(0, |p| p.diagnoses) + 1,
        error: None,
    }
}

/// JSON writes a NaN as null: read it back as NaN.
fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

fn finding_or_none<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Finding>, D::Error> {
    let v = Option::<serde_json::Value>::deserialize(d)?;
    Ok(v.and_then(|v| match serde_json::from_value(v) {
        Ok(f) => Some(f),
        Err(e) => {
            tracing::warn!(%e, "fleet: a finding that cannot be read back (a NaN?) is dropped");
            None
        }
    }))
}

/// A diagnosis made without the machine's history (a worker's, `crate::dispatch`) given that
/// history: the baseline and count [`judge`] and [`failed`] would have given with `prev`.
pub fn with_history(mut d: MachineDrift, prev: Option<&MachineDrift>) -> MachineDrift {
    if d.state == DriftState::Error {
        d.baseline_rms_um = prev.map_or(f64::NAN, |p| p.baseline_rms_um);
        d.diagnoses = prev.map_or(0, |p| p.diagnoses);
    } else {
        if let Some(p) = prev.filter(|p| p.state != DriftState::Error) {
            d.baseline_rms_um = p.baseline_rms_um;
        }
        d.diagnoses = prev.map_or(0, |p| p.diagnoses) + 1;
    }
    d
}

/// A failed diagnosis (no model, unreadable recording…), keeping the machine's history.
pub fn failed(
    recording: &Path,
    model: &Path,
    error: String,
    prev: Option<&MachineDrift>,
) -> MachineDrift {
    MachineDrift {
        state: DriftState::Error,
        recording: recording.display().to_string(),
        model: model.display().to_string(),
        rms_um: f64::NAN,
        baseline_rms_um: prev.map_or(f64::NAN, |p| p.baseline_rms_um),
        verdict: String::new(),
        finding: None,
        diagnoses: prev.map_or(0, |p| p.diagnoses),
        error: Some(error),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_spells_each_state_as_the_json_does() {
        for s in [
            DriftState::Ok,
            DriftState::Drifted,
            DriftState::Unexplained,
            DriftState::Error,
        ] {
            assert_eq!(serde_json::to_value(s).unwrap(), s.as_str());
        }
    }

    fn report(verdict: &str, rms: f64) -> Report {
        Report {
            verdict: verdict.into(),
            rms_before_um: rms,
            mismatch: vec![],
            sensor_faults: vec![],
            findings: vec![],
            alternatives: vec![],
            dropped: vec![],
            forward_check: vec![],
        }
    }

    #[test]
    fn drift_needs_a_grown_residual_and_an_explanation() {
        let (r, m) = (Path::new("r.csv"), Path::new("m.toml"));
        let first = judge(&report("none", 0.3), r, m, 2.0, None);
        assert_eq!(first.state, DriftState::Ok);
        let second = judge(&report("found", 5.0), r, m, 2.0, Some(&first));
        assert_eq!(second.state, DriftState::Drifted);
        assert_eq!(second.baseline_rms_um, 0.3);
        assert_eq!(second.diagnoses, 2);
        assert_eq!(
            judge(&report("none", 5.0), r, m, 2.0, None).state,
            DriftState::Unexplained
        );
        assert_eq!(
            judge(&report("found", 1.0), r, m, 2.0, None).state,
            DriftState::Ok
        );
    }

    #[test]
    fn a_workers_diagnosis_given_the_history_is_the_in_process_one() {
        let (r, m) = (Path::new("r.csv"), Path::new("m.toml"));
        let first = judge(&report("none", 0.3), r, m, 2.0, None);
        let err = failed(r, m, "no model".into(), Some(&first));
        let fresh = judge(&report("found", 5.0), r, m, 2.0, None);
        let here = judge(&report("found", 5.0), r, m, 2.0, Some(&err));
        let there = with_history(fresh, Some(&err));
        // After an error the baseline starts again (as judge does), the count goes on.
        assert_eq!((there.baseline_rms_um, there.diagnoses), (5.0, 2));
        assert_eq!(
            serde_json::to_value(&there).unwrap(),
            serde_json::to_value(&here).unwrap()
        );
        let e2 = with_history(failed(r, m, "x".into(), None), Some(&here));
        let e2_here = failed(r, m, "x".into(), Some(&here));
        assert_eq!(
            serde_json::to_value(&e2).unwrap(),
            serde_json::to_value(&e2_here).unwrap()
        );
        // Through JSON and back: NaN travels as null.
        let back: MachineDrift =
            serde_json::from_str(&serde_json::to_string(&failed(r, m, "x".into(), None)).unwrap())
                .unwrap();
        assert!(back.rms_um.is_nan() && back.baseline_rms_um.is_nan());
        assert_eq!(back.state, DriftState::Error);
    }
}
