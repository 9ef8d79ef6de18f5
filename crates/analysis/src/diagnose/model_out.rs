//! `diagnose --out DIR` → `DIR/model.toml`: a machine model (`retrocomp_model`, loadable by `retrocomp
//! run`, `eval` and `check-config`) that is the input model with the found terms added, or — when the
//! simulation came from the recording's `sim_e*_um` columns — a default chain of the recording's axes
//! holding only the found terms.
//!
//! Sign: every finding is error = actual − nominal (µm) added to the simulation, and so is every
//! model term; correction = −error. Mapping (effect → model slot):
//! - scale, backlash, reversal profile, cyclic → bidirectional table of the own-axis positioning
//!   component EXX/EYY/EZZ (forward = dir +1 values, reverse = dir −1), merged with the base
//!   model's component of that id (resampled on a grid fine enough for the cyclic period, with a
//!   node at each reversal-zone edge);
//! - straightness of signal a along axis o → table of EAO (translation along a while o moves);
//! - squareness of a vs o → `[[squareness]]` EC0Y/EB0Z/EA0Z on axis o (sign per `docs/model.md`);
//! - abbe → a rotation component of the own axis whose Abbe arm is the tool length;
//! - thermal drift / lag → sensor (τ) + `polynomial_dt` term; thermal expansion → `expansion` term;
//! - force deflection → force (direct, or from a strain with gain 1 N/µε) + constant compliance.
//!
//! Every mapped term is CHECKED: the model with the term minus the model without it, evaluated on the
//! recording's inputs, must reproduce the finding's own forward model within 2 % + 0.02 µm RMS.
//! A term that fails (e.g. a rotation whose Abbe arm also holds a z travel), an effect with no slot
//! in the schema (servo_lag, reversal_spike, time_drift, force on a non-force channel) and the
//! constant offset between recording and simulation (a measurement zero, not physics) are listed in
//! a comment block at the top of the TOML and in the report — never silently dropped.

use super::model_slots::{Item, add_item};
use super::{DiagnoseError, Diagnosis};
use crate::fit::to_model::to_checked_toml;
use retrocomp_model::recording::{AXES, Recording};
use retrocomp_model::{Axis, MachineModel, ModelSpec};
use retrocomp_model::{AxisSpec, Branch, ToolSpec};

/// Relative and absolute tolerance (RMS over the recording) of the per-term check.
const CHECK_REL: f64 = 0.02;
const CHECK_ABS_UM: f64 = 0.02;

/// The written model and what went where.
#[derive(Debug)]
pub struct ModelOut {
    /// TOML text: comment block, then the canonical model.
    pub toml: String,
    pub model: MachineModel,
    /// One line saying what the base was.
    pub base: String,
    /// "effect on axis → slot" per added term.
    pub added: Vec<String>,
    /// Findings (or parts) not in the model, with parameters and the reason.
    pub not_in_model: Vec<String>,
}

/// Build the model: `base` is the `--model` input, `None` when the simulation came from columns.
pub fn model_with_findings(
    d: &Diagnosis,
    rec: &Recording,
    base: Option<&MachineModel>,
) -> Result<ModelOut, DiagnoseError> {
    model_with_findings_opts(d, rec, base, false)
}

