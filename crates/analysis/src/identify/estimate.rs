//! Joint least squares ΔP = Xβ + γ with stepwise (backward) knot elimination, duplicate-probing
//! outlier rejection, per-parameter t, per-component partial F (ANOVA), and the null space of X
//! (what the artefacts cannot see).
//!
//! Solved through the normal equations with unit-norm column scaling and a symmetric eigen
//! decomposition: XᵀX is p×p (p ≈ 150) however many probings there are, so six 10×10 plates cost
//! one pass over the rows per fit. Eigenvalues below `rank_tol`·λmax span the null space; the
//! solution is the minimum-norm one there (unseen combinations are set to 0, not guessed).

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use statrs::distribution::{ContinuousCDF, FisherSnedecor, StudentsT};

use super::design::{CompBasis, Geometry, Obs, fill_row};

/// One solve.
#[derive(Debug, Clone)]
pub struct Solve {
    /// β (components, then 3 squareness) followed by γ.
    pub coef: Vec<f64>,
    /// Standard errors (0 for unseen directions).
    pub se: Vec<f64>,
    pub residual_um: Vec<f64>,
    pub sigma_um: f64,
    pub rank: usize,
    pub dof: usize,
    /// Pseudo-inverse of XᵀX in original units (covariance / σ²).
    pub xtx_pinv: DMatrix<f64>,
    /// Null-space vectors of X in original units (parameter changes the data cannot see).
    pub null: Vec<DVector<f64>>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EstimateError {
    #[error("{rows} observations for {cols} parameters: add artefacts")]
    TooFew { rows: usize, cols: usize },
    #[error("non-finite value in the observations")]
    NonFinite,
}

/// Number of β columns (components + 3 squareness).
pub(super) fn beta_len(bases: &[CompBasis]) -> usize {
    bases.iter().map(CompBasis::n_terms).sum::<usize>() + 3
}

/// Solves for one basis set and observation set; `n_setup` γ columns.
/// `rank_tol`: relative eigenvalue of the scaled XᵀX below which a direction counts as unseen.
pub(super) fn solve(
    geo: &Geometry,
    bases: &[CompBasis],
    obs: &[Obs],
    n_setup: usize,
    rank_tol: f64,
) -> Result<Solve, EstimateError> {
    let p = beta_len(bases) + n_setup;
    let n = obs.len();
    if n <= p {
        return Err(EstimateError::TooFew { rows: n, cols: p });
    }
    let mut xtx = DMatrix::<f64>::zeros(p, p);
    let mut xty = DVector::<f64>::zeros(p);
    let mut row = vec![0.0; p];
    let mut rows = Vec::with_capacity(n * p);
    for o in obs {
        fill_row(geo, bases, o, &mut row);
        if row.iter().any(|v| !v.is_finite()) || !o.y_um.is_finite() {
            return Err(EstimateError::NonFinite);
        }
        // Rank-1 update on the non-zero entries only (a row touches ~40 of ~150 columns).
        let nz: Vec<usize> = (0..p).filter(|&j| row[j] != 0.0).collect();
        for &i in &nz {
            xty[i] += row[i] * o.y_um;
            for &j in &nz {
                xtx[(i, j)] += row[i] * row[j];
            }
        }
        rows.extend_from_slice(&row);
    }
    let scale: Vec<f64> = (0..p)
        .map(|j| {
            let d = xtx[(j, j)].sqrt();
            if d > 0.0 { d } else { 1.0 }
        })
        .collect();
    let a = DMatrix::from_fn(p, p, |i, j| xtx[(i, j)] / (scale[i] * scale[j]));
    let eig = SymmetricEigen::new(a);
    let lmax = eig.eigenvalues.max().max(1e-300);
    let mut pinv = DMatrix::<f64>::zeros(p, p);
    let mut null = Vec::new();
    let mut rank = 0;
    for k in 0..p {
        let l = eig.eigenvalues[k];
        let v = eig.eigenvectors.column(k);
        if l > rank_tol * lmax {
            rank += 1;
            pinv += (v * v.transpose()) / l;
        } else {
            null.push(DVector::from_fn(p, |j, _| v[j] / scale[j]));
        }
    }
    // Back to original units: (XᵀX)⁺ = S⁻¹ A⁺ S⁻¹.
    for (i, si) in scale.iter().enumerate() {
        for (j, sj) in scale.iter().enumerate() {
            pinv[(i, j)] /= si * sj;
        }
    }
    let mut coef = &pinv * &xty;
    // A column the data never touches (e.g. ECY with the tool along Z) gets exactly 0: rounding in
    // the eigenvectors would otherwise leave ~1e-17 there with a meaningless t.
    let untouched: Vec<usize> = (0..p).filter(|&j| xtx[(j, j)] == 0.0).collect();
    for &j in &untouched {
        coef[j] = 0.0;
    }
    let x = DMatrix::from_row_slice(n, p, &rows);
    let fitted = &x * &coef;
    let residual_um: Vec<f64> = obs
        .iter()
        .zip(fitted.iter())
        .map(|(o, f)| o.y_um - f)
        .collect();
    let dof = n.saturating_sub(rank).max(1);
    let sse: f64 = residual_um.iter().map(|r| r * r).sum();
    let sigma_um = (sse / dof as f64).sqrt();
    let se = (0..p)
        .map(|j| {
            if untouched.contains(&j) {
                0.0
            } else {
                sigma_um * pinv[(j, j)].max(0.0).sqrt()
            }
        })
        .collect();
    Ok(Solve {
        coef: coef.iter().copied().collect(),
        se,
        residual_um,
        sigma_um,
        rank,
        dof,
        xtx_pinv: pinv,
        null,
    })
}

/// Duplicate probings (same artefact, same hole, different `repeat`): where two probings of one
/// hole disagree by more than `limit_um` in a direction, the one farther from the fit is dropped
/// (Spaan: lubrication pulses of 13–15 µm). Returns the indices of the observations to drop.
pub(super) fn duplicate_outliers(obs: &[Obs], residual_um: &[f64], limit_um: f64) -> Vec<usize> {
    use std::collections::HashMap;
    let mut groups: HashMap<(usize, &str, Option<usize>), Vec<usize>> = HashMap::new();
    for (i, o) in obs.iter().enumerate() {
        groups
            .entry((o.artefact, o.key.as_str(), o.dir))
            .or_default()
            .push(i);
    }
    let mut bad_probings: Vec<(usize, &str, u32)> = Vec::new();
    for idx in groups.values().filter(|g| g.len() >= 2) {
        let lo = idx
            .iter()
            .map(|&i| obs[i].y_um)
            .fold(f64::INFINITY, f64::min);
        let hi = idx
            .iter()
            .map(|&i| obs[i].y_um)
            .fold(f64::NEG_INFINITY, f64::max);
        if hi - lo > limit_um {
            let worst = *idx
                .iter()
                .max_by(|&&a, &&b| residual_um[a].abs().total_cmp(&residual_um[b].abs()))
                .expect("non-empty group");
            let o = &obs[worst];
            bad_probings.push((o.artefact, o.key.as_str(), o.repeat));
        }
    }
    // Drop the whole probing (both in-plane directions of that repeat).
    let mut drop: Vec<usize> = obs
        .iter()
        .enumerate()
        .filter(|(_, o)| {
            bad_probings
                .iter()
                .any(|(a, k, r)| *a == o.artefact && *k == o.key && *r == o.repeat)
        })
        .map(|(i, _)| i)
        .collect();
    drop.sort_unstable();
    drop
}

/// Backward stepwise knot elimination: per round, in each component the least significant knot
/// (|t| below the two-sided `alpha` quantile) is removed; repeat until all knots are significant.
pub(super) fn eliminate_knots(
    geo: &Geometry,
    bases: &mut [CompBasis],
    obs: &[Obs],
    n_setup: usize,
    alpha: f64,
    rank_tol: f64,
) -> Result<Solve, EstimateError> {
    loop {
        let s = solve(geo, bases, obs, n_setup, rank_tol)?;
        let t_crit = StudentsT::new(0.0, 1.0, s.dof as f64)
            .map(|d| d.inverse_cdf(1.0 - alpha / 2.0))
            .unwrap_or(4.0);
        let mut col = 0;
        let mut removed = false;
        for b in bases.iter_mut() {
            let first_knot = col + b.n_terms() - b.knots_mm.len();
            let worst = (0..b.knots_mm.len())
                .map(|k| {
                    let j = first_knot + k;
                    let t = if s.se[j] > 0.0 {
                        (s.coef[j] / s.se[j]).abs()
                    } else {
                        0.0
                    };
                    (k, t)
                })
                .min_by(|a, b| a.1.total_cmp(&b.1));
            col += b.n_terms();
            if let Some((k, t)) = worst
                && t < t_crit
            {
                b.knots_mm.remove(k);
                removed = true;
            }
        }
        if !removed {
            return Ok(s);
        }
    }
}

/// Partial F of a block of β (Wald form, equal to the extra-sum-of-squares F in least squares)
/// and its p-value; None when the block is not estimable.
pub(super) fn block_f(s: &Solve, cols: std::ops::Range<usize>) -> Option<(f64, f64)> {
    let k = cols.len();
    let b = DVector::from_iterator(k, cols.clone().map(|j| s.coef[j]));
    let c = DMatrix::from_fn(k, k, |i, j| s.xtx_pinv[(cols.start + i, cols.start + j)]);
    let inv = c.try_inverse()?;
    let f = (b.transpose() * inv * &b)[(0, 0)] / (k as f64 * s.sigma_um * s.sigma_um);
    if !f.is_finite() || f < 0.0 {
        return None;
    }
    let p = FisherSnedecor::new(k as f64, s.dof as f64)
        .ok()
        .map(|d| 1.0 - d.cdf(f))?;
    Some((f, p))
}
