//! The slow-noise side of a selection step's test: the step's error model ([`NoiseModel`],
//! quasi-differences and an inverse MA(1) filter) and the unit-root statistics that choose it
//! (augmented Dickey–Fuller τ against MacKinnon's 1 % critical values). Residuals µm; τ, ρ and θ
//! are dimensionless.

use super::super::lsq::{self, RowSums};

/// The error model of one selection step's prewhitened test ([`super::prewhitened_test`]), chosen once
/// per step (not per candidate: a candidate that happens to absorb the shape of a random walk
/// leaves a residual that looks stationary, and letting each candidate pick its own noise model
/// let the best such absorber through).
#[derive(Clone, Copy, Debug)]
pub(in crate::diagnose) struct NoiseModel {
    /// Quasi-difference coefficient (1: first differences).
    pub(in crate::diagnose) rho: f64,
    /// MA(1) coefficient inverted after the difference (0: none).
    pub(in crate::diagnose) ma: f64,
}

impl NoiseModel {
    /// `null_noise`: the step's null residual; `alt_noise`: the residual the step's strongest
    /// candidate (by RSS share) leaves; both with the cell means removed, as for n_eff.
    /// `recording_rejects`: with two or more error signals, whether the recording rejects a unit
    /// root before any term ([`recording_rejects_unit_root`]), else `None`.
    ///
    /// * **Integrated** unless the recording rejects a unit root: every error channel is read by
    ///   the same instrument, so the noise type is the recording's. A channel without a large
    ///   smooth effect shows it, and a channel whose noise is a walk says so whatever the other
    ///   shows; each channel is judged by the same two-way test as the step below, so one whose
    ///   large smooth effect hides stationary noise still rejects once its strongest candidate is
    ///   taken out. Until session 14 only the smallest null-residual τ over the signals was asked:
    ///   a walk channel that looks stationary by chance (ADF's 1 % tail; 4 of 60 walk nulls at
    ///   five seeds, τ −3.6 to −4.1) then decided for the recording although the other channel
    ///   read τ −1.4 to −2.3 — the two null false alarms of `rw_decoy` (seeds 12 and 13).
    /// * **Stationary**, else, when an augmented Dickey–Fuller test ([`adf_tau`]) rejects a unit root
    ///   at 1 % on the null residual ([`ADF_CRITICAL`]), or on the strongest candidate's residual
    ///   with the residual-based critical value ([`ADF_CRITICAL_FITTED`]: a fitted smooth column
    ///   absorbs part of a walk and pulls its residual towards stationarity, so the plain value
    ///   would call too many walks stationary). The null residual alone would call stationary
    ///   noise carrying a large smooth effect integrated (measured: standard CI recall
    ///   0.964 → 0.893, `regime` 0.64 → 0.50). Model: AR(1), Cochrane–Orcutt quasi-difference
    ///   v_t − ρ·v_{t−1}, ρ the lag-1 coefficient ([`lsq::ar1_coefficient`]) of `alt_noise`.
    ///   With short-memory noise ρ is small and the test is the usual one.
    /// * **Integrated** otherwise: the local-level model, a random walk plus white measurement
    ///   noise (every reading is quantised) = ARIMA(0,1,1): first differences, then the inverse
    ///   MA(1) filter with θ from the differenced null residual ([`ma1_theta`]; a smooth effect
    ///   has almost no power in the differences). Estimating ρ instead gives 0.985–0.998 on a
    ///   walk (the quantisation and fitted columns bias it down), and a quasi-difference with ρ
    ///   just below 1 keeps ≈ 1 % of the walk's level in every row: enough for a spurious
    ///   regression (Granger–Newbold) of any smooth column over thousands of rows. Differencing
    ///   alone would leave the quantisation noise doubled at every frequency; the MA(1) filter
    ///   weights the low frequencies, where slow physics lives, by the walk's innovations only.
    pub(in crate::diagnose) fn of(
        null_noise: &[f64],
        alt_noise: &[f64],
        recording_rejects: Option<bool>,
    ) -> NoiseModel {
        let lags = adf_lags(null_noise.len());
        let stationary = recording_rejects.unwrap_or(true) && {
            // The two statistics are independent regressions over every row: side by side.
            let (null_tau, alt_tau) =
                rayon::join(|| adf_tau(null_noise, lags), || adf_tau(alt_noise, lags));
            rejects_unit_root(null_tau, alt_tau)
        };
        if stationary {
            NoiseModel {
                rho: lsq::ar1_coefficient(alt_noise),
                ma: 0.0,
            }
        } else {
            NoiseModel {
                rho: 1.0,
                ma: ma1_theta(&lsq::quasi_difference(null_noise, 1.0)),
            }
        }
    }