/// As [`model_with_findings`]; with `write_offset` the joint refit's constant offset of each signal
/// is written too, as `e0` of that signal's last added `polynomial_dt` term (`--fit-offset`: for a
/// simulation that was itself fitted on this recording, whose intercept was fitted without the
/// found terms).
pub(super) fn model_with_findings_opts(
    d: &Diagnosis,
    rec: &Recording,
    base: Option<&MachineModel>,
    write_offset: bool,
) -> Result<ModelOut, DiagnoseError> {
    let mut spec = match base {
        Some(m) => m.spec().clone(),
        None => default_spec(rec)?,
    };
    let padded = if base.is_none() {
        with_placeholder_axes(&spec, rec)?
    } else {
        None
    };
    let placeholder = padded.as_ref().map(|(_, p)| p.clone());
    let rec = padded.as_ref().map_or(rec, |(r, _)| r);
    let base_line = base_line(base, &spec, placeholder.as_deref());
    let ctx = &d.context;
    let mut added = vec![];
    let mut not_in_model = vec![];
    let mut current =
        simulate_spec(&spec, rec).map_err(|e| DiagnoseError::BaseModel(Box::new(e)))?;
    for s in &d.signals {
        let axis = Axis::from_letter(s.axis).expect("signal axis is x, y or z");
        let (models, refit_note) = writable_refit(s, ctx, &spec, rec, axis);
        if let Some(n) = refit_note {
            added.push(n);
        }
        // Constant offset: the refit's intercept, i.e. the mean residual left after all terms.
        let mut left = s.residual_before.clone();
        for m in &models {
            if let Ok(v) = m.evaluate(s.axis, ctx) {
                left.iter_mut().zip(v).for_each(|(l, e)| *l -= e);
            }
        }
        let offset = left.iter().sum::<f64>() / left.len().max(1) as f64;
        let mut offset_pending = write_offset && !models.is_empty() && offset.abs() > 1e-9;
        if !write_offset && !models.is_empty() && offset.abs() > 1e-9 {
            not_in_model.push(format!(
                "{}: constant offset {offset:+.3} µm between recording and simulation (a measurement zero, not a machine term)",
                s.signal
            ));
        }
        for m in &models {
            let item = Item {
                signal: &s.signal,
                axis,
                model: m,
            };
            let expected = m.evaluate(s.axis, ctx).ok();
            let mut trial = spec.clone();
            let slot = match add_item(&mut trial, &item, rec) {
                Ok(slot) => slot,
                Err(why) => {
                    not_in_model.push(describe(&item, &why));
                    continue;
                }
            };
            let sim = simulate_spec(&trial, rec);
            let check = match (&sim, &expected) {
                (Ok(sim), Some(exp)) => {
                    reproduces(&sim[axis.index()], &current[axis.index()], exp, &slot)
                }
                (Err(e), _) => Err(format!("{slot}: the model does not evaluate: {e:#}")),
                (_, None) => Err("the recording lacks an input it needs".into()),
            };
            match check {
                Ok(()) => {
                    spec = trial;
                    current = sim.expect("checked");
                    added.push(format!("{} on {} ({}) → {slot}", m.id(), s.axis, s.signal));
                }
                Err(why) => not_in_model.push(describe(&item, &why)),
            }
        }
        if offset_pending && let Some(note) = offset_into_e0(&mut spec, &s.signal, offset) {
            added.push(note);
            offset_pending = false;
            current = simulate_spec(&spec, rec)?;
        }
        if offset_pending {
            not_in_model.push(format!(
                "{}: constant offset {offset:+.3} µm (no polynomial_dt term of this signal to hold it)",
                s.signal
            ));
        }
    }
    // The lags at the recording's last row, so `eval` can continue this recording (`[lag_state]`;
    // replaces any state the base model carried, `None` without `t_s` or lags).
    spec.lag_state =
        super::model_sim::final_lag_state(&MachineModel::from_spec(spec.clone()), rec)?;
    let (text, model) = to_checked_toml(spec)?;
    let head = header(&base_line, placeholder.as_deref(), &added, &not_in_model);
    Ok(ModelOut {
        toml: head + &text,
        model,
        base: base_line,
        added,
        not_in_model,
    })
}

/// What the written model is based on (the header's "Base:" line and `ModelOut::base`).
fn base_line(base: Option<&MachineModel>, spec: &ModelSpec, placeholder: Option<&str>) -> String {
    let mut line = match base {
        Some(m) => format!(
            "the input model `{}` (--model) with the found terms added",
            m.name()
        ),
        None => format!(
            "no --model given (simulation = the recording's sim_e*_um columns): a default chain \"{}\" holding ONLY the found terms; add them to your own model or rerun with --model",
            spec.chain_string()
        ),
    };
    if let Some(p) = &placeholder {
        line.push_str(&format!(
            " ({p}: placeholder axis, held at 0; a model with no position-dependent term runs without it)"
        ));
    }
    line
}

/// On the default chain, the axes the recording lacks (the placeholder of a one-axis recording,
/// or every axis of a thermal-only one) are evaluated at 0 mm: the recording with those columns
/// added, and their names; `None` when it has every axis.
fn with_placeholder_axes(
    spec: &ModelSpec,
    rec: &Recording,
) -> Result<Option<(Recording, String)>, DiagnoseError> {
    let missing: Vec<String> = spec
        .axes
        .iter()
        .map(|a| format!("{}_mm", a.axis.lower()))
        .filter(|n| rec.col(n).is_none())
        .collect();
    if missing.is_empty() {
        return Ok(None);
    }
    let mut cols: Vec<(String, Vec<f64>)> = rec
        .names()
        .iter()
        .map(|n| (n.clone(), rec.col(n).expect("listed").to_vec()))
        .collect();
    cols.extend(missing.iter().map(|n| (n.clone(), vec![0.0; rec.n_rows()])));
    Ok(Some((Recording::from_columns(cols)?, missing.join(", "))))
}

