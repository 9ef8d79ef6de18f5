//! The demo's fitted model: the measurement campaign's recordings ([`super::campaign`]) in, a
//! machine-model TOML out, with no look at the simulator's truth (not its model file, not its
//! manifest, not the recording's `sim_*` columns). Sans-IO: takes parsed recordings.
//!
//! - **Geometry** (`analysis::fit::workflow::fit_axis`, as `retrocomp fit axis`): per measured axis
//!   K and error direction J, the readings become the bidirectional table EJK (C¹ piecewise
//!   quadratics with stepwise knots, run `runs` held out for δ). They are tool-tip errors at the
//!   demo's tool, so angular errors (EBX's Abbe offset) are lumped into these translations at the
//!   measured arm. The X tables are absolute; the Y and Z tables are zeroed at the reference point,
//!   so that the sum of the three tables equals the error at the reference once, not three times.
//! - **Context** (`analysis::fit::regression::select`, BIC, as `retrocomp fit thermal|load`): the
//!   residual of each error signal after the fitted geometry is regressed on candidates
//!   ΔT_s = T_s − T_s,ref (T_ref = mean during the cold geometry runs), q·ΔT_s (q = the signal's own
//!   axis position: a scale expansion) and the force channels F_f. Trained on the first 70 % of the
//!   samples, δ on the last 30 %. Chosen terms become `polynomial_dt` (ΔT), `expansion` (q·ΔT,
//!   α in ppm/K = µm/(m·K), origin 0) and `compliance` load terms (F) on EJJ.
//!
//! Error = actual − nominal, µm; correction = −error is the gateway's business.

use std::fmt::Write as _;

use anyhow::{Context, bail};

use super::campaign::{AxisPlan, REFERENCE_MM};
use super::readings::{ERR, readings, readings_csv};
use crate::analysis::fit::efficiency::{Efficiency, efficiency};
use crate::analysis::fit::regression::{Candidate, Criterion, select};
use crate::analysis::fit::to_model::{AxisForm, axis_component, put_component, to_checked_toml};
use crate::analysis::fit::workflow::fit_axis;
use crate::analysis::iso230_2::Reading;
use crate::models::names::parse_component;
use crate::models::spec::{ForceSpec, LoadKind, LoadSpec, SensorSpec, ThermalKind, ThermalSpec};
use crate::models::{Axis, ComponentId, ErrorFunction, MachineModel, ModelSpec};
use crate::recording::Recording;

/// Significance of a knot (Spaan: 99.99 %).
const KNOT_ALPHA: f64 = 1e-4;
/// Largest number of context terms per error signal.
const MAX_CONTEXT_TERMS: usize = 3;

/// What the fit produced, for the report and the plots.
#[derive(Clone, Debug, Default)]
pub struct FitOutcome {
    /// The model TOML (already re-read through the validating parser).
    pub toml: String,
    /// One line per fitted component / context signal.
    pub report: Vec<String>,
    /// `readings_<EJK>.csv` files (ISO 230-2 long CSV) for `retrocomp fit axis`.
    pub readings_csv: Vec<(String, String)>,
}

fn component(name: &str) -> anyhow::Result<ComponentId> {
    parse_component(name).with_context(|| format!("`{name}` is not a component name"))
}

/// Subtracts the mean reading at the reference coordinate (both directions, all runs).
fn zero_at_reference(r: &mut [Reading], reference_mm: f64) -> anyhow::Result<()> {
    let at: Vec<f64> = r
        .iter()
        .filter(|x| (x.target_mm - reference_mm).abs() < 1e-9)
        .map(|x| x.deviation_um)
        .collect();
    if at.is_empty() {
        bail!("no reading at the reference {reference_mm} mm");
    }
    let mean = at.iter().sum::<f64>() / at.len() as f64;
    for x in r {
        x.deviation_um -= mean;
    }
    Ok(())
}

