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
use super::lead::LeadWave;
use super::piecewise::{PiecewiseError, PiecewiseQuadratic, fit_stepwise_lead};
use super::regression::{
    Candidate, Criterion, LinearModel, RegressionError, Selection, first_order_lag, select,
};
use crate::iso230_2::Reading;
use crate::table::Direction;
use retrocomp_model::recording::Recording;

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisFit {
    pub forward: PiecewiseQuadratic,
    pub reverse: PiecewiseQuadratic,
    pub heldout_run: Option<u32>,
    /// Efficiency δ and max residual on the held-out run (None without one).
    pub heldout: Option<Efficiency>,
    pub fit_rms_um: f64,
    /// With a lead: the wave of both directions together (the mean of their sin and cos
    /// coefficients, independent errors).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lead: Option<LeadWave>,
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
    fit_axis_lead(readings, knot_step_mm, alpha, heldout_run, None)
}

/// [`fit_axis`] with a ball-screw lead wave at `lead_mm` beside each direction's smooth part.
pub fn fit_axis_lead(
    readings: &[Reading],
    knot_step_mm: f64,
    alpha: f64,
    heldout_run: Option<u32>,
    lead_mm: Option<f64>,
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
        fit_stepwise_lead(&xs, &ys, &cands, alpha, lead_mm)
    };
    let mut forward = fit_dir(Direction::Forward)?;
    let mut reverse = fit_dir(Direction::Reverse)?;
    for (p, name) in [(&mut forward, "forward"), (&mut reverse, "reverse")] {
        if let Some(w) = &mut p.lead {
            w.name = name.into();
        }
    }
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
    let lead = match (&forward.lead, &reverse.lead) {
        (Some(f), Some(r)) => {
            let c = |i: usize, j: usize| 0.25 * (f.cov_um2[i][j] + r.cov_um2[i][j]);
            Some(LeadWave::new(
                "both directions",
                f.lead_mm,
                0.5 * (f.sin_um + r.sin_um),
                0.5 * (f.cos_um + r.cos_um),
                [[c(0, 0), c(0, 1)], [c(1, 0), c(1, 1)]],
            ))
        }
        _ => None,
    };
    Ok(AxisFit {
        forward,
        reverse,
        heldout_run,
        heldout,
        fit_rms_um,
        lead,
    })
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ContextFit {
    pub signal: String,
    pub selection: Selection,
    pub model: LinearModel,
    /// How the held-out data was chosen.
    pub heldout_rule: String,
    /// δ of the fit on the training rows, scored on the held-out rows (also with `refit_all`: it
    /// then says how well the procedure predicted, while `model` is chosen again on every row).
    pub heldout: Efficiency,
    /// Rows `model` was chosen and fitted on: "training" or "all".
    pub model_rows: String,
    /// Mean of each of the model's source signals over those rows (a sensor's reference).
    pub means: Vec<(String, f64)>,
}

/// A context signal that heats the machine with no sensor on it (issue 12 point 2): `column`
/// raised to `exponent` (rpm² for bearing friction) enters only through first-order lags.
///
/// Its identity in a fit's terms and JSON is the signal name `col^p` ([`Driver::signal`]);
/// [`Driver::of_signal`] is the one reader of that name (values, model sensor, CLI).
#[derive(Debug, Clone, PartialEq)]
pub struct Driver {
    pub column: String,
    pub exponent: f64,
}

/// A `--drivers` entry that is not `COLUMN` or `COLUMN^POWER` with a power in (0, 4].
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("driver `{given}`: {why}")]
pub struct DriverError {
    pub given: String,
    pub why: String,
}

impl Driver {
    /// The largest power accepted: rpm² is the physics (bearing friction ∝ n²); above 4 the
    /// regressor is dominated by the top speed alone.
    pub const MAX_EXPONENT: f64 = 4.0;