/// Whether the model with a finding added (`with`, µm per row on the signal's axis) differs from
/// the model before it (`before`) by the finding's own prediction (`expected`), within
/// CHECK_REL of its RMS + CHECK_ABS_UM.
fn reproduces(with: &[f64], before: &[f64], expected: &[f64], slot: &str) -> Result<(), String> {
    let (mut dev, mut norm) = (0.0, 0.0);
    for ((w, b), e) in with.iter().zip(before).zip(expected) {
        dev += (w - b - e).powi(2);
        norm += e.powi(2);
    }
    let n = expected.len().max(1) as f64;
    let (dev, norm) = ((dev / n).sqrt(), (norm / n).sqrt());
    if dev <= CHECK_REL * norm + CHECK_ABS_UM {
        Ok(())
    } else {
        Err(format!(
            "the model form {slot} does not reproduce it on this recording (deviation {dev:.3} µm RMS of {norm:.3} µm)"
        ))
    }
}

/// `--fit-offset`: the joint refit's constant offset (µm) into e0 of the signal's last
/// `polynomial_dt` term; the note for the header, or `None` when the signal has no such term.
fn offset_into_e0(spec: &mut ModelSpec, signal: &str, offset: f64) -> Option<String> {
    let stem = format!("diag_{}_", signal.trim_end_matches("_um"));
    let th = spec
        .thermal
        .iter_mut()
        .rev()
        .find(|t| t.name.starts_with(&stem))?;
    let retrocomp_model::ThermalKind::PolynomialDt { e0, .. } = &mut th.kind else {
        return None;
    };
    *e0 += offset;
    Some(format!(
        "{signal}: constant offset {offset:+.3} µm of the joint refit → e0 of `{}` (--fit-offset)",
        th.name
    ))
}

/// The comment block at the top of the written model: its base, sign, placeholder axes, what
/// was added and what is not in it.
fn header(
    base_line: &str,
    placeholder: Option<&str>,
    added: &[String],
    not_in_model: &[String],
) -> String {
    let mut head = String::new();
    head.push_str("# Machine model written by `retrocomp diagnose --out`.\n");
    head.push_str(&format!("# Base: {base_line}.\n"));
    head.push_str("# Sign: error = actual - nominal (um); correction = -error.\n");
    if let Some(p) = placeholder {
        head.push_str(&format!(
            "# The recording lacks {p}: placeholder axes (the model format needs 2-3 axes), held at 0.\n"
        ));
    }
    if !added.is_empty() {
        head.push_str("# Added (each checked against the finding on the recording):\n");
        for a in added {
            head.push_str(&format!("#   {a}\n"));
        }
    }
    if !not_in_model.is_empty() {
        head.push_str("# NOT in this model (no slot in the model schema, or the form did not reproduce the finding):\n");
        for a in not_in_model {
            head.push_str(&format!("#   {a}\n"));
        }
    }
    head.push('\n');
    head
}

/// The signal's findings as they go into the model. When some finding has no slot (time_drift,
/// servo_lag…), the others' gains were fitted jointly with it and would be biased without it: the
/// writable terms' linear coefficients (and the intercept) are refitted alone on the same residual,
/// their nonlinear parameters (τ, period) kept. Returns the models and a note saying so.
fn writable_refit(
    s: &super::SignalResult,
    ctx: &super::features::Context,
    spec: &ModelSpec,
    rec: &Recording,
    axis: Axis,
) -> (Vec<super::effects::EffectModel>, Option<String>) {
    if let Some(w) = &s.written {
        let note = format!(
            "{}: written as the rolling origin over the recording's regimes chose (forward_check[].regimes: {} term(s))",
            s.signal,
            w.len()
        );
        return (w.clone(), Some(note));
    }
    let writable: Vec<bool> = s
        .models
        .iter()
        .map(|m| {
            let item = Item {
                signal: &s.signal,
                axis,
                model: m,
            };
            add_item(&mut spec.clone(), &item, rec).is_ok()
        })
        .collect();
    if writable.iter().all(|&w| w)
        || !writable.iter().any(|&w| w)
        || s.terms.len() != s.models.len()
    {
        return (s.models.clone(), None);
    }
    let mut cols = vec![vec![1.0; s.residual_before.len()]];
    let mut widths = vec![];
    for ((c, th), _) in s.terms.iter().zip(&writable).filter(|(_, w)| **w) {
        let cc = c.columns(ctx, *th);
        widths.push(cc.len());
        cols.extend(cc);
    }
    let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
    let beta = super::lsq::coef(&refs, &s.residual_before);
    let mut at = 1;
    let mut it = widths.iter();
    let models = s
        .terms
        .iter()
        .zip(&s.models)
        .zip(&writable)
        .filter(|(_, w)| **w)
        .map(|(((c, th), _), _)| {
            let w = *it.next().expect("one width per writable term");
            let m = c.to_model(&beta[at..at + w], *th);
            at += w;
            m
        })
        .collect();
    let dropped: Vec<&str> = s
        .models
        .iter()
        .zip(&writable)
        .filter(|(_, w)| !**w)
        .map(|(m, _)| m.id())
        .collect();
    let note = format!(
        "{}: the written terms' gains refitted without {} (no slot), which was fitted jointly with them",
        s.signal,
        dropped.join(", ")
    );
    (models, Some(note))
}

