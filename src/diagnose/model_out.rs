//! `diagnose --out DIR` → `DIR/model.toml`: a machine model (`crate::models`, loadable by `retrocomp
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

use anyhow::Context as _;

use super::Diagnosis;
use super::effects::EffectModel;
use crate::analysis::fit::to_model::{put_component, to_checked_toml};
use crate::models::spec::{
    AxisSpec, Branch, ComponentSpec, ForceSpec, LoadKind, LoadSpec, SensorSpec, SquarenessSpec,
    StrainSource, ThermalKind, ThermalSpec, ToolSpec,
};
use crate::models::{
    Axis, ComponentId, ErrorFunction, Interpolation, MachineModel, ModelSpec, Motion, Squareness,
    Table,
};
use crate::recording::{AXES, Recording};

/// Relative and absolute tolerance (RMS over the recording) of the per-term check.
const CHECK_REL: f64 = 0.02;
const CHECK_ABS_UM: f64 = 0.02;
/// Table grid: at least this many intervals over the span, and ≥ 32 nodes per cyclic period.
const MIN_INTERVALS: f64 = 400.0;
const NODES_PER_PERIOD: f64 = 32.0;
const MAX_NODES: usize = 20_001;

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

/// One finding to add: which signal axis and model.
struct Item<'a> {
    signal: &'a str,
    axis: Axis,
    model: &'a EffectModel,
}

