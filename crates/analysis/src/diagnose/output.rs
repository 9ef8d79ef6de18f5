//! Files written by `diagnose --out DIR`: the docs/diagnose-json.md report as JSON (`report.json`), the machine
//! model with the found terms added (`model.toml`, see `super::model_out`), the found terms as a
//! plain list (`found_terms.toml`: one `[[term]]` per finding, params in contract units, for people
//! and scripts; not a model file), and the SVG plots of [`super::plots`].

use std::path::Path;

use serde::Serialize;

use super::model_out::{ModelOut, write_model};
use super::{DiagnoseError, Diagnosis};
use retrocomp_model::MachineModel;
use retrocomp_model::recording::Recording;

#[derive(Serialize)]
struct TermToml<'a> {
    signal: &'a str,
    axis: String,
    #[serde(flatten)]
    model: &'a super::effects::EffectModel,
}

#[derive(Serialize)]
struct TermsToml<'a> {
    /// Sign convention of every term: error = actual − nominal (µm); correction = −error.
    convention: &'static str,
    term: Vec<TermToml<'a>>,
}

/// The found terms as TOML text.
pub fn terms_toml(d: &Diagnosis) -> String {
    let term = d
        .signals
        .iter()
        .flat_map(|s| {
            s.models.iter().map(move |m| TermToml {
                signal: &s.signal,
                axis: s.axis.to_string(),
                model: m,
            })
        })
        .collect();
    toml::to_string(&TermsToml {
        convention: "error = actual - nominal (um); correction = -error",
        term,
    })
    .expect("terms serialise to TOML")
}

/// Write report.json, model.toml, found_terms.toml and the plots into `dir` (created if
/// missing). `base` is the `--model` input (None: the simulation came from `sim_e*_um` columns).
/// Returns the files (report.json first, model.toml second) and what went into the model.
pub fn write_outputs(
    d: &Diagnosis,
    rec: &Recording,
    base: Option<&MachineModel>,
    dir: &Path,
) -> Result<(Vec<std::path::PathBuf>, ModelOut), DiagnoseError> {
    write_outputs_opts(d, rec, base, dir, false)
}

/// As [`write_outputs`]; `write_offset`: see `super::model_out::model_with_findings_opts`.
pub fn write_outputs_opts(
    d: &Diagnosis,
    rec: &Recording,
    base: Option<&MachineModel>,
    dir: &Path,
    write_offset: bool,
) -> Result<(Vec<std::path::PathBuf>, ModelOut), DiagnoseError> {
    std::fs::create_dir_all(dir)?;
    let mut written = vec![];
    let p = dir.join("report.json");
    std::fs::write(&p, serde_json::to_string_pretty(&d.report)?)?;
    written.push(p);
    let m = super::model_out::model_with_findings_opts(d, rec, base, write_offset)?;
    written.push(write_model(&m, dir)?);
    let p = dir.join("found_terms.toml");
    std::fs::write(&p, terms_toml(d))?;
    written.push(p);
    written.extend(super::plots::write_plots(d, dir)?);
    Ok((written, m))
}
