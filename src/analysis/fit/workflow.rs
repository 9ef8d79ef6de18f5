//! The `fit` workflows: measurements in, fitted functions + held-out validation out.
//!
//! - [`fit_axis`]: laser runs of one axis → forward and reverse C¹ piecewise quadratics (stepwise
//!   knots), validated on a held-out run.
//! - [`fit_context`]: a recording → linear model of one error signal on temperatures (optionally
//!   lagged) and/or strains, with subset selection, validated on held-out runs (`run` column) or,
//!   without one, on the last 30 % of the samples.
//!
//! The output is serialisable ([`AxisFit`], [`ContextFit`]) and written as TOML by the CLI.

use serde::Serialize;

use super::efficiency::{Efficiency, efficiency};
use super::piecewise::{PiecewiseError, PiecewiseQuadratic, fit_stepwise};
use super::regression::{
    Candidate, Criterion, LinearModel, RegressionError, Selection, first_order_lag, select,
};
use crate::analysis::iso230_2::Reading;
use crate::analysis::table::Direction;
use crate::recording::Recording;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisFit {
    pub forward: PiecewiseQuadratic,
    pub reverse: PiecewiseQuadratic,
    pub heldout_run: Option<u32>,
    /// Efficiency δ and max residual on the held-out run (None without one).
    pub heldout: Option<Efficiency>,
    pub fit_rms_um: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    #[error("held-out run {0} is not in the data")]
    NoSuchRun(u32),
    #[error("column `{0}` is not in the recording")]
    NoColumn(String),
    #[error("{0}")]
    Piecewise(#[from] PiecewiseError),
    #[error("{0}")]
    Regression(#[from] RegressionError),
    #[error("no held-out data")]
    NoHeldout,
}

/// Fits both directions; `knot_step_mm` spaces the candidate knots across the travel.
pub fn fit_axis(
    readings: &[Reading],
    knot_step_mm: f64,
    alpha: f64,
    heldout_run: Option<u32>,
) -> Result<AxisFit, FitError> {
    if let Some(r) = heldout_run
        && !readings.iter().any(|x| x.run == r)
    {
        return Err(FitError::NoSuchRun(r));
    }
    let train: Vec<&Reading> = readings
        .iter()
        .filter(|r| Some(r.run) != heldout_run)
        .collect();
    let (lo, hi) = train
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), r| {
            (a.min(r.target_mm), b.max(r.target_mm))
        });
    let cands: Vec<f64> = (1..)
        .map(|k| lo + knot_step_mm * f64::from(k))
        .take_while(|t| *t < hi)
        .collect();
    let fit_dir = |d: Direction| {
        let pts: Vec<(f64, f64)> = train
            .iter()
            .filter(|r| r.direction == d)
            .map(|r| (r.target_mm, r.deviation_um))
            .collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = pts.into_iter().unzip();
        fit_stepwise(&xs, &ys, &cands, alpha)
    };
    let forward = fit_dir(Direction::Forward)?;
    let reverse = fit_dir(Direction::Reverse)?;
    let model = |r: &Reading| {
        if r.direction == Direction::Forward {
            forward.eval(r.target_mm)
        } else {
            reverse.eval(r.target_mm)
        }
    };
    let fit_rms_um = (train
        .iter()
        .map(|r| (r.deviation_um - model(r)).powi(2))
        .sum::<f64>()
        / train.len() as f64)
        .sqrt();
    let heldout = heldout_run.and_then(|run| {
        let h: Vec<&Reading> = readings.iter().filter(|r| r.run == run).collect();
        efficiency(
            &h.iter().map(|r| r.deviation_um).collect::<Vec<_>>(),
            &h.iter().map(|r| model(r)).collect::<Vec<_>>(),
        )
    });
    Ok(AxisFit {
        forward,
        reverse,
        heldout_run,
        heldout,
        fit_rms_um,
    })
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ContextFit {
    pub signal: String,
    pub selection: Selection,
    pub model: LinearModel,
    /// How the held-out data was chosen.
    pub heldout_rule: String,
    pub heldout: Efficiency,
}

/// Fits `signal` on the recording's temperatures (`use_temperatures`, with the given lag grid)
/// and/or strains (`use_strains`, unlagged).
#[allow(clippy::too_many_arguments)]
pub fn fit_context(
    rec: &Recording,
    signal: &str,
    use_temperatures: bool,
    use_strains: bool,
    lags_s: &[f64],
    max_terms: usize,
    criterion: Criterion,
    heldout_runs: &[u32],
) -> Result<ContextFit, FitError> {
    let y = rec
        .col(signal)
        .ok_or_else(|| FitError::NoColumn(signal.to_string()))?;
    let t = rec
        .col("t_s")
        .ok_or_else(|| FitError::NoColumn("t_s".into()))?;
    let n = y.len();
    let (test, rule): (Vec<bool>, String) = match (rec.col("run"), heldout_runs.is_empty()) {
        (Some(run), false) => (
            run.iter()
                .map(|r| heldout_runs.iter().any(|h| f64::from(*h) == *r))
                .collect(),
            format!("runs {heldout_runs:?}"),
        ),
        _ => (
            (0..n).map(|i| i >= n * 7 / 10).collect(),
            "last 30 % of samples".to_string(),
        ),
    };
    if !test.iter().any(|b| *b) {
        return Err(FitError::NoHeldout);
    }
    let mut full: Vec<Candidate> = Vec::new();
    if use_temperatures {
        for name in rec.temperature_channels() {
            let values = rec.col(&name).expect("listed by the recording");
            for &tau in lags_s {
                full.push(Candidate {
                    signal: name.clone(),
                    tau_s: tau,
                    values: first_order_lag(t, values, tau),
                });
            }
        }
    }
    if use_strains {
        for name in rec.strain_channels() {
            full.push(Candidate {
                values: rec.col(&name).expect("listed by the recording").to_vec(),
                signal: name,
                tau_s: 0.0,
            });
        }
    }
    // Samples of the training (`heldout = false`) or held-out (`true`) part.
    let pick = |v: &[f64], heldout: bool| -> Vec<f64> {
        v.iter()
            .zip(&test)
            .filter(|(_, t)| **t == heldout)
            .map(|(x, _)| *x)
            .collect()
    };
    let train_c: Vec<Candidate> = full
        .iter()
        .map(|c| Candidate {
            values: pick(&c.values, false),
            ..c.clone()
        })
        .collect();
    let selection = select(&pick(y, false), &train_c, max_terms, criterion)?;
    let model = selection.model.clone();
    let predicted = model
        .predict(t, &|name: &str| rec.col(name).map(<[f64]>::to_vec))
        .ok_or_else(|| FitError::NoColumn("a selected signal".into()))?;
    let heldout = efficiency(&pick(y, true), &pick(&predicted, true)).ok_or(FitError::NoHeldout)?;
    Ok(ContextFit {
        signal: signal.to_string(),
        selection,
        model,
        heldout_rule: rule,
        heldout,
    })
}