    /// The transform: quasi-difference, then the inverse MA(1) filter (one row fewer).
    pub(in crate::diagnose) fn whiten(&self, v: &[f64]) -> Vec<f64> {
        inverse_ma1(lsq::quasi_difference(v, self.rho), self.ma)
    }
}

/// 1 % critical value of the Dickey–Fuller test with a constant (MacKinnon 2010, asymptotic):
/// the slow-noise test leaves the conservative integrated model only on strong evidence of
/// stationarity (a false "stationary" on a walk is a false finding; a false "integrated" on
/// stationary noise only costs power).
const ADF_CRITICAL: f64 = -3.43;

/// 1 % critical value of a residual-based (Engle–Granger) unit-root test with three fitted
/// variables (MacKinnon 2010, asymptotic): the strongest candidate's residual comes from a
/// least-squares fit of its column(s) and, for a lag, a fitted time constant, chosen as the best
/// of the library.
const ADF_CRITICAL_FITTED: f64 = -4.29;

/// The step's unit-root test ([`NoiseModel::of`]): ADF τ of the null residual at 1 %
/// ([`ADF_CRITICAL`]), or of the residual the strongest candidate leaves at the residual-based 1 %
/// ([`ADF_CRITICAL_FITTED`]).
fn rejects_unit_root(null_tau: f64, alt_tau: f64) -> bool {
    null_tau <= ADF_CRITICAL || alt_tau <= ADF_CRITICAL_FITTED
}

/// The recording's verdict from its signals' (null τ, alt τ) before any term
/// ([`NoiseModel::of`]): `None` with fewer than two signals; else a unit root is rejected only
/// when the most stationary-looking signal rejects it on its own residual at 1 % (no fitted
/// column to pull it there) AND every signal rejects it by [`rejects_unit_root`]. The first
/// alone let a walk channel that looks stationary by chance decide for the recording; the second
/// alone let a strongest candidate of a few hundred, fitted to each walk channel, make both
/// residuals look stationary (seed 2026 `random_walk_0000`, null: τ −1.2 on both channels, −4.3
/// and −4.5 after the fit).
pub(in crate::diagnose) fn recording_rejects_unit_root(taus: &[(f64, f64)]) -> Option<bool> {
    let most_stationary = taus.iter().map(|t| t.0).fold(f64::INFINITY, f64::min);
    (taus.len() >= 2).then(|| {
        most_stationary <= ADF_CRITICAL && taus.iter().all(|&(n, a)| rejects_unit_root(n, a))
    })
}

/// Lagged differences in the augmented Dickey–Fuller regression: Schwert's 4·(n/100)^{1/4}, at
/// most 12 and n/20 (short records).
pub(in crate::diagnose) fn adf_lags(n: usize) -> usize {
    crate::numeric::trunc_usize(4.0 * (n as f64 / 100.0).powf(0.25))
        .min(12)
        .min(n / 20)
}

/// Augmented Dickey–Fuller t-statistic (with a constant) of Δy_t = a + γ·y_{t−1} + Σ_{j≤p}
/// β_j·Δy_{t−j} + e_t: γ̂ / se(γ̂). Very negative: no unit root (stationary); near 0 or positive:
/// integrated. +∞ when the record is too short (or too degenerate) to tell: the integrated model
/// is the safe one.
///
/// The regression's k = p + 2 columns are never held: their cross-products (the normal equations)
/// are accumulated in one pass and solved by Cholesky, so the test takes O(k²) memory instead of k
/// columns of n rows (≈ 130 MB at 10⁶ rows and p = 12: the peak of a 1M-row diagnosis). y is
/// centred first (the constant absorbs it), so the level column is of the size of the walk, not of
/// its offset, and the cross-products stay well conditioned.
pub(in crate::diagnose) fn adf_tau(y: &[f64], p: usize) -> f64 {
    let n = y.len();
    if n < p + 12 {
        return f64::INFINITY;
    }
    let k = p + 2;
    let mean = y.iter().sum::<f64>() / n as f64;
    let mut sums = RowSums::new(k);
    let mut yty = 0.0;
    // Row t: [1, y_{t−1} − ȳ, Δy_{t−1}, …, Δy_{t−p}], response Δy_t.
    for t in p + 1..n {
        let x = sums.row_mut();
        x[0] = 1.0;
        x[1] = y[t - 1] - mean;
        for j in 1..=p {
            x[1 + j] = y[t - j] - y[t - j - 1];
        }
        let dy = y[t] - y[t - 1];
        sums.add_values(dy);
        yty += dy * dy;
    }
    let (xtx, xty) = sums.into_gram();
    let Some(chol) = xtx.cholesky() else {
        return f64::INFINITY;
    };
    let beta = chol.solve(&xty);
    let mut e1 = nalgebra::DVector::<f64>::zeros(k);
    e1[1] = 1.0;
    let inv11 = chol.solve(&e1)[1];
    let m = (n - p - 1) as f64;
    let rss = (yty - beta.dot(&xty)).max(0.0);
    let se = (rss / (m - k as f64) * inv11).sqrt();
    if se.is_nan() || se <= 0.0 {
        return f64::INFINITY;
    }
    beta[1] / se
}

