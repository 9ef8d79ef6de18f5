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

use super::error::{Context as _, DemoError};

use super::campaign::{AxisPlan, REFERENCE_MM};
use super::readings::{ERR, readings, readings_csv};
use retrocomp_analysis::fit::regression::{Candidate, Criterion, select};
use retrocomp_analysis::fit::to_model::{AxisForm, axis_component, put_component, to_checked_toml};
use retrocomp_analysis::fit::workflow::fit_axis;
use retrocomp_analysis::fit::{Efficiency, efficiency};
use retrocomp_analysis::iso230_2::Reading;
use retrocomp_model::approach::{ApproachLatch, RECORDED_DEADBAND_MM};
use retrocomp_model::parse_component;
use retrocomp_model::recording::Recording;
use retrocomp_model::units::ChannelKind;
use retrocomp_model::{Axis, ComponentId, ErrorFunction, MachineModel, ModelSpec};
use retrocomp_model::{ForceSpec, LoadKind, LoadSpec, SensorSpec, ThermalKind, ThermalSpec};

/// Significance of a knot (Spaan: 99.99 %).
const KNOT_ALPHA: f64 = 1e-4;
/// Largest number of context terms per error signal.
const MAX_CONTEXT_TERMS: usize = 3;

/// What the fit produced, for the report and the plots.
#[derive(Clone, Debug, Default)]
pub(crate) struct FitOutcome {
    /// The model TOML (already re-read through the validating parser).
    pub toml: String,
    /// One line per fitted component / context signal.
    pub report: Vec<String>,
    /// `readings_<EJK>.csv` files (ISO 230-2 long CSV) for `retrocomp fit axis`.
    pub readings_csv: Vec<(String, String)>,
}

fn component(name: &str) -> Result<ComponentId, DemoError> {
    parse_component(name).with_context(|| format!("`{name}` is not a component name"))
}

/// Subtracts the mean reading at the reference coordinate (both directions, all runs).
fn zero_at_reference(r: &mut [Reading], reference_mm: f64) -> Result<(), DemoError> {
    let at: Vec<f64> = r
        .iter()
        .filter(|x| (x.target_mm - reference_mm).abs() < 1e-9)
        .map(|x| x.deviation_um)
        .collect();
    if at.is_empty() {
        return Err(DemoError::Failed(format!(
            "no reading at the reference {reference_mm} mm"
        )));
    }
    let mean = at.iter().sum::<f64>() / at.len() as f64;
    for x in r {
        x.deviation_um -= mean;
    }
    Ok(())
}

