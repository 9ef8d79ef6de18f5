//! `retrocomp diagnose`: find where a simulation and a recording disagree, name the missing physics
//! from the effect library of docs/diagnose-json.md, fit it, and prove the fit improves on held-out blocks.
//!
//! Residual r = measured − simulated, per error signal (`ex_um` …, µm, actual − nominal). Every
//! finding's parameters are in docs/diagnose-json.md units; adding the finding's term to the simulation reduces r.
//! Pipeline: [`features`] (context per sample) → [`locate`] (where/when) → [`select`] (screen, select,
//! refine, validate, detect ambiguity over [`candidates`]) → joint refit with confidence intervals
//! (this file) → [`report`] (docs/diagnose-json.md JSON / text), [`plots`] and the found-terms TOML ([`output`]).

pub mod candidates;
pub mod effects;
pub mod features;
pub mod forward_check;
pub mod heldout;
pub mod locate;
pub mod lsq;
pub mod model_out;
pub mod model_sim;
mod model_slots;
mod null_model;
pub mod output;
pub mod plots;
pub mod progress;
mod refit;
pub mod regime_check;
pub mod regimes;
pub mod report;
pub mod scoring;
pub mod select;
mod select_step;
pub mod selection;
pub mod sensor_faults;
pub mod swap;

use serde_json::{Map, Value};

use candidates::{Candidate, separating_experiment};
use effects::EffectModel;
use features::Context;
use heldout::Heldout;
use refit::{joint_refit, parsimony_drop};
use report::{AlternativeOut, Dropped, Evidence, Finding, ForwardCheck, Report};
use retrocomp_model::recording::Recording;
use selection::Options;