/// θ of an MA(1) d_t = u_t − θ·u_{t−1} from the lag-1 autocorrelation r₁ = −θ/(1 + θ²) of `d`
/// (moment estimator, invertible root), 0 when r₁ ≥ 0, at most 0.9. On the first differences of
/// a random walk plus white noise of variance σ_ε², r₁ = −σ_ε²/(σ_η² + 2σ_ε²).
fn ma1_theta(d: &[f64]) -> f64 {
    let n = d.len();
    if n < 3 {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    let den: f64 = d.iter().map(|v| (v - mean).powi(2)).sum();
    let num: f64 = d.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum();
    if den.is_nan() || den <= 0.0 {
        return 0.0;
    }
    let r1 = (num / den).clamp(-0.499, 0.0);
    if r1 >= 0.0 {
        return 0.0;
    }
    ((-1.0 + (1.0 - 4.0 * r1 * r1).sqrt()) / (2.0 * r1)).min(0.9)
}

/// The inverse MA(1) filter u_t = d_t + θ·u_{t−1} (u_0 = d_0): white innovations from an MA(1)
/// with coefficient θ (the conditional GLS transform); θ = 0 returns `d` as it is.
fn inverse_ma1(mut d: Vec<f64>, theta: f64) -> Vec<f64> {
    if theta > 0.0 {
        for t in 1..d.len() {
            d[t] += theta * d[t - 1];
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::super::super::lsq::dot;
    use super::*;
    use rand::SeedableRng;

    /// A standard normal draw.
    fn normal(rng: &mut rand_chacha::ChaCha8Rng) -> f64 {
        use rand::Rng;
        rng.sample(rand_distr::StandardNormal)
    }

    /// The ADF statistic the direct way (columns held, Frisch–Waugh with Gram–Schmidt): what
    /// `adf_tau`'s one-pass normal equations must reproduce.
    fn adf_tau_direct(y: &[f64], p: usize) -> f64 {
        let rows = p + 1..y.len();
        let d = |t: usize| y[t] - y[t - 1];
        let mut nuisance = vec![vec![1.0; rows.len()]];
        for j in 1..=p {
            nuisance.push(rows.clone().map(|t| d(t - j)).collect());
        }
        let basis = lsq::orthonormalize(&[], nuisance, 2);
        let lag = lsq::deflate(&basis, &rows.clone().map(|t| y[t - 1]).collect::<Vec<_>>());
        let dy = lsq::deflate(&basis, &rows.clone().map(d).collect::<Vec<_>>());
        let sxx = dot(&lag, &lag);
        let gamma = dot(&lag, &dy) / sxx;
        let rss: f64 = dy
            .iter()
            .zip(&lag)
            .map(|(e, x)| (e - gamma * x).powi(2))
            .sum();
        let dof = rows.len() as f64 - basis.len() as f64 - 1.0;
        gamma / (rss / dof / sxx).sqrt()
    }

    #[test]
    fn adf_in_one_pass_is_the_direct_least_squares_statistic() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for (rho, offset_um, p) in [
            (1.0, 250.0, 12),
            (0.99, -40.0, 8),
            (0.5, 3.0, 4),
            (0.0, 0.0, 0),
        ] {
            let mut level = 0.0;
            // Readings quantised to 0.05 µm, as a laser's are, on top of the process.
            let y: Vec<f64> = (0..20_000)
                .map(|_| {
                    level = rho * level + normal(&mut rng);
                    ((offset_um + 0.3 * level) / 0.05).round() * 0.05
                })
                .collect();
            let (ours, direct) = (adf_tau(&y, p), adf_tau_direct(&y, p));
            assert!(
                (ours - direct).abs() <= 1e-8 * direct.abs().max(1.0),
                "ρ {rho}, p {p}: one pass τ {ours}, direct {direct}"
            );
        }
    }

    /// The unit-root test separates a random walk (τ above the 1 % critical value −3.43) from
    /// white noise and from AR(0.5) (τ far below it) on the same innovations.
    #[test]
    fn adf_tells_a_random_walk_from_stationary_noise() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let e: Vec<f64> = (0..2000).map(|_| normal(&mut rng)).collect();
        let walk: Vec<f64> = e
            .iter()
            .scan(0.0, |s, v| {
                *s += v;
                Some(*s)
            })
            .collect();
        let ar: Vec<f64> = e
            .iter()
            .scan(0.0, |s, v| {
                *s = 0.5 * *s + v;
                Some(*s)
            })
            .collect();
        let p = adf_lags(e.len());
        assert!(adf_tau(&walk, p) > -3.43, "walk τ {}", adf_tau(&walk, p));
        assert!(adf_tau(&e, p) < -10.0, "white τ {}", adf_tau(&e, p));
        assert!(adf_tau(&ar, p) < -10.0, "AR(0.5) τ {}", adf_tau(&ar, p));
        assert_eq!(
            adf_tau(&walk[..10], 0),
            f64::INFINITY,
            "too short: integrated"
        );
    }

    /// θ of a simulated MA(1) comes back, and the inverse filter whitens it (lag-1
    /// autocorrelation of the filtered series near 0, of the series itself near −θ/(1+θ²)).
    /// A signal that does not reject a unit root vetoes the stationary model: white noise is
    /// called stationary on its own (ρ < 1) and when every signal rejects, integrated (ρ = 1)
    /// when one does not.
    #[test]
    fn one_walk_signal_vetoes_the_stationary_model() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        let e: Vec<f64> = (0..2000).map(|_| normal(&mut rng)).collect();
        assert!(NoiseModel::of(&e, &e, None).rho < 0.5);
        assert!(NoiseModel::of(&e, &e, Some(true)).rho < 0.5);
        let vetoed = NoiseModel::of(&e, &e, Some(false));
        assert_eq!(
            vetoed.rho, 1.0,
            "integrated when no channel rejects a unit root"
        );
    }

    /// (null τ, alt τ) pairs measured on generated cases (`hil-sim gen-cases`, x then y).
    #[test]
    fn the_recording_rejects_a_unit_root_only_when_every_signal_does() {
        // One signal: no pooled verdict.
        assert_eq!(recording_rejects_unit_root(&[(-5.0, -6.0)]), None);
        // rw_decoy seed 13 case 1, a walk null: y looks stationary by chance, x does not.
        assert_eq!(
            recording_rejects_unit_root(&[(-1.44, -3.21), (-4.06, -5.11)]),
            Some(false)
        );
        // random_walk seed 2026 case 0, a walk null: a fitted candidate pulls both residuals
        // past the residual-based value, but neither channel rejects on its own residual.
        assert_eq!(
            recording_rejects_unit_root(&[(-1.22, -4.34), (-1.17, -4.50)]),
            Some(false)
        );
        // ar099 seed 7 case 19: x carries a smooth effect (rejects only once it is taken out),
        // y shows the stationary noise.
        assert_eq!(
            recording_rejects_unit_root(&[(-2.39, -4.88), (-4.05, -4.14)]),
            Some(true)
        );
    }

    #[test]
    fn ma1_theta_and_its_inverse_filter_whiten_an_ma1() {
        let lag1 = |d: &[f64]| {
            let m = d.iter().sum::<f64>() / d.len() as f64;
            let den: f64 = d.iter().map(|v| (v - m).powi(2)).sum();
            d.windows(2).map(|w| (w[0] - m) * (w[1] - m)).sum::<f64>() / den
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let u: Vec<f64> = (0..20_000).map(|_| normal(&mut rng)).collect();
        let theta = 0.6;
        let d: Vec<f64> = (0..u.len())
            .map(|t| u[t] - if t > 0 { theta * u[t - 1] } else { 0.0 })
            .collect();
        let r1 = lag1(&d);
        assert!((r1 + theta / (1.0 + theta * theta)).abs() < 0.03, "r1 {r1}");
        let est = ma1_theta(&d);
        assert!((est - theta).abs() < 0.05, "θ̂ {est}");
        let w = inverse_ma1(d.clone(), est);
        assert!(lag1(&w).abs() < 0.03, "filtered r1 {}", lag1(&w));
        // Positive lag-1 correlation has no invertible MA(1) of this sign: θ = 0, no filtering.
        let smooth: Vec<f64> = u.windows(2).map(|w| w[0] + w[1]).collect();
        assert_eq!(ma1_theta(&smooth), 0.0);
        assert_eq!(inverse_ma1(smooth.clone(), 0.0), smooth);
    }
}