/// Fits the geometric tables into `spec` from one recording per plan.
pub(crate) fn fit_geometry(
    spec: &mut ModelSpec,
    runs: &[(&AxisPlan, &Recording, &str)],
    out: &mut FitOutcome,
) -> Result<(), DemoError> {
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
                .map_err(|e| DemoError::Failed(format!("{what}: fit of {name}: {e}")))?;
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
pub(crate) fn reference_temperatures(recs: &[&Recording]) -> Vec<(String, f64)> {
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

/// Direction latch per axis from the nominal motion (+1/−1; 0 until the axis first moves): the
/// shared definition of [`retrocomp_model::approach`].
fn latched_directions(pos: &[&[f64]]) -> Vec<[i8; 3]> {
    let n = pos[0].len();
    let mut latches: Vec<ApproachLatch> = pos
        .iter()
        .map(|_| ApproachLatch::new(RECORDED_DEADBAND_MM))
        .collect();
    let mut d = [0i8; 3];
    (0..n)
        .map(|i| {
            for (k, p) in pos.iter().enumerate() {
                latches[k].update(p[i]);
                d[k] = latches[k].dir();
            }
            d
        })
        .collect()
}

/// The fitted geometry's error along the recording's nominal path (what the context terms are
/// fitted on top of), per sample.
fn geometric_errors(geometric: &MachineModel, pos: &[&[f64]], t: &[f64]) -> Vec<[f64; 3]> {
    let n = t.len();
    let dirs = latched_directions(pos);
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
    geo
}

/// A context regressor: name, values, and the axis whose signal it may explain (`usize::MAX`:
/// any).
type ContextCandidate = (String, Vec<f64>, usize);

/// Every context regressor of the recording: per cold-referenced sensor ΔT and q·ΔT for each axis
/// q, then each force channel.
fn context_candidates(
    rec: &Recording,
    t_ref: &[(String, f64)],
    pos: &[&[f64]],
) -> Vec<ContextCandidate> {
    let mut cands: Vec<ContextCandidate> = Vec::new();
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
        .filter(|c| ChannelKind::of(c) == ChannelKind::ForceN)
    {
        cands.push((
            ch.clone(),
            rec.col(&ch).expect("listed").to_vec(),
            usize::MAX,
        ));
    }
    cands
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
pub(crate) fn fit_context_terms(
    spec: &mut ModelSpec,
    geometric: &MachineModel,
    rec: &Recording,
    t_ref: &[(String, f64)],
    what: &str,
    out: &mut FitOutcome,
) -> Result<(), DemoError> {
    let t = rec.t_s();
    let n = t.len();
    let pos: Vec<&[f64]> = ["x_mm", "y_mm", "z_mm"]
        .iter()
        .map(|c| {
            rec.col(c)
                .with_context(|| format!("{what}: no column `{c}`"))
        })
        .collect::<Result<_, DemoError>>()?;
    let geo = geometric_errors(geometric, &pos, t);
    let n_train = n * 7 / 10;
    let cands = context_candidates(rec, t_ref, &pos);
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
        let mine: Vec<&ContextCandidate> = cands
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
            .map_err(|e| DemoError::Failed(format!("{what}: context fit of {signal}: {e}")))?;
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
) -> Result<(), DemoError> {
    let target = component(&format!("E{0}{0}", axis.upper()))?;
    let short = signal.trim_end_matches("_um");
    let mut line = format!("{signal}: intercept {:+.3} µm", ct.intercept_um);
    let mut poly_sensors = Vec::new();
    let mut poly_b = Vec::new();
    for (name, coef) in &ct.terms {
        if let Some(s) = name.strip_prefix("dT_") {
            add_sensor(spec, t_ref, s);
            poly_sensors.push(s.to_string());
            poly_b.push(*coef);
            let _ = write!(line, ", {coef:+.3} µm/K × ΔT_{s}");
        } else if let Some((_, s)) = name.split_once("·dT_") {
            add_sensor(spec, t_ref, s);
            // coef in µm/(mm·K); 1 ppm/K = 1e-3 µm/(mm·K).
            let alpha = coef * 1e3;
            spec.thermal.push(ThermalSpec {
                name: format!("fit_{short}_expansion_{s}"),
                target,
                kind: ThermalKind::Expansion {
                    sensor: s.to_string(),
                    alpha_ppm_per_k: alpha,
                    origin_mm: 0.0,
                    reference_c: reference(t_ref, s),
                },
            });
            let _ = write!(line, ", {alpha:+.2} ppm/K × {} × ΔT_{s}", axis.lower());
        } else if let Some(f) = name.strip_prefix("F_").and_then(|f| f.strip_suffix("_N")) {
            add_compliance(spec, target, short, f, *coef);
            let _ = write!(line, ", {coef:+.4} µm/N × {name}");
        } else {
            return Err(DemoError::Failed(format!(
                "unexpected context term `{name}`"
            )));
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

/// The cold reference temperature of sensor `s`.
fn reference(t_ref: &[(String, f64)], s: &str) -> f64 {
    t_ref
        .iter()
        .find(|(ch, _)| sensor_of(ch) == s)
        .map(|x| x.1)
        .expect("candidates come from t_ref")
}

/// Declares sensor `s` (at its cold reference) unless `spec` has it already.
fn add_sensor(spec: &mut ModelSpec, t_ref: &[(String, f64)], s: &str) {
    if !spec.sensors.iter().any(|x| x.name == s) {
        spec.sensors.push(SensorSpec {
            name: s.to_string(),
            reference_c: reference(t_ref, s),
            tau_s: None,
            column: None,
            exponent: None,
        });
    }
}

/// A compliance load term of force `f` (µm/N) on `target`, declaring the force if it is new.
fn add_compliance(spec: &mut ModelSpec, target: ComponentId, short: &str, f: &str, coef: f64) {
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
                coefficients: vec![coef],
                range_mm: None,
            },
        },
    });
}

/// The whole fit: geometry, then context on top of it. `base` is the machine without error terms.
pub(crate) fn fit_model(
    base: &ModelSpec,
    geometry: &[(&AxisPlan, &Recording, &str)],
    context: (&Recording, &str),
) -> Result<(MachineModel, FitOutcome), DemoError> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A context recording with known terms: ex = 11.5 ppm/K · x · ΔT_xscrew + 0.004 µm/N · F,
    /// ey = 0.003 µm/N · F, ez = −6 µm/K · ΔT_spindle − 0.002 µm/N · F (the demo mill's values),
    /// plus ±0.05 µm of deterministic pseudo-noise; references 20 °C.
    fn context() -> Recording {
        let n = 3000;
        let mut cols: Vec<(String, Vec<f64>)> = [
            "t_s",
            "x_mm",
            "y_mm",
            "z_mm",
            "ex_um",
            "ey_um",
            "ez_um",
            "T_spindle_C",
            "T_xscrew_C",
            "F_cut_N",
        ]
        .iter()
        .map(|n| (n.to_string(), Vec::new()))
        .collect();
        for i in 0..n {
            let t = f64::from(i) * 0.05;
            let x = 75.0 + 75.0 * (0.3 * t).sin();
            let y = 50.0 + 50.0 * (0.17 * t).sin();
            let z = 25.0 + 25.0 * (0.11 * t).sin();
            let ts = 20.0 + 5.0 * (1.0 - (-t / 30.0).exp()) * (1.0 + 0.3 * (0.05 * t).sin());
            let tx = 20.0 + 8.0 * (1.0 - (-t / 15.0).exp()) * (1.0 + 0.5 * (0.023 * t).cos());
            let f = if retrocomp_analysis::numeric::trunc_usize(t / 10.0) % 2 == 1 {
                200.0 * (0.5 * t).sin().abs()
            } else {
                0.0
            };
            let noise = |k: f64| 0.05 * (7.3 * f64::from(i) + k).sin();
            let ex = 0.0115 * x * (tx - 20.0) + 0.004 * f + noise(0.0);
            let ey = 0.003 * f + noise(1.0);
            let ez = -6.0 * (ts - 20.0) - 0.002 * f + noise(2.0);
            for (c, v) in cols.iter_mut().zip([t, x, y, z, ex, ey, ez, ts, tx, f]) {
                c.1.push(v);
            }
        }
        Recording::from_columns(cols).unwrap()
    }

    fn base() -> ModelSpec {
        MachineModel::from_toml_str(super::super::BASE_MODEL, "base")
            .unwrap()
            .spec()
            .clone()
    }

    #[test]
    fn context_terms_recover_expansion_growth_and_compliance_with_their_signs() {
        let mut spec = base();
        let geometric = MachineModel::from_spec(spec.clone());
        let t_ref = vec![
            ("T_spindle_C".to_string(), 20.0),
            ("T_xscrew_C".to_string(), 20.0),
        ];
        let mut out = FitOutcome::default();
        fit_context_terms(&mut spec, &geometric, &context(), &t_ref, "ctx", &mut out).unwrap();
        let report = out.report.join("\n");
        let alpha: Vec<f64> = spec
            .thermal
            .iter()
            .filter_map(|t| match &t.kind {
                ThermalKind::Expansion {
                    sensor,
                    alpha_ppm_per_k,
                    ..
                } if sensor == "xscrew" && t.target.iso_name() == "EXX" => Some(*alpha_ppm_per_k),
                _ => None,
            })
            .collect();
        assert!(
            alpha.len() == 1 && (alpha[0] - 11.5).abs() < 0.2,
            "{alpha:?}\n{report}"
        );
        let growth = spec.thermal.iter().find_map(|t| match &t.kind {
            ThermalKind::PolynomialDt {
                sensors, b_per_k, ..
            } if t.target.iso_name() == "EZZ" => sensors
                .iter()
                .position(|s| s == "spindle")
                .map(|k| b_per_k[k]),
            _ => None,
        });
        assert!(
            growth.is_some_and(|b| (b + 6.0).abs() < 0.05),
            "{growth:?}\n{report}"
        );
        for (target, want) in [("EXX", 0.004), ("EYY", 0.003), ("EZZ", -0.002)] {
            let c = spec.load.iter().find_map(|l| match &l.kind {
                LoadKind::Compliance {
                    force,
                    compliance: ErrorFunction::Polynomial { coefficients, .. },
                } if force == "cut" && l.target.iso_name() == target => Some(coefficients[0]),
                _ => None,
            });
            assert!(
                c.is_some_and(|c| (c - want).abs() < 2e-4),
                "{target}: {c:?}\n{report}"
            );
        }
        // End to end through the written model: at x = 100 mm, the screw 2 K over its reference,
        // no force, the spindle at its reference: ex = 11.5e-3 µm/(mm·K) · 100 mm · 2 K = +2.3 µm.
        let (_, model) = to_checked_toml(spec).unwrap();
        let mut input = model.new_input();
        input.pos_mm = [100.0, 0.0, 0.0];
        for (k, s) in model.temperature_sensors().iter().enumerate() {
            input.temps_c[k] = if s == "xscrew" { 22.0 } else { 20.0 };
        }
        let (mut st, mut bd) = (model.new_state(), model.new_breakdown());
        model.evaluate(&input, &mut st, &mut bd);
        assert!(
            (bd.total_um[0] - 2.3).abs() < 0.1,
            "{:?}\n{report}",
            bd.total_um
        );
    }

    #[test]
    fn y_and_z_tables_are_zeroed_at_the_reference_and_directions_latch() {
        let mut r: Vec<Reading> = [(0.0, 3.0), (0.0, 5.0), (10.0, 9.0)]
            .iter()
            .map(|&(t, v)| Reading {
                target_mm: t,
                run: 1,
                direction: retrocomp_analysis::table::Direction::Forward,
                deviation_um: v,
            })
            .collect();
        zero_at_reference(&mut r, 0.0).unwrap();
        let v: Vec<f64> = r.iter().map(|x| x.deviation_um).collect();
        assert_eq!(v, [-1.0, 1.0, 5.0]);
        assert!(zero_at_reference(&mut r, 7.0).is_err());
        let x = [0.0, 1.0, 1.0, 0.5];
        let still = [2.0; 4];
        let d = latched_directions(&[&x, &still, &still]);
        assert_eq!(d, [[0, 0, 0], [1, 0, 0], [1, 0, 0], [-1, 0, 0]]);
    }
}
