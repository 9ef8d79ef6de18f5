//! Linear least squares on nalgebra (SVD with column scaling), shared by the fitting tools and the
//! circular-test diagnosis.

use nalgebra::{DMatrix, DVector};

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LsqFit {
    pub beta: DVector<f64>,
    /// Residual sum of squares.
    pub sse: f64,
    /// Numerical rank of the (scaled) design matrix.
    pub rank: usize,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LsqError {
    #[error(
        "design matrix has {rows} rows and {cols} columns: need at least as many rows as columns"
    )]
    Underdetermined { rows: usize, cols: usize },
    #[error("non-finite value in the design matrix or data")]
    NonFinite,
    #[error("SVD failed: {0}")]
    Svd(&'static str),
}

/// Solves min ‖Xβ − y‖². Columns are scaled to unit norm first so that regressors in different
/// units (mm, mm², °C) do not make the rank decision depend on units.
pub(crate) fn lstsq(x: &DMatrix<f64>, y: &DVector<f64>) -> Result<LsqFit, LsqError> {
    let (n, p) = x.shape();
    if n < p {
        return Err(LsqError::Underdetermined { rows: n, cols: p });
    }
    if x.iter().chain(y.iter()).any(|v| !v.is_finite()) {
        return Err(LsqError::NonFinite);
    }
    let scales: Vec<f64> = (0..p).map(|j| x.column(j).norm().max(1e-300)).collect();
    let mut xs = x.clone();
    for (j, s) in scales.iter().enumerate() {
        xs.column_mut(j).unscale_mut(*s);
    }
    let svd = xs.svd(true, true);
    let smax = svd.singular_values.max();
    let eps = smax * 1e-10 * n.max(p) as f64;
    let rank = svd.singular_values.iter().filter(|s| **s > eps).count();
    let mut beta = svd.solve(y, eps).map_err(LsqError::Svd)?;
    for (j, s) in scales.iter().enumerate() {
        beta[j] /= s;
    }
    let r = y - x * &beta;
    Ok(LsqFit {
        sse: r.norm_squared(),
        beta,
        rank,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_exact_coefficients_with_mixed_scales() {
        let xs: Vec<f64> = (0..20).map(|i| f64::from(i) * 50.0).collect();
        let x = DMatrix::from_fn(20, 3, |i, j| [1.0, xs[i], xs[i] * xs[i]][j]);
        let y = DVector::from_fn(20, |i, _| 3.0 - 0.01 * xs[i] + 2e-6 * xs[i] * xs[i]);
        let f = lstsq(&x, &y).unwrap();
        assert!(
            (f.beta[0] - 3.0).abs() < 1e-9
                && (f.beta[1] + 0.01).abs() < 1e-12
                && (f.beta[2] - 2e-6).abs() < 1e-15
        );
        assert_eq!(f.rank, 3);
        assert!(lstsq(&DMatrix::zeros(2, 3), &DVector::zeros(2)).is_err());
    }
}