    /// `rpm^2` → rpm to the power 2; `load` → power 1.
    pub fn parse(given: &str) -> Result<Driver, DriverError> {
        let bad = |why: String| DriverError {
            given: given.to_string(),
            why,
        };
        let (column, exponent) = match given.split_once('^') {
            Some((c, p)) => (
                c,
                p.parse::<f64>()
                    .ok()
                    .filter(|p| *p > 0.0 && *p <= Self::MAX_EXPONENT)
                    .ok_or_else(|| {
                        bad(format!(
                            "the power must be a number in (0, {}]",
                            Self::MAX_EXPONENT
                        ))
                    })?,
            ),
            None => (given, 1.0),
        };
        if column.is_empty() {
            return Err(bad("no column name".into()));
        }
        Ok(Driver {
            column: column.to_string(),
            exponent,
        })
    }

    /// The driver a term's signal names, if it names one (`rpm^2`); `None` for a recording
    /// column (`T_4_C`, `strain_1_um_per_m`).
    pub fn of_signal(signal: &str) -> Option<Driver> {
        signal
            .contains('^')
            .then(|| Driver::parse(signal).ok())
            .flatten()
    }

    /// "rpm^2": the candidate's signal name, read back by [`Driver::of_signal`].
    pub fn signal(&self) -> String {
        format!("{}^{}", self.column, self.exponent)
    }

    /// |column|^exponent on every row, `None` when the recording lacks the column.
    pub fn values(&self, rec: &Recording) -> Option<Vec<f64>> {
        let p = self.exponent;
        Some(
            rec.col(&self.column)?
                .iter()
                .map(|x| x.abs().powf(p))
                .collect(),
        )
    }
}

/// A regressor's raw values: a recording column, or for a driver signal `col^p`, |col|^p.
pub fn source_values(rec: &Recording, signal: &str) -> Option<Vec<f64>> {
    match Driver::of_signal(signal) {
        Some(d) => d.values(rec),
        None => rec.col(signal).map(<[f64]>::to_vec),
    }
}

/// What [`fit_context_with`] fits on and how.
#[derive(Debug, Clone)]
pub struct ContextOptions<'a> {
    pub use_temperatures: bool,
    pub use_strains: bool,
    pub lags_s: &'a [f64],
    pub max_terms: usize,
    pub criterion: Criterion,
    pub heldout_runs: &'a [u32],
    /// Lagged drivers (each lag of `lags_s` above 0 s).
    pub drivers: &'a [Driver],
    /// Subtracted from the signal before fitting: a base model's prediction (µm), so the fit
    /// adds to the model it extends instead of counting its part twice.
    pub base_um: Option<&'a [f64]>,
    /// After scoring the training fit on the held-out rows, choose and fit again on every row.
    pub refit_all: bool,
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
    fit_context_with(
        rec,
        signal,
        &ContextOptions {
            use_temperatures,
            use_strains,
            lags_s,
            max_terms,
            criterion,
            heldout_runs,
            drivers: &[],
            base_um: None,
            refit_all: false,
        },
    )
}

/// Every candidate regressor of the options over the whole recording.
fn candidates(
    rec: &Recording,
    o: &ContextOptions<'_>,
    t: &[f64],
) -> Result<Vec<Candidate>, FitError> {
    let mut full: Vec<Candidate> = Vec::new();
    if o.use_temperatures {
        for name in rec.temperature_channels() {
            let values = rec.col(&name).expect("listed by the recording");
            for &tau in o.lags_s {
                full.push(Candidate {
                    signal: name.clone(),
                    tau_s: tau,
                    values: first_order_lag(t, values, tau),
                });
            }
        }
    }
    for d in o.drivers {
        let signal = d.signal();
        let values = d.values(rec).ok_or(FitError::NoColumn(d.column.clone()))?;
        for &tau in o.lags_s.iter().filter(|tau| **tau > 0.0) {
            full.push(Candidate {
                signal: signal.clone(),
                tau_s: tau,
                values: first_order_lag(t, &values, tau),
            });
        }
    }
    if o.use_strains {
        for name in rec.strain_channels() {
            full.push(Candidate {
                values: rec.col(&name).expect("listed by the recording").to_vec(),
                signal: name,
                tau_s: 0.0,
            });
        }
    }
    Ok(full)
}

