//! `retrocomp diagnose`: find where a simulation and a recording disagree, name the missing physics
//! from the effect library of docs/diagnose-json.md, fit it, and prove the fit improves on held-out blocks.
//!
//! Residual r = measured − simulated, per error signal (`ex_um` …, µm, actual − nominal). Every
//! finding's parameters are in docs/diagnose-json.md units; adding the finding's term to the simulation reduces r.
//! Pipeline: [`features`] (context per sample) → `locate` (where/when) → [`select`] (screen, select,
//! refine, validate, detect ambiguity over [`candidates`]) → joint refit with confidence intervals
//! (this file) → [`report`] (docs/diagnose-json.md JSON / text), [`plots`] and the found-terms TOML ([`output`]).

mod assembly;
pub mod candidates;
pub mod effects;
pub mod features;
mod forward_check;
mod heldout;
mod locate;
pub mod lsq;
mod model_out;
pub mod model_sim;
mod model_slots;
mod null_model;
pub mod output;
pub mod plots;
pub mod progress;
mod refit;
mod regime_check;
mod regimes;
pub mod report;
pub mod scoring;
pub mod select;
mod select_step;
mod selection;
pub mod sensor_faults;
pub mod swap;

use rayon::prelude::*;

use assembly::Assembly;
use candidates::Candidate;
use effects::EffectModel;
use features::Context;
use report::Report;

pub use model_out::{ModelOut, model_with_findings};
pub use regime_check::{DriverRange, Excursion, RegimeCheck};
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
    diagnose_residuals(&rec, residuals, &[], opts)
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
    let residuals = sims
        .iter()
        .map(|(signal, sim)| {
            let meas = rec.col(signal).ok_or(DiagnoseError::NoSimulation {
                signal: signal.clone(),
            })?;
            let r: Vec<f64> = meas.iter().zip(sim.iter()).map(|(m, s)| m - s).collect();
            Ok((signal.clone(), r))
        })
        .collect::<Result<Vec<_>, DiagnoseError>>()?;
    diagnose_residuals(rec, residuals, sim_inputs, opts)
}

/// Above this many rows the error signals are diagnosed one after another; at or below it, side by
/// side on rayon's pool (each signal's selection screens its candidates in parallel either way).
/// Two signals at once hold two selections' candidate columns and held-out folds: on a 10⁶-row
/// recording that would pass the 500 MB a diagnosis may use (docs/performance.md).
pub const SIGNALS_SIDE_BY_SIDE_MAX_ROWS: usize = 250_000;

/// The diagnosis of residuals r = measured − simulated, one `(signal, r)` per error signal.
/// Signals are independent until the report is assembled: each gives an [`assembly::Part`] (in
/// parallel on small recordings), merged in signal order, so the report is the same whether they
/// ran side by side or in turn.
fn diagnose_residuals(
    rec: &Recording,
    residuals: Vec<(String, Vec<f64>)>,
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
    let side_by_side = rec.n_rows() <= SIGNALS_SIDE_BY_SIDE_MAX_ROWS;
    // The recording's noise statistic (`NoiseModel::of`): every signal's residual before any
    // term, read once ahead of the selection.
    // Each signal's first screening is kept for its selection (one screening, not two).
    let pre = each_signal(side_by_side, &residuals, |(signal, r)| {
        progress::stage(|| format!("{signal}: noise pre-pass (first screening)"));
        select::unit_root_taus(&ctx, axis_of(signal), r, sim_inputs, opts)
    });
    let taus: Vec<(f64, f64)> = pre.iter().flatten().map(|(t, _)| *t).collect();
    let recording_rejects = null_model::recording_rejects_unit_root(&taus);
    let work: Vec<_> = residuals
        .into_iter()
        .zip(pre.into_iter().map(|p| p.map(|(_, first)| first)))
        .collect();
    let parts = each_signal(side_by_side, work, |((signal, r), first_screen)| {
        let axis = axis_of(&signal);
        let sel = select::select_pooled(
            &ctx,
            axis,
            &r,
            sim_inputs,
            opts,
            recording_rejects,
            first_screen,
        );
        assembly::Part::of(&ctx, signal, r, sel, sim_inputs, opts)
    });
    let mut out = Assembly::new(sensor_faults);
    for part in parts {
        out.merge(part);
    }
    Ok(out.finish(ctx))
}

/// The axis of an error signal `e<axis>_um`.
fn axis_of(signal: &str) -> char {
    signal.chars().nth(1).expect("e<axis>_um")
}

/// `f` over every signal's item, in parallel when `side_by_side`; the results in the items' order
/// either way (rayon's `collect` keeps it).
fn each_signal<T: Send, U: Send>(
    side_by_side: bool,
    items: impl IntoParallelIterator<Item = T> + IntoIterator<Item = T>,
    f: impl Fn(T) -> U + Sync + Send,
) -> Vec<U> {
    if side_by_side {
        items.into_par_iter().map(f).collect()
    } else {
        items.into_iter().map(f).collect()
    }
}

/// A rayon pool of `threads` threads: the tests that lock "the same bits with any number of
/// threads" run the same call in pools of different sizes.
#[cfg(test)]
pub(crate) fn test_pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
}

#[cfg(test)]
mod tests {
    use super::*;
    use candidates::{Candidate, Kind};
    use heldout::Heldout;
    use refit::parsimony_drop;
    use selection::Term;
    use serde_json::{Map, json};

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
