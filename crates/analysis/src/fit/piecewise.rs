//! C¹ piecewise quadratics in truncated-power form with stepwise knot selection (Spaan Ch3):
//! p(x) = β0 + β1·x + β2·x² + Σ_i γ_i·(x − t_i)₊². Each knot adds one parameter and keeps the
//! function and its slope continuous. Knots are chosen from candidates by forward selection
//! (the knot that lowers the residual sum of squares most, kept if its partial F-test is
//! significant at level `alpha`; Spaan used 99.99 %, i.e. alpha = 1e-4), followed by backward
//! elimination of knots that are no longer significant.
//!
//! x is centred on the data mean before fitting so the x² column is well conditioned.
//!
//! With a lead L ([`fit_stepwise_lead`]) a ball-screw wave s·sin(2πx/L) + c·cos(2πx/L) is fitted
//! beside it (two more columns in every candidate model, `fit::lead`): readings at steps ≤ L/4
//! separate it from the smooth part.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::lead::LeadWave;
use super::lsq::{LsqError, lstsq};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PiecewiseQuadratic {
    /// Centre subtracted from x before evaluating the basis, mm.
    pub centre_mm: f64,
    /// β0, β1, β2 (µm, µm/mm, µm/mm²).
    pub poly: [f64; 3],
    /// Knots t_i (mm, absolute) and γ_i (µm/mm²).
    pub knots_mm: Vec<f64>,
    pub gammas: Vec<f64>,
    /// The lead wave fitted beside the smooth part, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lead: Option<LeadWave>,
}

impl PiecewiseQuadratic {
    pub fn eval(&self, x_mm: f64) -> f64 {
        let u = x_mm - self.centre_mm;
        let mut y = self.poly[0] + self.poly[1] * u + self.poly[2] * u * u;
        for (t, g) in self.knots_mm.iter().zip(&self.gammas) {
            let d = (x_mm - t).max(0.0);
            y += g * d * d;
        }
        y + self.lead.as_ref().map_or(0.0, |w| w.eval(x_mm))
    }

