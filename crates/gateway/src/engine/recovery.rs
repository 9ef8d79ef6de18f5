//! Sensor-failure recovery by inter-sensor correlation (Ni 1996 §5, Fig. 10: "T27 = g(T26, T29)"; with
//! T27 forced to zero the recovered prediction tracks the normal one).
//!
//! At commissioning, fit `T_target ≈ c0 + Σ c_j·T_neighbour_j` by least squares (SVD) on a log of
//! healthy readings. At run time, while the target sensor is faulty and all its neighbours are healthy,
//! the estimate replaces it (flagged `substituted` in the status). Units: °C (any channel unit works).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeighbourEstimate {
    pub target: String,
    pub neighbours: Vec<String>,
    /// `[c0, c1, …]`: intercept then one coefficient per neighbour.
    pub coefficients: Vec<f64>,
    /// RMS residual of the fit on the commissioning data, target units.
    pub fit_rms: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RecoveryError {
    #[error("recovery fit for {target}: need at least {need} rows, got {got}")]
    TooFewRows {
        target: String,
        need: usize,
        got: usize,
    },
    #[error(
        "recovery fit for {target}: row {row} has {got} values, expected {expected} (target + neighbours)"
    )]
    RowWidth {
        target: String,
        row: usize,
        got: usize,
        expected: usize,
    },
    #[error("recovery fit for {target}: row {row} holds a non-finite value")]
    NotFinite { target: String, row: usize },
    #[error(
        "recovery fit for {target}: neighbours are collinear or constant (rank {rank} < {need}); pick other neighbours or log a wider thermal range"
    )]
    RankDeficient {
        target: String,
        rank: usize,
        need: usize,
    },
    #[error("recovery estimate for {target}: expected {expected} neighbour values, got {got}")]
    Arity {
        target: String,
        expected: usize,
        got: usize,
    },
}

impl NeighbourEstimate {
    /// Fit from rows `[target, n1, n2, …]` of simultaneous healthy readings.
    pub fn fit(
        target: &str,
        neighbours: &[&str],
        rows: &[Vec<f64>],
    ) -> Result<Self, RecoveryError> {
        let k = neighbours.len() + 1;
        let need = k + 1;
        if rows.len() < need {
            return Err(RecoveryError::TooFewRows {
                target: target.into(),
                need,
                got: rows.len(),
            });
        }
        let mut a = DMatrix::<f64>::zeros(rows.len(), k);
        let mut b = DVector::<f64>::zeros(rows.len());
        for (i, r) in rows.iter().enumerate() {
            if r.len() != k {
                return Err(RecoveryError::RowWidth {
                    target: target.into(),
                    row: i,
                    got: r.len(),
                    expected: k,
                });
            }
            if r.iter().any(|v| !v.is_finite()) {
                return Err(RecoveryError::NotFinite {
                    target: target.into(),
                    row: i,
                });
            }
            b[i] = r[0];
            a[(i, 0)] = 1.0;
            for j in 1..k {
                a[(i, j)] = r[j];
            }
        }
        let svd = a.clone().svd(true, true);
        let smax = svd.singular_values.max();
        let rank = svd.rank(smax * 1e-9);
        if rank < k {
            return Err(RecoveryError::RankDeficient {
                target: target.into(),
                rank,
                need: k,
            });
        }
        let c = svd
            .solve(&b, smax * 1e-12)
            .map_err(|_| RecoveryError::RankDeficient {
                target: target.into(),
                rank,
                need: k,
            })?;
        let resid = &a * &c - &b;
        let fit_rms = (resid.norm_squared() / rows.len() as f64).sqrt();
        Ok(Self {
            target: target.into(),
            neighbours: neighbours.iter().map(|s| s.to_string()).collect(),
            coefficients: c.iter().copied().collect(),
            fit_rms,
        })
    }

    /// Estimate the target from the neighbours' current values (same order as `neighbours`).
    pub fn estimate(&self, neighbour_values: &[f64]) -> Result<f64, RecoveryError> {
        if neighbour_values.len() + 1 != self.coefficients.len() {
            return Err(RecoveryError::Arity {
                target: self.target.clone(),
                expected: self.coefficients.len().saturating_sub(1),
                got: neighbour_values.len(),
            });
        }
        Ok(self.coefficients[0]
            + self.coefficients[1..]
                .iter()
                .zip(neighbour_values)
                .map(|(c, v)| c * v)
                .sum::<f64>())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn recovers_failed_sensor_from_correlated_neighbours() {
        // Synthetic warm-up: two neighbours heat with different time constants; the target is a
        // weighted mix plus 0.02 °C noise (Ni 1996 Fig. 10 shows the shape, not the numbers).
        let mut rng = ChaCha8Rng::seed_from_u64(27);
        let rows: Vec<Vec<f64>> = (0..400)
            .map(|k| {
                let t = f64::from(k) * 30.0;
                let t26 = 20.0 + 8.0 * (1.0 - (-t / 3600.0).exp());
                let t29 = 20.0 + 5.0 * (1.0 - (-t / 1200.0).exp());
                let t27 = 1.0 + 0.6 * t26 + 0.35 * t29 + rng.random_range(-0.02..0.02);
                vec![t27, t26, t29]
            })
            .collect();
        let est = NeighbourEstimate::fit("T27_C", &["T26_C", "T29_C"], &rows).unwrap();
        assert!(est.fit_rms < 0.02, "fit rms {}", est.fit_rms);
        let truth = 1.0 + 0.6 * 27.0 + 0.35 * 24.5;
        assert!((est.estimate(&[27.0, 24.5]).unwrap() - truth).abs() < 0.05);
        assert!(est.estimate(&[27.0]).is_err());
    }

    #[test]
    fn constant_neighbour_is_rejected_with_reason() {
        let rows: Vec<Vec<f64>> = (0..10).map(|k| vec![f64::from(k), 20.0]).collect();
        assert!(matches!(
            NeighbourEstimate::fit("T1_C", &["T2_C"], &rows),
            Err(RecoveryError::RankDeficient { .. })
        ));
    }
}
