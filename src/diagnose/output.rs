//! Files written by `diagnose --out DIR`: the DESIGN §5 report as JSON, the found terms as TOML
//! (`found_terms.toml`: one `[[term]]` per finding, params in contract units, ready to be added to a
//! machine model), and the SVG plots of [`super::plots`].

use std::path::Path;

use serde::Serialize;

use super::Diagnosis;

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

/// Write report.json, found_terms.toml and the plots into `dir` (created if missing).
pub fn write_outputs(d: &Diagnosis, dir: &Path) -> anyhow::Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut written = vec![];
    let p = dir.join("report.json");
    std::fs::write(&p, serde_json::to_string_pretty(&d.report)?)?;
    written.push(p);
    let p = dir.join("found_terms.toml");
    std::fs::write(&p, terms_toml(d))?;
    written.push(p);
    written.extend(super::plots::write_plots(d, dir)?);
    Ok(written)
}