/// Build the model: `base` is the `--model` input, `None` when the simulation came from columns.
pub fn model_with_findings(
    d: &Diagnosis,
    rec: &Recording,
    base: Option<&MachineModel>,
) -> anyhow::Result<ModelOut> {
    let mut spec = match base {
        Some(m) => m.spec().clone(),
        None => default_spec(rec)?,
    };
    // A one-axis recording on the default chain: its placeholder axis is evaluated at 0 mm.
    let padded;
    let mut placeholder = None;
    let rec = match spec
        .axes
        .iter()
        .find(|a| rec.col(&format!("{}_mm", a.axis.lower())).is_none())
    {
        Some(a) if base.is_none() => {
            let name = format!("{}_mm", a.axis.lower());
            let mut cols: Vec<(String, Vec<f64>)> = rec
                .names()
                .iter()
                .map(|n| (n.clone(), rec.col(n).expect("listed").to_vec()))
                .collect();
            cols.push((name.clone(), vec![0.0; rec.n_rows()]));
            padded = Recording::from_columns(cols)?;
            placeholder = Some(name);
            &padded
        }
        _ => rec,
    };
    let mut base_line = match base {
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
        base_line.push_str(&format!(" (`{p}` is a placeholder axis: give it as 0)"));
    }
    let ctx = &d.context;
    let mut added = vec![];
    let mut not_in_model = vec![];
    let mut current = simulate_spec(&spec, rec).context("evaluating the base model")?;
    for s in &d.signals {
        let axis = Axis::from_letter(s.axis).expect("signal axis is x, y or z");
        // Constant offset: the refit's intercept, i.e. the mean residual left after all terms.
        let mut left = s.residual_before.clone();
        for m in &s.models {
            if let Ok(v) = m.evaluate(s.axis, ctx) {
                left.iter_mut().zip(v).for_each(|(l, e)| *l -= e);
            }
        }
        let offset = left.iter().sum::<f64>() / left.len().max(1) as f64;
        if !s.models.is_empty() && offset.abs() > 1e-9 {
            not_in_model.push(format!(
                "{}: constant offset {offset:+.3} µm between recording and simulation (a measurement zero, not a machine term)",
                s.signal
            ));
        }
        for m in &s.models {
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
                    let k = axis.index();
                    let (mut dev, mut norm) = (0.0, 0.0);
                    for i in 0..exp.len() {
                        let got = sim[k][i] - current[k][i];
                        dev += (got - exp[i]).powi(2);
                        norm += exp[i].powi(2);
                    }
                    let n = exp.len().max(1) as f64;
                    let (dev, norm) = ((dev / n).sqrt(), (norm / n).sqrt());
                    if dev <= CHECK_REL * norm + CHECK_ABS_UM {
                        Ok(())
                    } else {
                        Err(format!(
                            "the model form {slot} does not reproduce it on this recording (deviation {dev:.3} µm RMS of {norm:.3} µm)"
                        ))
                    }
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
    }
    let (text, model) = to_checked_toml(spec).map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut head = String::new();
    head.push_str("# Machine model written by `retrocomp diagnose --out`.\n");
    head.push_str(&format!("# Base: {base_line}.\n"));
    head.push_str("# Sign: error = actual - nominal (um); correction = -error.\n");
    if let Some(p) = &placeholder {
        head.push_str(&format!(
            "# The recording has one axis; `{p}` is a placeholder (the model format needs 2-3 axes): give it as 0.\n"
        ));
    }
    if !added.is_empty() {
        head.push_str("# Added (each checked against the finding on the recording):\n");
        for a in &added {
            head.push_str(&format!("#   {a}\n"));
        }
    }
    if !not_in_model.is_empty() {
        head.push_str("# NOT in this model (no slot in the model schema, or the form did not reproduce the finding):\n");
        for a in &not_in_model {
            head.push_str(&format!("#   {a}\n"));
        }
    }
    head.push('\n');
    Ok(ModelOut {
        toml: head + &text,
        model,
        base: base_line,
        added,
        not_in_model,
    })
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
fn default_spec(rec: &Recording) -> anyhow::Result<ModelSpec> {
    let mut axes: Vec<Axis> = AXES
        .iter()
        .filter(|a| rec.col(&format!("{a}_mm")).is_some())
        .map(|&a| Axis::from_letter(a).expect("x, y or z"))
        .collect();
    if axes.is_empty() {
        anyhow::bail!("the recording has no axis position column (x_mm, y_mm, z_mm)");
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
        rec.col(&format!("{}_mm", a.lower())).map(|p| {
            let lo = p.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (lo, hi)
        })
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
    })
}

/// The spec evaluated on the recording: error per machine axis x/y/z, µm, per row.
fn simulate_spec(spec: &ModelSpec, rec: &Recording) -> anyhow::Result<[Vec<f64>; 3]> {
    let model = MachineModel::from_spec(spec.clone());
    super::model_sim::simulate_axes(&model, rec)
}

/// Add one finding to `spec`; returns the slot's description, or why there is no slot.
fn add_item(spec: &mut ModelSpec, item: &Item<'_>, rec: &Recording) -> Result<String, String> {
    let a = item.axis;
    let own = ComponentId {
        axis: a,
        motion: Motion::Translation(a),
    };
    let in_chain = |x: Axis| spec.axes.iter().any(|s| s.axis == x);
    if !in_chain(a) {
        return Err(format!("axis {} is not in the model's chain", a.upper()));
    }
    match item.model {
        EffectModel::ScaleError { .. }
        | EffectModel::Backlash { .. }
        | EffectModel::ReversalProfile { .. }
        | EffectModel::CyclicError { .. } => {
            add_to_table(spec, own, a, item.model, rec)?;
            Ok(format!("{} table", own.iso_name()))
        }
        EffectModel::Straightness { along_axis, .. } => {
            let o = Axis::from_letter(*along_axis).ok_or("bad axis")?;
            if !in_chain(o) {
                return Err(format!("axis {} is not in the model's chain", o.upper()));
            }
            let id = ComponentId {
                axis: o,
                motion: Motion::Translation(a),
            };
            add_to_table(spec, id, o, item.model, rec)?;
            Ok(format!("{} table", id.iso_name()))
        }
        EffectModel::Squareness { other_axis, urad } => {
            let o = Axis::from_letter(*other_axis).ok_or("bad axis")?;
            if !in_chain(o) {
                return Err(format!("axis {} is not in the model's chain", o.upper()));
            }
            // docs/model.md: EC0Y on x: ey = −S·x, on y: ex = −S·y; EB0Z: ex = +S·z, ez = +S·x;
            // EA0Z: ey = −S·z, ez = −S·y. The finding is e_a += urad·1e-3·q_o.
            let (kind, sign) = match (a.lower().min(o.lower()), a.lower().max(o.lower())) {
                ('x', 'y') => (Squareness::EC0Y, -1.0),
                ('x', 'z') => (Squareness::EB0Z, 1.0),
                ('y', 'z') => (Squareness::EA0Z, -1.0),
                _ => return Err("squareness needs two different axes".into()),
            };
            let value = sign * urad;
            match spec
                .squareness
                .iter_mut()
                .find(|s| s.kind == kind && s.on_axis == o)
            {
                Some(s) => s.value_urad += value,
                None => spec.squareness.push(SquarenessSpec {
                    kind,
                    on_axis: o,
                    value_urad: value,
                }),
            }
            Ok(format!("squareness {} on {}", kind.iso_name(), o.lower()))
        }
        EffectModel::Abbe { urad_per_mm } => {
            // e_a = (ε × arm)_a·1e-3 with arm ∋ s·tool_mm·û_t: a rotation about the third axis r
            // gives ε_r·s·h·lc(r, t, a); the finding is urad_per_mm·q_a·h·1e-3.
            let (t, s) = spec.tool_axis;
            if t == a {
                return Err(format!(
                    "the tool length lies along {}: no rotation gives an Abbe error along it",
                    a.lower()
                ));
            }
            let r = Axis::ALL
                .iter()
                .copied()
                .find(|x| *x != a && *x != t)
                .expect("three axes");
            let lc = levi_civita(r.index(), t.index(), a.index());
            let k = urad_per_mm / (s * lc);
            let id = ComponentId {
                axis: a,
                motion: Motion::Rotation(r),
            };
            let m = EffectModel::ScaleError { ppm: k * 1e3 };
            add_to_table(spec, id, a, &m, rec)?;
            Ok(format!(
                "{} table (µrad, Abbe arm = tool length)",
                id.iso_name()
            ))
        }
        EffectModel::ThermalDrift { sensor, um_per_k } => {
            let name = sensor_name(sensor)?;
            let t0 = first_reading(rec, sensor)?;
            let reference = ensure_sensor(spec, &name, None, t0)?;
            push_thermal(
                spec,
                item,
                own,
                ThermalKind::PolynomialDt {
                    sensors: vec![name.clone()],
                    e0: um_per_k * (reference - t0),
                    b_per_k: vec![*um_per_k],
                    c_per_k2: vec![],
                },
            );
            Ok(format!(
                "sensor `{name}` + thermal polynomial_dt on {}",
                own.iso_name()
            ))
        }
        EffectModel::ThermalLag {
            sensor,
            tau_s,
            um_per_k,
        } => {
            let name = sensor_name(sensor)?;
            let t0 = first_reading(rec, sensor)?;
            let reference = ensure_sensor(spec, &name, Some(*tau_s), t0)?;
            push_thermal(
                spec,
                item,
                own,
                ThermalKind::PolynomialDt {
                    sensors: vec![name.clone()],
                    e0: um_per_k * (reference - t0),
                    b_per_k: vec![*um_per_k],
                    c_per_k2: vec![],
                },
            );
            Ok(format!(
                "sensor `{name}` (tau_s {tau_s:.0}) + thermal polynomial_dt on {}",
                own.iso_name()
            ))
        }
        EffectModel::ThermalExpansion { sensor, ppm_per_k } => {
            let name = sensor_name(sensor)?;
            let t0 = first_reading(rec, sensor)?;
            ensure_sensor(spec, &name, None, t0)?;
            push_thermal(
                spec,
                item,
                own,
                ThermalKind::Expansion {
                    sensor: name.clone(),
                    alpha_ppm_per_k: *ppm_per_k,
                    origin_mm: 0.0,
                    reference_c: t0,
                },
            );
            Ok(format!("thermal expansion on {} ({name})", own.iso_name()))
        }
        EffectModel::ForceDeflection { channel, um_per_n } => {
            let force = if let Some(n) = strip(channel, "F_", "_N") {
                match spec.forces.iter().find(|f| f.name == n) {
                    Some(f) if f.from_strain.is_some() => {
                        return Err(format!(
                            "force `{n}` is derived from a strain in the model, not read from {channel}"
                        ));
                    }
                    Some(_) => {}
                    None => spec.forces.push(ForceSpec {
                        name: n.clone(),
                        from_strain: None,
                    }),
                }
                n
            } else if let Some(sname) = strip(channel, "strain_", "_ue") {
                let n = format!("diag_{sname}");
                spec.forces.retain(|f| f.name != n);
                spec.forces.push(ForceSpec {
                    name: n.clone(),
                    from_strain: Some(StrainSource {
                        strain: sname,
                        gain_n_per_ue: 1.0,
                        offset_ue: 0.0,
                    }),
                });
                n
            } else {
                return Err(format!(
                    "`{channel}` is neither F_<name>_N nor strain_<name>_ue"
                ));
            };
            let name = unique(
                &format!("diag_{}_{force}", signal_stem(item.signal)),
                spec.load.iter().map(|l| l.name.as_str()),
            );
            spec.load.push(LoadSpec {
                name,
                target: own,
                kind: LoadKind::Compliance {
                    force: force.clone(),
                    compliance: ErrorFunction::Polynomial {
                        coefficients: vec![*um_per_n],
                        range_mm: None,
                    },
                },
            });
            Ok(format!(
                "force {force} + constant compliance on {}",
                own.iso_name()
            ))
        }
        EffectModel::ServoLag { .. } => {
            Err("no slot: the model is a function of position, not of velocity".into())
        }
        EffectModel::ReversalSpike { .. } => {
            Err("no slot: the model has no state for the distance since the last reversal".into())
        }
        EffectModel::TimeDrift { .. } => {
            Err("no slot: the model has no term in time without a measured cause".into())
        }
    }
}

/// A parameter value for people: numbers to 4 significant digits.
fn fmt_value(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => {
            let x = n.as_f64().unwrap_or(f64::NAN);
            let digits = (3 - x.abs().max(1e-300).log10().floor() as i32).clamp(0, 12) as usize;
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

fn levi_civita(i: usize, j: usize, k: usize) -> f64 {
    match (i, j, k) {
        (0, 1, 2) | (1, 2, 0) | (2, 0, 1) => 1.0,
        (0, 2, 1) | (2, 1, 0) | (1, 0, 2) => -1.0,
        _ => 0.0,
    }
}

fn strip(s: &str, pre: &str, suf: &str) -> Option<String> {
    s.strip_prefix(pre)
        .and_then(|r| r.strip_suffix(suf))
        .filter(|r| !r.is_empty())
        .map(str::to_string)
}

fn sensor_name(column: &str) -> Result<String, String> {
    strip(column, "T_", "_C").ok_or_else(|| format!("`{column}` is not a T_<name>_C column"))
}

fn signal_stem(signal: &str) -> &str {
    signal.trim_end_matches("_um")
}

fn first_reading(rec: &Recording, column: &str) -> Result<f64, String> {
    rec.col(column)
        .and_then(|c| c.first().copied())
        .ok_or_else(|| format!("the recording has no `{column}`"))
}

fn unique<'a>(want: &str, taken: impl Iterator<Item = &'a str> + Clone) -> String {
    let mut name = want.to_string();
    let mut k = 2;
    while taken.clone().any(|t| t == name) {
        name = format!("{want}_{k}");
        k += 1;
    }
    name
}

/// Make sure sensor `name` exists with lag `tau_s`; returns its reference temperature. A sensor
/// already in the model with another lag cannot also be read without it (one sensor per column).
fn ensure_sensor(
    spec: &mut ModelSpec,
    name: &str,
    tau_s: Option<f64>,
    t0: f64,
) -> Result<f64, String> {
    if let Some(s) = spec.sensors.iter().find(|s| s.name == name) {
        let same = match (s.tau_s, tau_s) {
            (None, None) => true,
            (Some(a), Some(b)) => (a - b).abs() <= 1e-9 * a.abs().max(b.abs()),
            _ => false,
        };
        return if same {
            Ok(s.reference_c)
        } else {
            Err(format!(
                "sensor `{name}` is already in the model with lag {:?} s, the finding needs {:?} s",
                s.tau_s, tau_s
            ))
        };
    }
    spec.sensors.push(SensorSpec {
        name: name.to_string(),
        reference_c: t0,
        tau_s,
    });
    Ok(t0)
}

fn push_thermal(spec: &mut ModelSpec, item: &Item<'_>, target: ComponentId, kind: ThermalKind) {
    let name = unique(
        &format!("diag_{}_{}", signal_stem(item.signal), item.model.id()),
        spec.thermal.iter().map(|t| t.name.as_str()),
    );
    spec.thermal.push(ThermalSpec { name, target, kind });
}

/// Add a one-position (and direction) effect to component `id` whose argument is axis `arg`:
/// the base function (if any) plus the effect, sampled as a bidirectional table.
fn add_to_table(
    spec: &mut ModelSpec,
    id: ComponentId,
    arg: Axis,
    m: &EffectModel,
    rec: &Recording,
) -> Result<(), String> {
    let base = spec
        .components
        .iter()
        .find(|c| c.id == id)
        .map(|c| c.function.clone());
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut widen = |a: f64, b: f64| {
        lo = lo.min(a);
        hi = hi.max(b);
    };
    if let Some(p) = rec.col(&format!("{}_mm", arg.lower())) {
        widen(
            p.iter().copied().fold(f64::INFINITY, f64::min),
            p.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
    }
    if let Some((a, b)) = spec
        .axes
        .iter()
        .find(|s| s.axis == arg)
        .and_then(|s| s.travel_mm)
    {
        widen(a, b);
    }
    let mut extra_nodes = vec![];
    match &base {
        Some(ErrorFunction::Table(t)) => {
            widen(t.positions_mm[0], *t.positions_mm.last().expect("≥ 2"));
            extra_nodes.extend(t.positions_mm.iter().copied());
        }
        Some(
            ErrorFunction::Polynomial {
                range_mm: Some((a, b)),
                ..
            }
            | ErrorFunction::PiecewiseQuadratic {
                range_mm: Some((a, b)),
                ..
            },
        ) => widen(*a, *b),
        _ => {}
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(format!("no positions of axis {} to tabulate", arg.lower()));
    }
    if hi - lo < 1e-6 {
        hi = lo + 1.0;
    }
    let span = hi - lo;
    let mut h = span / MIN_INTERVALS;
    if let EffectModel::CyclicError { period_mm, .. } = m {
        h = h.min(period_mm / NODES_PER_PERIOD);
    }
    h = h.max(span / (MAX_NODES - 1) as f64);
    let n = (span / h).ceil() as usize;
    let mut nodes: Vec<f64> = (0..=n).map(|i| lo + span * i as f64 / n as f64).collect();
    nodes.extend(extra_nodes);
    if let EffectModel::ReversalProfile { edges_mm, .. } = m {
        // A zone edge is a step: one node just below it and one on it.
        for &e in edges_mm {
            if e > lo && e < hi {
                nodes.push(e - 1e-6 * span);
                nodes.push(e);
            }
        }
    }
    nodes.sort_by(f64::total_cmp);
    nodes.dedup_by(|b, a| (*b - *a).abs() < 1e-9 * span);
    let val = |x: f64, dir: i8| {
        base.as_ref().map_or(0.0, |f| f.eval(x, dir).0)
            + m.at_position(x, f64::from(dir)).expect("positional effect")
    };
    let forward = nodes.iter().map(|&x| val(x, 1)).collect();
    let reverse = nodes.iter().map(|&x| val(x, -1)).collect();
    let interpolation = match &base {
        Some(ErrorFunction::Table(t)) => t.interpolation,
        _ => Interpolation::Linear,
    };
    put_component(
        spec,
        ComponentSpec {
            id,
            function: ErrorFunction::Table(Table::new(nodes, forward, reverse, interpolation)),
        },
    )
    .map_err(|e| e.to_string())
}

/// Write `model.toml` into `dir`.
pub fn write_model(out: &ModelOut, dir: &std::path::Path) -> anyhow::Result<std::path::PathBuf> {
    let p = dir.join("model.toml");
    std::fs::write(&p, &out.toml).with_context(|| p.display().to_string())?;
    Ok(p)
}