    /// Slope dp/dx (continuous by construction).
    pub fn slope(&self, x_mm: f64) -> f64 {
        let u = x_mm - self.centre_mm;
        let mut s = self.poly[1] + 2.0 * self.poly[2] * u;
        for (t, g) in self.knots_mm.iter().zip(&self.gammas) {
            s += 2.0 * g * (x_mm - t).max(0.0);
        }
        if let Some(w) = &self.lead {
            let k = std::f64::consts::TAU / w.lead_mm;
            let [sn, cs] = super::lead::columns(w.lead_mm, x_mm);
            s += k * (w.sin_um * cs - w.cos_um * sn);
        }
        s
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PiecewiseError {
    #[error("need at least 4 points, found {0}")]
    TooFew(usize),
    #[error("x and y have different lengths")]
    Lengths,
    #[error(transparent)]
    Lsq(#[from] LsqError),
}

/// Columns 1, u, u², the knots', then (with a lead) sin and cos.
fn design(xs: &[f64], centre: f64, knots: &[f64], lead: Option<f64>) -> DMatrix<f64> {
    let nk = 3 + knots.len();
    let p = nk + if lead.is_some() { 2 } else { 0 };
    DMatrix::from_fn(xs.len(), p, |i, j| {
        let u = xs[i] - centre;
        match j {
            0 => 1.0,
            1 => u,
            2 => u * u,
            k if k < nk => (xs[i] - knots[k - 3]).max(0.0).powi(2),
            k => lead.map_or(0.0, |l| super::lead::columns(l, xs[i])[k - nk]),
        }
    })
}

fn sse(
    xs: &[f64],
    y: &DVector<f64>,
    centre: f64,
    knots: &[f64],
    lead: Option<f64>,
) -> Result<(f64, DVector<f64>), LsqError> {
    let f = lstsq(&design(xs, centre, knots, lead), y)?;
    Ok((f.sse, f.beta))
}

/// p-value of adding `q` parameters that lower SSE from `sse0` to `sse1` with `df1` residual dof.
fn partial_f_p(sse0: f64, sse1: f64, q: f64, df1: f64) -> f64 {
    if df1 <= 0.0 {
        return 1.0;
    }
    if sse1 <= 1e-300 {
        return 0.0;
    }
    let f = ((sse0 - sse1) / q) / (sse1 / df1);
    match FisherSnedecor::new(q, df1) {
        Ok(d) => 1.0 - d.cdf(f.max(0.0)),
        Err(_) => 1.0,
    }
}

/// Fits with stepwise knot selection among `candidates` (mm; those outside the open data range are
/// ignored).
pub fn fit_stepwise(
    xs: &[f64],
    ys: &[f64],
    candidates: &[f64],
    alpha: f64,
) -> Result<PiecewiseQuadratic, PiecewiseError> {
    fit_stepwise_lead(xs, ys, candidates, alpha, None)
}

/// [`fit_stepwise`] with a lead wave at `lead_mm` in every candidate model (None: none).
pub(super) fn fit_stepwise_lead(
    xs: &[f64],
    ys: &[f64],
    candidates: &[f64],
    alpha: f64,
    lead_mm: Option<f64>,
) -> Result<PiecewiseQuadratic, PiecewiseError> {
    if xs.len() != ys.len() {
        return Err(PiecewiseError::Lengths);
    }
    if xs.len() < 4 {
        return Err(PiecewiseError::TooFew(xs.len()));
    }
    let n = xs.len() as f64;
    let centre = xs.iter().sum::<f64>() / n;
    let (lo, hi) = xs
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let cands: Vec<f64> = candidates
        .iter()
        .cloned()
        .filter(|t| *t > lo && *t < hi)
        .collect();
    let y = DVector::from_column_slice(ys);
    let mut knots: Vec<f64> = Vec::new();
    let extra = if lead_mm.is_some() { 2.0 } else { 0.0 };
    let (mut cur, _) = sse(xs, &y, centre, &knots, lead_mm)?;
    loop {
        // Forward step.
        let mut best: Option<(f64, f64)> = None;
        for &t in cands.iter().filter(|t| !knots.contains(t)) {
            let mut k = knots.clone();
            k.push(t);
            let p = 3.0 + extra + k.len() as f64;
            if n - p < 1.0 {
                continue;
            }
            let (s, _) = sse(xs, &y, centre, &k, lead_mm)?;
            if best.is_none_or(|b| s < b.1) {
                best = Some((t, s));
            }
        }
        let Some((t, s)) = best else { break };
        let df1 = n - (4.0 + extra + knots.len() as f64);
        if partial_f_p(cur, s, 1.0, df1) >= alpha {
            break;
        }
        knots.push(t);
        cur = s;
        // Backward elimination of knots no longer significant.
        loop {
            let mut worst: Option<(usize, f64, f64)> = None;
            for i in 0..knots.len() {
                let mut k = knots.clone();
                k.remove(i);
                let (s_without, _) = sse(xs, &y, centre, &k, lead_mm)?;
                let p = partial_f_p(s_without, cur, 1.0, n - (3.0 + extra + knots.len() as f64));
                if p >= alpha && worst.is_none_or(|w| p > w.1) {
                    worst = Some((i, p, s_without));
                }
            }
            match worst {
                Some((i, _, s_without)) => {
                    knots.remove(i);
                    cur = s_without;
                }
                None => break,
            }
        }
    }
    knots.sort_by(f64::total_cmp);
    let (s, beta) = sse(xs, &y, centre, &knots, lead_mm)?;
    let nk = 3 + knots.len();
    let lead = lead_mm.map(|l| {
        // The pair's covariance σ²·(XᵀX)⁻¹ (columns as fitted; the design is full rank at steps
        // ≤ L/4, else the wave is reported with an infinite uncertainty).
        let x = design(xs, centre, &knots, lead_mm);
        let sigma2 = s / (n - nk as f64 - 2.0).max(1.0);
        let cov = (x.transpose() * &x)
            .try_inverse()
            .map_or([[f64::INFINITY; 2]; 2], |m| {
                let v = |a: usize, b: usize| sigma2 * m[(nk + a, nk + b)];
                [[v(0, 0), v(0, 1)], [v(1, 0), v(1, 1)]]
            });
        LeadWave::new("fit", l, beta[nk], beta[nk + 1], cov)
    });
    Ok(PiecewiseQuadratic {
        centre_mm: centre,
        poly: [beta[0], beta[1], beta[2]],
        gammas: (0..knots.len()).map(|i| beta[3 + i]).collect(),
        knots_mm: knots,
        lead,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_knot_of_a_true_piecewise_quadratic() {
        // True curve: 2 + 0.01·x, bending at x = 300 with γ = 1e-4 µm/mm².
        let xs: Vec<f64> = (0..=50).map(|i| 10.0 * f64::from(i)).collect();
        let ys: Vec<f64> = xs
            .iter()
            .map(|x| {
                2.0 + 0.01 * x + 1e-4 * (x - 300.0f64).max(0.0).powi(2) + 0.02 * (x * 0.37).sin()
            })
            .collect();
        let cands: Vec<f64> = (1..10).map(|i| 50.0 * f64::from(i)).collect();
        let f = fit_stepwise(&xs, &ys, &cands, 1e-4).unwrap();
        assert_eq!(f.knots_mm, vec![300.0]);
        assert!((f.gammas[0] - 1e-4).abs() < 1e-5);
        for x in &xs {
            assert!(
                (f.eval(*x) - (2.0 + 0.01 * x + 1e-4 * (x - 300.0f64).max(0.0).powi(2))).abs()
                    < 0.05
            );
        }
        // C¹: slope continuous across the knot.
        assert!((f.slope(300.0 - 1e-9) - f.slope(300.0 + 1e-9)).abs() < 1e-9);
    }

    #[test]
    fn pure_quadratic_needs_no_knot() {
        let xs: Vec<f64> = (0..30).map(f64::from).collect();
        let ys: Vec<f64> = xs
            .iter()
            .map(|x| 1.0 - 0.2 * x + 0.003 * x * x + 0.01 * (x * 1.3).sin())
            .collect();
        let f = fit_stepwise(&xs, &ys, &[5.0, 10.0, 15.0, 20.0, 25.0], 1e-4).unwrap();
        assert!(f.knots_mm.is_empty(), "{:?}", f.knots_mm);
    }
}