/// Fits the geometric tables into `spec` from one recording per plan.
pub fn fit_geometry(
    spec: &mut ModelSpec,
    runs: &[(&AxisPlan, &Recording, &str)],
    out: &mut FitOutcome,
) -> anyhow::Result<()> {
    for (plan, rec, what) in runs {
        let k = plan.axis;
        let step = plan.targets_mm[1] - plan.targets_mm[0];
        let per_signal = readings(plan, rec, what)?;
        for (j, mut r) in per_signal.into_iter().enumerate() {
            let name = format!("E{}{}", Axis::ALL[j].upper(), k.upper());
            if k != Axis::X {
                zero_at_reference(&mut r, REFERENCE_MM[k.index()])
                    .with_context(|| format!("{what}: {name}"))?;
            }
            let fit = fit_axis(&r, step, KNOT_ALPHA, Some(plan.runs))
                .map_err(|e| anyhow::anyhow!("{what}: fit of {name}: {e}"))?;
            let c = axis_component(&fit, component(&name)?, AxisForm::Table, &plan.targets_mm)?;
            put_component(spec, c)?;
            let held = fit
                .heldout
                .map(|h| format!("δ {:.3}, max residual {:.2} µm", h.delta, h.max_residual_um))
                .unwrap_or_else(|| "δ undefined".into());
            let span = r
                .iter()
                .map(|x| x.deviation_um)
                .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
            out.report.push(format!(
                "{name}: table of {} targets, {} knots fwd / {} rev, span {:.2}..{:.2} µm; run {} held out: {held}",
                plan.targets_mm.len(),
                fit.forward.knots_mm.len(),
                fit.reverse.knots_mm.len(),
                span.0,
                span.1,
                plan.runs
            ));
            out.readings_csv.push((
                format!("readings_{name}.csv"),
                readings_csv(
                    &r,
                    &format!("{name} from {what} ({} run along {})", ERR[j], k.upper()),
                ),
            ));
        }
    }
    Ok(())
}

/// Mean of each `T_*_C` column over the cold geometry runs: the reference temperature of the
/// geometric tables.
pub fn reference_temperatures(recs: &[&Recording]) -> Vec<(String, f64)> {
    let mut names: Vec<String> = recs.iter().flat_map(|r| r.temperature_channels()).collect();
    names.sort();
    names.dedup();
    names
        .into_iter()
        .filter_map(|n| {
            let (s, c) = recs
                .iter()
                .filter_map(|r| r.col(&n))
                .fold((0.0, 0usize), |(s, c), v| {
                    (s + v.iter().sum::<f64>(), c + v.len())
                });
            (c > 0).then(|| (n, s / c as f64))
        })
        .collect()
}

/// Direction latch per axis from the nominal motion (+1/−1; 0 until the axis first moves).
fn latched_directions(pos: &[&[f64]]) -> Vec<[i8; 3]> {
    let n = pos[0].len();
    let mut d = [0i8; 3];
    (0..n)
        .map(|i| {
            for (k, p) in pos.iter().enumerate() {
                if i > 0 && p[i] != p[i - 1] {
                    d[k] = if p[i] > p[i - 1] { 1 } else { -1 };
                }
            }
            d
        })
        .collect()
}

/// Per error signal, the context residual fit's outcome.
struct ContextTerms {
    intercept_um: f64,
    terms: Vec<(String, f64)>,
    heldout: Efficiency,
}

fn sensor_of(channel: &str) -> &str {
    channel.trim_start_matches("T_").trim_end_matches("_C")
}