fn describe(item: &Item<'_>, why: &str) -> String {
    let params = match &serde_json::to_value(item.model).expect("serialisable")["params"] {
        serde_json::Value::Object(m) => m
            .iter()
            .map(|(k, v)| format!("{k} = {}", fmt_value(v)))
            .collect::<Vec<_>>()
            .join(", "),
        _ => String::new(),
    };
    format!(
        "{} on {} ({}): {}; {} — {why}",
        item.model.id(),
        item.axis.lower(),
        item.signal,
        params,
        item.model.equation(item.axis.lower())
    )
}

/// A chain of the recording's axes (X F Y Z order: the first axis on the workpiece side), no tool
/// offset, tool along −z. Two axes at least (the model format needs 2–3): a one-axis recording
/// gets a placeholder second axis, which the recording must then carry as a column.
fn default_spec(rec: &Recording) -> Result<ModelSpec, DiagnoseError> {
    let mut axes: Vec<Axis> = AXES
        .iter()
        .filter(|a| rec.col(&format!("{a}_mm")).is_some())
        .map(|&a| Axis::from_letter(a).expect("x, y or z"))
        .collect();
    if axes.is_empty() {
        // Thermal-only recording (an ISO 230-3 test): the full X F Y Z chain, no travel limits;
        // only position-independent terms can be found, so the axes are never read.
        axes = Axis::ALL.to_vec();
    }
    if axes.len() == 1 {
        let extra = Axis::ALL
            .iter()
            .copied()
            .find(|a| *a != axes[0])
            .expect("three axes");
        axes.push(extra);
    }
    let travel = |a: Axis| {
        rec.col(&format!("{}_mm", a.lower()))
            .map(|p| {
                let lo = p.iter().copied().fold(f64::INFINITY, f64::min);
                let hi = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                (lo, hi)
            })
            // A constant column has no travel (the model format needs min < max).
            .filter(|(lo, hi)| hi > lo)
    };
    Ok(ModelSpec {
        name: "diagnose-found-terms".into(),
        description: "terms found by retrocomp diagnose, on a default chain".into(),
        synthetic: false,
        axes: axes
            .iter()
            .enumerate()
            .map(|(k, &a)| AxisSpec {
                axis: a,
                branch: if k == 0 {
                    Branch::Workpiece
                } else {
                    Branch::Tool
                },
                offset_mm: [0.0; 3],
                travel_mm: travel(a),
            })
            .collect(),
        tool_axis: (Axis::Z, -1.0),
        tools: vec![ToolSpec {
            name: "tool".into(),
            offset_mm: [0.0; 3],
        }],
        components: vec![],
        squareness: vec![],
        sensors: vec![],
        thermal: vec![],
        forces: vec![],
        load: vec![],
        lag_state: None,
    })
}

/// The spec evaluated on the recording: error per machine axis x/y/z, µm, per row.
fn simulate_spec(spec: &ModelSpec, rec: &Recording) -> Result<[Vec<f64>; 3], DiagnoseError> {
    let model = MachineModel::from_spec(spec.clone());
    super::model_sim::simulate_axes(&model, rec)
}

/// A parameter value for people: numbers to 4 significant digits.
fn fmt_value(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => {
            let x = n.as_f64().unwrap_or(f64::NAN);
            let digits = crate::numeric::trunc_usize(
                (3.0 - x.abs().max(1e-300).log10().floor()).clamp(0.0, 12.0),
            );
            format!("{x:.digits$}")
        }
        serde_json::Value::Array(a) => {
            format!(
                "[{}]",
                a.iter().map(fmt_value).collect::<Vec<_>>().join(", ")
            )
        }
        serde_json::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Write `model.toml` into `dir`.
pub(super) fn write_model(
    out: &ModelOut,
    dir: &std::path::Path,
) -> Result<std::path::PathBuf, DiagnoseError> {
    let p = dir.join("model.toml");
    std::fs::write(&p, &out.toml).map_err(|source| DiagnoseError::Write {
        path: p.display().to_string(),
        source,
    })?;
    Ok(p)
}