/// Everything diagnose and its outputs (`--out`, `--model`, the benchmark's manifests) can fail
/// with. Messages are the user's: the CLI prints them with their source chain (`{:#}`).
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    #[error("signal `{signal}` has no simulation: add a `sim_{signal}` column or give --model")]
    NoSimulation { signal: String },
    #[error("the recording has only {0} rows; diagnose needs at least 8")]
    TooShort(usize),
    /// `--model` or the written model needs a column the recording lacks.
    #[error("the model needs column `{0}`, which the recording does not have")]
    MissingColumn(String),
    /// The machine model flagged an input row (invalid input or time going backwards).
    #[error("model evaluation failed at recording line {line}: {flags:?}")]
    ModelEvaluation {
        line: u64,
        flags: retrocomp_model::EvalFlags,
    },
    /// The base model of `--out` (the input model or the default chain) could not be evaluated.
    #[error("evaluating the base model")]
    BaseModel(#[source] Box<DiagnoseError>),
    /// The model with the found terms does not make a valid model file.
    #[error(transparent)]
    Model(#[from] crate::fit::to_model::ToModelError),
    #[error(transparent)]
    Recording(#[from] retrocomp_model::recording::RecordingError),
    /// Creating the output directory or writing report.json / found_terms.toml.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// Writing a named file (the message is the path, the source the I/O error).
    #[error("{path}")]
    Write {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// Drawing an SVG plot (plotters' message).
    #[error("{0}")]
    Plot(String),
    /// A case manifest (`case_NNNN.json`) that cannot be read.
    #[error("{}: {err}", path.display())]
    ReadManifest {
        path: std::path::PathBuf,
        err: std::io::Error,
    },
    #[error("{}: not a case manifest: {err}", path.display())]
    BadManifest {
        path: std::path::PathBuf,
        err: serde_json::Error,
    },
}

/// One signal's result, kept for plots and the found-terms TOML.
#[derive(Clone, Debug)]
pub struct SignalResult {
    pub signal: String,
    pub axis: char,
    pub residual_before: Vec<f64>,
    /// Each accepted term's candidate at its refitted parameter, in acceptance order.
    pub terms: Vec<(Candidate, f64)>,
    /// Coefficients of the cumulative refits behind [`SignalResult::residual_after`]: entry k
    /// holds those of the intercept and the columns of `terms[..=k]`.
    pub after_coef: Vec<Vec<f64>>,
    pub models: Vec<EffectModel>,
    /// What `--out` writes when it is not `models` (`regimes.rs`: named terms left out, the
    /// statistical fit, or nothing); `None`: `models`.
    pub written: Option<Vec<EffectModel>>,
}

impl SignalResult {
    /// Residual after each accepted term (cumulative, intercept removed), in acceptance order,
    /// recomputed from the context with the refits' coefficients (the same arithmetic as the
    /// refit's own residual). Not held: one column per term is 8 MB on a 1M-row recording, and
    /// only the plots and `--out` need them (issue 12 item 10).
    pub fn residual_after(&self, ctx: &Context) -> Vec<Vec<f64>> {
        let mut cols = vec![vec![1.0; self.residual_before.len()]];
        for (c, th) in &self.terms {
            cols.extend(c.columns(ctx, *th));
        }
        self.after_coef
            .iter()
            .map(|b| {
                let upto: Vec<&[f64]> = cols[..b.len()].iter().map(Vec::as_slice).collect();
                lsq::residual(&upto, b, &self.residual_before)
            })
            .collect()
    }
}

#[derive(Debug)]
pub struct Diagnosis {
    pub report: Report,
    pub signals: Vec<SignalResult>,
    pub context: Context,
}

/// Diagnose a recording whose simulation is in its `sim_e*_um` columns.
pub fn diagnose(rec: &Recording, opts: &Options) -> Result<Diagnosis, DiagnoseError> {
    // The recording's own columns, borrowed (not copied: 8 MB each on a 1M-row recording).
    let sims = rec
        .error_signals()
        .into_iter()
        .map(|s| {
            let sim = rec
                .col(&format!("sim_{s}"))
                .ok_or(DiagnoseError::NoSimulation { signal: s.clone() })?;
            Ok((s, sim))
        })
        .collect::<Result<Vec<_>, DiagnoseError>>()?;
    diagnose_sims(rec, &sims, &[], opts)
}

/// As [`diagnose`], taking the recording: the residuals are formed first and the error and sim
/// columns dropped before the search (6 of a recording's columns, 50 MB at 10⁶ rows: issue 12
/// item 10). The same arithmetic, so the same result as [`diagnose`].
pub fn diagnose_owned(mut rec: Recording, opts: &Options) -> Result<Diagnosis, DiagnoseError> {
    let mut residuals = vec![];
    for s in rec.error_signals() {
        let sim = rec
            .col(&format!("sim_{s}"))
            .ok_or(DiagnoseError::NoSimulation { signal: s.clone() })?;
        let meas = rec.col(&s).expect("listed");
        let r: Vec<f64> = meas.iter().zip(sim).map(|(m, s)| m - s).collect();
        residuals.push((s, r));
    }
    rec.retain_columns(|n| {
        !residuals
            .iter()
            .any(|(s, _)| n == s || n.strip_prefix("sim_") == Some(s.as_str()))
    });
    // Cloned one at a time at its turn (the pooled noise pass reads them first).
    let each = residuals.iter().map(|(s, r)| Ok((s.clone(), r.clone())));
    diagnose_residuals(&rec, each, &[], opts)
}

/// Diagnose against an explicit simulation per signal (`(signal, sim_um per row)`).
pub fn diagnose_with_sim(
    rec: &Recording,
    sims: &[(String, Vec<f64>)],
    opts: &Options,
) -> Result<Diagnosis, DiagnoseError> {
    diagnose_with_model_sim(rec, sims, &[], opts)
}

/// [`diagnose_with_sim`] for a simulation that is a machine model, with its thermal inputs
/// (`model_sim::regressors`): forward validation then refits the simulation's gains per fold
/// (`heldout.rs`), so a term is judged against the simulation's own extrapolation error.
pub fn diagnose_with_model_sim(
    rec: &Recording,
    sims: &[(String, Vec<f64>)],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
) -> Result<Diagnosis, DiagnoseError> {
    let sims: Vec<(String, &[f64])> = sims.iter().map(|(s, v)| (s.clone(), &v[..])).collect();
    diagnose_sims(rec, &sims, sim_inputs, opts)
}

fn diagnose_sims(
    rec: &Recording,
    sims: &[(String, &[f64])],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
) -> Result<Diagnosis, DiagnoseError> {
    // Each residual formed when its signal's turn comes (not all at once).
    let residuals = sims.iter().map(|(signal, sim)| {
        let meas = rec.col(signal).ok_or(DiagnoseError::NoSimulation {
            signal: signal.clone(),
        })?;
        let r: Vec<f64> = meas.iter().zip(sim.iter()).map(|(m, s)| m - s).collect();
        Ok((signal.clone(), r))
    });
    diagnose_residuals(rec, residuals, sim_inputs, opts)
}

/// The diagnosis of residuals r = measured − simulated, one `(signal, r)` per error signal.
fn diagnose_residuals(
    rec: &Recording,
    residuals: impl Iterator<Item = Result<(String, Vec<f64>), DiagnoseError>> + Clone,
    sim_inputs: &[Vec<f64>],
    opts: &Options,
) -> Result<Diagnosis, DiagnoseError> {
    if rec.n_rows() < 8 {
        return Err(DiagnoseError::TooShort(rec.n_rows()));
    }
    // Sensor faults first: a faulted column is a finding of its own and is left out of the
    // physics search, so it is never explained as physics (issue 36 point 4).
    let ctx = Context::from_recording(rec);
    let sensor_faults = sensor_faults::scan(&ctx);
    let faulted: Vec<&str> = sensor_faults.iter().map(|f| f.column.as_str()).collect();
    let ctx = ctx.without(&faulted);
    // The recording's noise statistic (`NoiseModel::of`): every signal's residual before any
    // term, read once ahead of the selection.
    // Each signal's first screening is kept for its selection (one screening, not two).
    let (mut taus, mut first_screens) = (vec![], vec![]);
    for res in residuals.clone() {
        let (signal, r) = res?;
        let axis = signal.chars().nth(1).expect("e<axis>_um");
        progress::stage(|| format!("{signal}: noise pre-pass (first screening)"));
        let pre = select::unit_root_taus(&ctx, axis, &r, sim_inputs, opts);
        taus.extend(pre.as_ref().map(|(t, _)| *t));
        first_screens.push(pre.map(|(_, first)| first));
    }
    let recording_rejects = null_model::recording_rejects_unit_root(&taus);
    let mut out = Assembly {
        sensor_faults,
        ..Assembly::default()
    };
    for (res, first_screen) in residuals.zip(first_screens) {
        let (signal, r) = res?;
        let signal = &signal;
        let axis = signal.chars().nth(1).expect("e<axis>_um");
        out.all_sq += r.iter().map(|v| v * v).sum::<f64>();
        out.all_n += r.len();
        out.mismatch.extend(locate::locate(&ctx, signal, &r));
        let mut sel = select::select_pooled(
            &ctx,
            axis,
            &r,
            sim_inputs,
            opts,
            recording_rejects,
            first_screen,
        );
        progress::stage(|| format!("{signal}: joint refit, parsimony and checks"));
        let (models, cis, after_coef, refit_terms) =
            out.parsimony(&ctx, &r, &mut sel, signal, sim_inputs, opts);
        out.exchanged(&sel, signal);
        let regime = regimes::check(&ctx, axis, &r, sim_inputs, &refit_terms, opts);
        out.findings(&sel, &models, &cis, signal);
        if let Some(o) = &regime {
            regimes::set_driver_ranges(&mut out.findings, signal, &o.ranges);
        }
        out.runners_up(&sel, signal, opts);
        let mut result = SignalResult {
            signal: signal.clone(),
            axis,
            residual_before: r,
            terms: refit_terms,
            after_coef,
            models,
            written: None,
        };
        let final_resid = result.residual_after(&ctx).pop().unwrap_or_else(|| {
            let r = &result.residual_before;
            let m = r.iter().sum::<f64>() / r.len() as f64;
            r.iter().map(|v| v - m).collect()
        });
        out.mismatch
            .extend(locate::unexplained(&ctx, signal, &final_resid));
        drop(final_resid);
        out.forward_check
            .extend(regimes::with_regimes(&ctx, &mut result, regime));
        result.after_coef.shrink_to_fit();
        out.signals.push(result);
    }
    Ok(out.finish(ctx))
}

/// The report as it is assembled from each signal's selection ([`diagnose_residuals`]).
#[derive(Default)]
struct Assembly {
    /// Found before the physics search (`sensor_faults.rs`), listed before any finding.
    sensor_faults: Vec<sensor_faults::SensorFault>,
    /// Each finding with its RSS gain (the report lists the largest first).
    findings: Vec<(f64, Finding)>,
    alternatives: Vec<AlternativeOut>,
    dropped: Vec<Dropped>,
    forward_check: Vec<ForwardCheck>,
    mismatch: Vec<report::Mismatch>,
    signals: Vec<SignalResult>,
    ambiguous: bool,
    all_sq: f64,
    all_n: usize,
}

impl Assembly {
    /// Parsimony after the final refit (issue 12 point 3), one term at a time, the rest refitted
    /// jointly after each drop: first a term whose 95 % interval of its gain includes 0 once
    /// every term is fitted jointly (the weakest first); then a term whose removal does not
    /// raise the held-out RMS (forward on thermal tests: `heldout.rs`) by the bar a term needs
    /// to enter (`cv_min_gain`), the one whose removal leaves the lowest held-out RMS first.
    /// The second test also catches pairs of near-collinear lags with opposite gains that fit
    /// a difference of two sensors without predicting better than one of them.
    fn parsimony(
        &mut self,
        ctx: &Context,
        r: &[f64],
        sel: &mut select::SignalSelection,
        signal: &str,
        sim_inputs: &[Vec<f64>],
        opts: &Options,
    ) -> refit::Refit {
        let axis = sel.axis;
        let heldout = Heldout::new(ctx, axis, r, sim_inputs, opts);
        loop {
            let (models, cis, after_coef, refit_terms) = joint_refit(ctx, r, &sel.terms);
            let Some((k, reason, with, without)) =
                parsimony_drop(&heldout, r, &sel.terms, &cis, opts)
            else {
                return (models, cis, after_coef, refit_terms);
            };
            let t = sel.terms.remove(k);
            let why = if reason == "ci_includes_zero" {
                "the 95 % interval of its gain includes 0".to_string()
            } else if reason == "no_forward_gain" {
                format!(
                    "removing it lowers the forward-check RMS by more than {:.0} %, and by more than it raises the held-out RMS ({with:.3} → {without:.3} µm forward)",
                    100.0 * opts.cv_min_gain
                )
            } else {
                format!(
                    "removing it does not raise the held-out RMS by {:.0} % ({with:.3} → {without:.3} µm)",
                    100.0 * opts.cv_min_gain
                )
            };
            self.alternatives.push(AlternativeOut {
                effect: t.cand.effect_id().into(),
                axis: Some(axis.to_string()),
                why_not: format!(
                    "{} on {signal} was selected (ΔBIC {:.1}) but dropped after the final joint refit: {why}",
                    t.cand.label(),
                    t.delta_bic
                ),
                experiment: None,
            });
            self.dropped.push(Dropped {
                effect: t.cand.effect_id().into(),
                axis: axis.to_string(),
                signal: signal.to_string(),
                term: t.cand.label(),
                reason: reason.into(),
                heldout_rms_with_um: with,
                heldout_rms_without_um: without,
                score: if reason == "no_forward_gain" {
                    "forward_check"
                } else {
                    "heldout"
                }
                .into(),
                replaced_by: vec![],
            });
        }
    }

    /// Terms accepted and later replaced by the exchange step (unless back in the final set).
    fn exchanged(&mut self, sel: &select::SignalSelection, signal: &str) {
        let axis = sel.axis;
        for ex in &sel.exchanged {
            let label = ex.term.cand.label();
            if sel.terms.iter().any(|t| t.cand.label() == label) {
                continue;
            }
            self.dropped.push(Dropped {
                effect: ex.term.cand.effect_id().into(),
                axis: axis.to_string(),
                signal: signal.to_string(),
                term: label,
                reason: "exchanged".into(),
                heldout_rms_with_um: ex.heldout_rms_before_um,
                heldout_rms_without_um: ex.heldout_rms_after_um,
                score: "heldout".into(),
                replaced_by: ex.by.clone(),
            });
        }
    }

    /// The final terms as findings, and their ambiguous alternatives.
    fn findings(
        &mut self,
        sel: &select::SignalSelection,
        models: &[EffectModel],
        cis: &[Map<String, Value>],
        signal: &str,
    ) {
        let axis = sel.axis;
        for (k, term) in sel.terms.iter().enumerate() {
            let model = &models[k];
            let mut params =
                match serde_json::to_value(model).expect("serialisable")["params"].clone() {
                    Value::Object(m) => m,
                    _ => Map::new(),
                };
            params.retain(|_, v| !v.is_null());
            // A lag of a power of a column names the column and the exponent it acts through.
            let power = params
                .get("sensor")
                .and_then(Value::as_str)
                .and_then(|s| features::power_of(s).map(|(c, p, _)| (c.to_string(), p)));
            if let Some((column, exponent)) = power {
                params.insert("column".into(), column.into());
                params.insert("exponent".into(), exponent.into());
            }
            self.findings.push((
                term.gain_rss,
                Finding {
                    effect: model.id().into(),
                    axis: axis.to_string(),
                    signal: signal.to_string(),
                    explanation: report::explanation(model.id()).into(),
                    equation: model.equation(axis),
                    params,
                    ci95: cis[k].clone(),
                    evidence: Evidence {
                        delta_bic: term.delta_bic,
                        p_value: term.p_value,
                    },
                    rms_after_um: term.rms_after_um,
                    heldout_rms_before_um: term.heldout_rms_before_um,
                    heldout_rms_after_um: term.heldout_rms_after_um,
                    driver_range: None,
                },
            ));
            for alt in &term.ambiguous_with {
                self.ambiguous = true;
                let exp = separating_experiment(term.cand.effect_id(), alt.cand.effect_id());
                self.alternatives.push(AlternativeOut {
                    effect: alt.cand.effect_id().into(),
                    axis: Some(axis.to_string()),
                    why_not: format!(
                        "{} explains the same residual of {signal} as {} (ΔBIC {:.1} vs {:.1}, correlation {:.3}): the data cannot separate them; {exp}",
                        alt.cand.label(),
                        term.cand.label(),
                        alt.delta_bic,
                        term.delta_bic,
                        alt.corr
                    ),
                    experiment: Some(exp),
                });
            }
        }
    }

    /// Runners-up of the first step that were not taken: why not.
    fn runners_up(&mut self, sel: &select::SignalSelection, signal: &str, opts: &Options) {
        let axis = sel.axis;
        let chosen: Vec<String> = sel
            .terms
            .iter()
            .map(|t| t.cand.effect_id().to_string())
            .collect();
        let (first_label, best) = sel.first_choice.clone().unwrap_or_default();
        for (c, dbic) in sel
            .runners_up
            .iter()
            .filter(|(c, _)| !chosen.iter().any(|e| e == c.effect_id()))
            .take(2)
        {
            if self.alternatives.iter().any(|a: &AlternativeOut| {
                a.effect == c.effect_id() && a.axis.as_deref() == Some(&axis.to_string())
            }) {
                continue;
            }
            let why = if sel.terms.is_empty() {
                format!(
                    "best candidate for {signal} but below the bar (ΔBIC {dbic:.1}; needs > {} with a Holm-corrected F-test and a held-out gain)",
                    opts.min_delta_bic
                )
            } else {
                format!(
                    "{} on {signal}: ΔBIC {dbic:.1} against {best:.1} for {first_label}, the term chosen at the first step",
                    c.label()
                )
            };
            self.alternatives.push(AlternativeOut {
                effect: c.effect_id().into(),
                axis: Some(axis.to_string()),
                why_not: why,
                experiment: None,
            });
        }
    }

    /// The report (findings by RSS gain, the verdict) and the diagnosis.
    fn finish(self, ctx: Context) -> Diagnosis {
        let Assembly {
            sensor_faults,
            mut findings,
            alternatives,
            dropped,
            forward_check,
            mismatch,
            signals,
            ambiguous,
            all_sq,
            all_n,
        } = self;
        findings.sort_by(|a, b| b.0.total_cmp(&a.0));
        let findings: Vec<Finding> = findings.into_iter().map(|f| f.1).collect();
        let verdict = if findings.is_empty() {
            "none"
        } else if ambiguous {
            "ambiguous"
        } else {
            "found"
        };
        let report = Report {
            verdict: verdict.into(),
            rms_before_um: (all_sq / all_n.max(1) as f64).sqrt(),
            sensor_faults,
            mismatch,
            findings,
            alternatives,
            dropped,
            forward_check,
        };
        Diagnosis {
            report,
            signals,
            context: ctx,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candidates::{Candidate, Kind};
    use selection::Term;
    use serde_json::json;

    /// Parsimony's removal test: of two lags of near-identical sensors (the second a copy of the
    /// first plus a little noise), whose gains' intervals both exclude 0, one does not improve
    /// the forward held-out error once the other is in, and is dropped as `no_heldout_gain`; the
    /// one left stays (removing it would raise the held-out error).
    #[test]
    fn parsimony_drops_a_term_whose_removal_does_not_hurt_forward_error() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 1200;
        let t: Vec<f64> = (0..n).map(|i| 15.0 * i as f64).collect();
        // Heating steps every 150 rows, so a 900 s lag has structure in every forward block.
        let a: Vec<f64> = (0..n)
            .map(|i| 20.0 + if (i / 150) % 2 == 0 { 0.0 } else { 5.0 })
            .collect();
        let b: Vec<f64> = a
            .iter()
            .map(|v| v + rng.random_range(-0.05..0.05))
            .collect();
        let rec = Recording::from_columns(vec![
            ("t_s".into(), t),
            ("T_a_C".into(), a),
            ("T_b_C".into(), b),
            ("ez_um".into(), vec![0.0; n]),
        ])
        .unwrap();
        let ctx = Context::from_recording(&rec);
        let lag = |s: &str| Candidate {
            axis: 'z',
            kind: Kind::ThermalLag { sensor: s.into() },
            grid: vec![900.0],
        };
        let (ca, cb) = (lag("T_a_C"), lag("T_b_C"));
        let col = ca.columns(&ctx, 900.0).remove(0);
        let r: Vec<f64> = col
            .iter()
            .map(|v| 2.0 * v + rng.random_range(-0.3..0.3))
            .collect();
        let term = |c: &Candidate| Term::accepted(c.clone(), 900.0, c.columns(&ctx, 900.0));
        let opts = Options::default();
        let heldout = Heldout::new(&ctx, 'z', &r, &[], &opts);
        assert!(
            heldout.forward,
            "a thermal-only recording is validated forward"
        );
        // Intervals that exclude 0, so only the removal test can drop a term.
        let ci = || {
            let mut m = Map::new();
            m.insert("um_per_K".into(), json!([0.5, 3.0]));
            m
        };
        let both = [term(&ca), term(&cb)];
        let (k, reason, with, without) = parsimony_drop(&heldout, &r, &both, &[ci(), ci()], &opts)
            .expect("one of the pair goes");
        assert_eq!(reason, "no_heldout_gain");
        assert!(
            k < 2 && without <= with / (1.0 - opts.cv_min_gain),
            "{with} {without}"
        );
        let one = [term(&ca)];
        assert!(
            parsimony_drop(&heldout, &r, &one, &[ci()], &opts).is_none(),
            "the lag that explains the residual stays"
        );
        // The interval test comes first.
        let mut zero = Map::new();
        zero.insert("um_per_K".into(), json!([-0.1, 3.0]));
        let (k, reason, ..) = parsimony_drop(&heldout, &r, &both, &[ci(), zero], &opts).unwrap();
        assert_eq!((k, reason), (1, "ci_includes_zero"));
    }
}