/// Fits the thermal and load terms into `spec` from the context run; `geometric` is the model with
/// the fitted tables (its error is removed first), `t_ref` the cold reference temperatures.
pub fn fit_context_terms(
    spec: &mut ModelSpec,
    geometric: &MachineModel,
    rec: &Recording,
    t_ref: &[(String, f64)],
    what: &str,
    out: &mut FitOutcome,
) -> anyhow::Result<()> {
    let t = rec.t_s();
    let n = t.len();
    let pos: Vec<&[f64]> = ["x_mm", "y_mm", "z_mm"]
        .iter()
        .map(|c| {
            rec.col(c)
                .with_context(|| format!("{what}: no column `{c}`"))
        })
        .collect::<anyhow::Result<_>>()?;
    let dirs = latched_directions(&pos);
    let mut input = geometric.new_input();
    let (mut state, mut bd) = (geometric.new_state(), geometric.new_breakdown());
    let mut geo = Vec::with_capacity(n);
    for i in 0..n {
        input.pos_mm = [pos[0][i], pos[1][i], pos[2][i]];
        input.dir = dirs[i];
        input.t_s = t[i];
        geometric.evaluate(&input, &mut state, &mut bd);
        geo.push(bd.total_um);
    }
    let n_train = n * 7 / 10;
    let mut cands: Vec<(String, Vec<f64>, usize)> = Vec::new(); // name, values, axis (usize::MAX = any)
    for (ch, tr) in t_ref {
        let Some(v) = rec.col(ch) else { continue };
        let dt: Vec<f64> = v.iter().map(|x| x - tr).collect();
        for (k, p) in pos.iter().enumerate() {
            let q = Axis::ALL[k].lower();
            let prod = dt.iter().zip(*p).map(|(d, q)| d * q).collect();
            cands.push((format!("{q}·dT_{}", sensor_of(ch)), prod, k));
        }
        cands.push((format!("dT_{}", sensor_of(ch)), dt, usize::MAX));
    }
    for ch in rec
        .load_channels()
        .into_iter()
        .filter(|c| c.starts_with("F_"))
    {
        cands.push((
            ch.clone(),
            rec.col(&ch).expect("listed").to_vec(),
            usize::MAX,
        ));
    }
    // A candidate that does not move on the training part cannot be told from the intercept.
    let moves = |v: &[f64]| {
        let tr = &v[..n_train];
        let m = tr.iter().sum::<f64>() / tr.len() as f64;
        tr.iter().map(|x| (x - m).powi(2)).sum::<f64>() / tr.len() as f64 > 1e-12
    };
    for (j, signal) in ERR.iter().enumerate() {
        let e = rec
            .col(signal)
            .with_context(|| format!("{what}: no column `{signal}`"))?;
        let y: Vec<f64> = e.iter().zip(&geo).map(|(e, g)| e - g[j]).collect();
        let mine: Vec<&(String, Vec<f64>, usize)> = cands
            .iter()
            .filter(|c| (c.2 == usize::MAX || c.2 == j) && moves(&c.1))
            .collect();
        if mine.is_empty() {
            out.report
                .push(format!("{signal}: no context signal moves; no term"));
            continue;
        }
        let train: Vec<Candidate> = mine
            .iter()
            .map(|c| Candidate {
                signal: c.0.clone(),
                tau_s: 0.0,
                values: c.1[..n_train].to_vec(),
            })
            .collect();
        let sel = select(&y[..n_train], &train, MAX_CONTEXT_TERMS, Criterion::Bic)
            .map_err(|e| anyhow::anyhow!("{what}: context fit of {signal}: {e}"))?;
        let mut pred = vec![sel.model.intercept_um; n];
        for term in &sel.model.terms {
            let c = mine
                .iter()
                .find(|c| c.0 == term.signal)
                .expect("a candidate");
            for (p, v) in pred.iter_mut().zip(&c.1) {
                *p += term.coef * v;
            }
        }
        let heldout = efficiency(&y[n_train..], &pred[n_train..])
            .with_context(|| format!("{what}: {signal}: no held-out samples"))?;
        let ct = ContextTerms {
            intercept_um: sel.model.intercept_um,
            terms: sel
                .model
                .terms
                .iter()
                .map(|t| (t.signal.clone(), t.coef))
                .collect(),
            heldout,
        };
        add_context_terms(spec, Axis::ALL[j], signal, &ct, t_ref, out)?;
    }
    Ok(())
}

