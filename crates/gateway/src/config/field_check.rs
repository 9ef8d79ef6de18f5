//! A field file and the model it names, checked together without opening any source or sink
//! (`retrocomp check-config FIELD.toml`, and `retrocomp run` before it starts anything): the field
//! file's own checks ([`FieldConfig::load_for_run`]), the model loaded from `[model] path` (a
//! missing or broken model names the field file, line and key that asked for it), and every
//! channel the model needs delivered by a configured source. A model input no source delivers
//! would be read as missing forever: the axes would never be compensated, silently.

use std::path::{Path, PathBuf};

use crate::config::FieldConfig;
use crate::engine::ErrorModel;
use crate::engine::model_adapter::MachineModelAdapter;
use retrocomp_model::{ConfigError, ConfigIssue, MachineModel};
use std::sync::Arc;

/// A field file that passed every offline check, with its model ready for the engine.
#[derive(Debug)]
pub struct CheckedField {
    pub cfg: FieldConfig,
    /// The model file used (`--model` or `[model] path`, resolved against the field file).
    pub model_path: PathBuf,
    pub model: MachineModelAdapter,
    /// Optional model inputs (forces, strains) that no source delivers: the load terms stay out and
    /// `compensation.<axis>.partial` stays active while the box runs.
    pub optional_missing: Vec<Arc<str>>,
}

/// The field file's key that names the model.
const MODEL_KEY: &str = "model.path";

fn at_key(field: &Path, key: &str, what: String) -> ConfigIssue {
    let text = std::fs::read_to_string(field).unwrap_or_default();
    ConfigIssue {
        file: field.display().to_string(),
        line: retrocomp_bus::config::locate(&text, key).unwrap_or(0),
        column: 0,
        key: key.into(),
        message: what,
    }
}

/// Load `field` for a run and its model (`model_override` is `--model`), and check that every
/// channel the model requires is delivered by a source (or estimated from delivered ones by a
/// `[[recovery]]`). Opens no source, sink or listener.
pub fn check_field(
    field: &Path,
    model_override: Option<&Path>,
) -> Result<CheckedField, ConfigError> {
    let cfg = FieldConfig::load_for_run(field)?;
    let base = field.parent().unwrap_or(Path::new("."));
    let model_path = match (model_override, &cfg.model) {
        (Some(p), _) => p.to_path_buf(),
        (None, Some(m)) => base.join(&m.path),
        (None, None) => {
            return Err(ConfigError {
                issues: vec![at_key(
                    field,
                    "model",
                    "expected [model] path = \"MODEL.toml\" (relative to this file), or --model"
                        .into(),
                )],
            });
        }
    };
    let model = MachineModel::from_toml_path(&model_path).map_err(|e| {
        let asked_by = match model_override {
            Some(_) => ConfigIssue {
                file: field.display().to_string(),
                line: 0,
                column: 0,
                key: "--model".into(),
                message: format!("the model {} cannot be used:", model_path.display()),
            },
            None => at_key(
                field,
                MODEL_KEY,
                format!(
                    "expected a machine model TOML; {} cannot be used:",
                    model_path.display()
                ),
            ),
        };
        let mut issues = vec![asked_by];
        issues.extend(e.issues);
        ConfigError { issues }
    })?;
    let model = MachineModelAdapter::new(model);
    let optional_missing = check_channels(&cfg, &model).map_err(|what| {
        let key = if model_override.is_some() {
            ""
        } else {
            MODEL_KEY
        };
        let mut issue = at_key(field, key, what);
        if model_override.is_some() {
            issue.key = "--model".into();
        }
        ConfigError {
            issues: vec![issue],
        }
    })?;
    for ch in &optional_missing {
        tracing::warn!(
            "no source delivers {ch}, an optional input of the model: its load terms stay out (fault {ch} no_source for as long as the box runs)"
        );
    }
    Ok(CheckedField {
        cfg,
        model_path,
        model,
        optional_missing,
    })
}

/// The optional inputs of `model` that no source of `cfg` delivers (each a `no_source` fault while
/// the box runs). A required one missing is the start-up refusal of [`check_field`], not listed.
pub(crate) fn undelivered_optional(cfg: &FieldConfig, model: &dyn ErrorModel) -> Vec<Arc<str>> {
    check_channels(cfg, model).unwrap_or_default()
}

/// Every required channel of `model` delivered; returns the optional ones that are not.
fn check_channels(cfg: &FieldConfig, model: &dyn ErrorModel) -> Result<Vec<Arc<str>>, String> {
    let mut have: Vec<&str> = cfg.source_channels();
    // A recovery estimates its target from neighbours: delivered when they all are.
    for r in &cfg.recoveries {
        if r.neighbours.iter().all(|n| have.contains(&n.as_str())) {
            have.push(r.target.as_str());
        }
    }
    let optional = model.optional_channels();
    let missing: Vec<Arc<str>> = model
        .required_channels()
        .into_iter()
        .filter(|c| !have.contains(&&**c))
        .collect();
    let (optional_missing, required_missing): (Vec<Arc<str>>, Vec<Arc<str>>) =
        missing.into_iter().partition(|c| optional.contains(c));
    if required_missing.is_empty() {
        return Ok(optional_missing);
    }
    let names: Vec<&str> = required_missing.iter().map(|c| &**c).collect();
    Err(format!(
        "the model needs {} but no source delivers {} (sources deliver {have:?}): expected a source channel for each (e.g. a [[modbus.source]] channel), or a model without these inputs; without them no axis would ever be compensated",
        names.join(", "),
        if names.len() == 1 { "it" } else { "them" },
    ))
}