/// [`fit_context`] with drivers, a base model's prediction and a final fit on every row.
#[allow(
    clippy::float_cmp,
    reason = "run numbers are small integers, exact in f64 (parsed from the recording)"
)]
pub fn fit_context_with(
    rec: &Recording,
    signal: &str,
    o: &ContextOptions<'_>,
) -> Result<ContextFit, FitError> {
    let y = rec
        .col(signal)
        .ok_or_else(|| FitError::NoColumn(signal.to_string()))?;
    let y: Vec<f64> = match o.base_um {
        Some(b) => y.iter().zip(b).map(|(y, b)| y - b).collect(),
        None => y.to_vec(),
    };
    let t = rec
        .col("t_s")
        .ok_or_else(|| FitError::NoColumn("t_s".into()))?;
    let n = y.len();
    let (test, rule): (Vec<bool>, String) = match (rec.col("run"), o.heldout_runs.is_empty()) {
        (Some(run), false) => (
            run.iter()
                .map(|r| o.heldout_runs.iter().any(|h| f64::from(*h) == *r))
                .collect(),
            format!("runs {:?}", o.heldout_runs),
        ),
        _ => (
            (0..n).map(|i| i >= n * 7 / 10).collect(),
            "last 30 % of samples".to_string(),
        ),
    };
    if !test.iter().any(|b| *b) {
        return Err(FitError::NoHeldout);
    }
    let full = candidates(rec, o, t)?;
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
    let selection = select(&pick(&y, false), &train_c, o.max_terms, o.criterion)?;
    let source = |name: &str| source_values(rec, name);
    let predicted = selection
        .model
        .predict(t, &source)
        .ok_or_else(|| FitError::NoColumn("a selected signal".into()))?;
    let heldout =
        efficiency(&pick(&y, true), &pick(&predicted, true)).ok_or(FitError::NoHeldout)?;
    let (selection, rows) = if o.refit_all {
        (select(&y, &full, o.max_terms, o.criterion)?, vec![true; n])
    } else {
        (selection, test.iter().map(|h| !h).collect())
    };
    let model = selection.model.clone();
    let means = model
        .terms
        .iter()
        .map(|term| {
            let v = source(&term.signal).expect("a selected signal is in the recording");
            let (s, k) = v
                .iter()
                .zip(&rows)
                .filter(|(_, r)| **r)
                .fold((0.0, 0usize), |(s, k), (x, _)| (s + x, k + 1));
            (term.signal.clone(), s / k.max(1) as f64)
        })
        .collect();
    Ok(ContextFit {
        signal: signal.to_string(),
        selection,
        model,
        heldout_rule: rule,
        heldout,
        model_rows: if o.refit_all { "all" } else { "training" }.to_string(),
        means,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_driver_is_read_back_from_its_signal_name_and_columns_are_not_drivers() {
        let rpm2 = Driver::parse("rpm^2").unwrap();
        assert_eq!((rpm2.column.as_str(), rpm2.exponent), ("rpm", 2.0));
        assert_eq!(Driver::of_signal(&rpm2.signal()), Some(rpm2));
        let load = Driver::parse("spindle_load").unwrap();
        assert_eq!(load.signal(), "spindle_load^1");
        assert_eq!(Driver::of_signal(&load.signal()), Some(load));
        assert_eq!(Driver::of_signal("T_4_C"), None);
        assert_eq!(Driver::of_signal("strain_1_um_per_m"), None);
        assert_eq!(
            Driver::parse("rpm^9").unwrap_err().to_string(),
            "driver `rpm^9`: the power must be a number in (0, 4]"
        );
        for bad in ["rpm^9", "rpm^0", "rpm^x", "^2"] {
            assert!(Driver::parse(bad).is_err(), "{bad}");
        }
    }
}