fn add_context_terms(
    spec: &mut ModelSpec,
    axis: Axis,
    signal: &str,
    ct: &ContextTerms,
    t_ref: &[(String, f64)],
    out: &mut FitOutcome,
) -> anyhow::Result<()> {
    let target = component(&format!("E{0}{0}", axis.upper()))?;
    let short = signal.trim_end_matches("_um");
    let mut line = format!("{signal}: intercept {:+.3} µm", ct.intercept_um);
    let mut poly_sensors = Vec::new();
    let mut poly_b = Vec::new();
    let reference = |s: &str| {
        t_ref
            .iter()
            .find(|(ch, _)| sensor_of(ch) == s)
            .map(|x| x.1)
            .expect("candidates come from t_ref")
    };
    let add_sensor = |spec: &mut ModelSpec, s: &str| {
        if !spec.sensors.iter().any(|x| x.name == s) {
            spec.sensors.push(SensorSpec {
                name: s.to_string(),
                reference_c: reference(s),
                tau_s: None,
            });
        }
    };
    for (name, coef) in &ct.terms {
        if let Some(s) = name.strip_prefix("dT_") {
            add_sensor(spec, s);
            poly_sensors.push(s.to_string());
            poly_b.push(*coef);
            let _ = write!(line, ", {coef:+.3} µm/K × ΔT_{s}");
        } else if let Some((_, s)) = name.split_once("·dT_") {
            add_sensor(spec, s);
            // coef in µm/(mm·K); 1 ppm/K = 1e-3 µm/(mm·K).
            let alpha = coef * 1e3;
            spec.thermal.push(ThermalSpec {
                name: format!("fit_{short}_expansion_{s}"),
                target,
                kind: ThermalKind::Expansion {
                    sensor: s.to_string(),
                    alpha_ppm_per_k: alpha,
                    origin_mm: 0.0,
                    reference_c: reference(s),
                },
            });
            let _ = write!(line, ", {alpha:+.2} ppm/K × {} × ΔT_{s}", axis.lower());
        } else if let Some(f) = name.strip_prefix("F_").and_then(|f| f.strip_suffix("_N")) {
            if !spec.forces.iter().any(|x| x.name == f) {
                spec.forces.push(ForceSpec {
                    name: f.to_string(),
                    from_strain: None,
                });
            }
            spec.load.push(LoadSpec {
                name: format!("fit_{short}_{f}"),
                target,
                kind: LoadKind::Compliance {
                    force: f.to_string(),
                    compliance: ErrorFunction::Polynomial {
                        coefficients: vec![*coef],
                        range_mm: None,
                    },
                },
            });
            let _ = write!(line, ", {coef:+.4} µm/N × {name}");
        } else {
            bail!("unexpected context term `{name}`");
        }
    }
    if poly_sensors.is_empty() {
        if !ct.terms.is_empty() {
            let _ = write!(line, " (intercept not kept: no ΔT term to carry it)");
        }
    } else {
        spec.thermal.push(ThermalSpec {
            name: format!("fit_{short}_thermal"),
            target,
            kind: ThermalKind::PolynomialDt {
                sensors: poly_sensors,
                e0: ct.intercept_um,
                b_per_k: poly_b,
                c_per_k2: vec![],
            },
        });
    }
    if ct.terms.is_empty() {
        line.push_str(", no term selected");
    }
    let _ = write!(
        line,
        "; last 30 % held out: δ {:.3}, max residual {:.2} µm",
        ct.heldout.delta, ct.heldout.max_residual_um
    );
    out.report.push(line);
    Ok(())
}

/// The whole fit: geometry, then context on top of it. `base` is the machine without error terms.
pub fn fit_model(
    base: &ModelSpec,
    geometry: &[(&AxisPlan, &Recording, &str)],
    context: (&Recording, &str),
) -> anyhow::Result<(MachineModel, FitOutcome)> {
    let mut out = FitOutcome::default();
    let mut spec = base.clone();
    fit_geometry(&mut spec, geometry, &mut out)?;
    let (_, geometric) = to_checked_toml(spec.clone())?;
    let t_ref = reference_temperatures(&geometry.iter().map(|g| g.1).collect::<Vec<_>>());
    fit_context_terms(
        &mut spec, &geometric, context.0, &t_ref, context.1, &mut out,
    )?;
    let (toml, model) = to_checked_toml(spec)?;
    out.toml = toml;
    Ok((model, out))
}
