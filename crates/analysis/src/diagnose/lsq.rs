//! Least-squares kernels on column vectors: Gram–Schmidt projection (the screening step adds a
//! candidate's columns to an orthonormal basis and reads off the RSS drop, as FROLS/ERR does),
//! full fits with covariance (normal equations solved by SVD, so rank deficiency is tolerated),
//! block cross-validation, and the effective sample size of AR(1)-correlated residuals.

use nalgebra::{DMatrix, DVector};

mod blocks;
mod cgs;
mod gram;
mod mgs;
mod spans;

pub use blocks::{cv_rss, forward_block_rss, forward_rss, forward_rss_pred};
pub use cgs::projected_gain;
pub use mgs::{orthonormalize, orthonormalize_gain};

pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn axpy(k: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(yi, xi)| *yi += k * xi);
}

/// RSS drop from projecting `r0` (already orthogonal to the basis) on orthonormal `u`.
pub fn gain(u: &[Vec<f64>], r0: &[f64]) -> f64 {
    u.iter().map(|c| dot(c, r0).powi(2)).sum()
}

/// The RSS drop [`orthonormalize`] + [`gain`] would give for `cols` against orthonormal `basis` and
/// a residual `r0` orthogonal to it, from dot products only (XᵀX, BᵀX, Xᵀr0 in one pass over the
/// rows, then a small Cholesky of XᵀX − (BᵀX)ᵀ(BᵀX)): no orthonormalised copies, half the
/// arithmetic. A column whose part outside the basis is below 1e-5 of its norm is dropped (the
/// subtraction cannot resolve less), so it is used only for candidates that are never nearly in
/// the span of the basis (cyclic sin/cos pairs). Returns the drop and the number of columns kept.
pub fn gram_gain(basis: &[Vec<f64>], cols: &[Vec<f64>], r0: &[f64]) -> (f64, usize) {
    gain_of_sums(cols.len(), basis.len(), gram::sums(basis, cols, r0))
}

/// [`gram_gain`] of `periods` sin/cos pairs written block by block by `fill(rows, cols)` (each
/// pair's two columns over `rows`, from 0 in `cols[p]`): the same gains, bit for bit, with r0
/// and the basis read once for all the pairs (`gram::pair_sums_sweep`).
pub fn gram_gains_sweep(
    basis: &[Vec<f64>],
    r0: &[f64],
    periods: usize,
    fill: impl FnMut(std::ops::Range<usize>, &mut [[Vec<f64>; 2]]),
) -> Vec<(f64, usize)> {
    gram::pair_sums_sweep(basis, r0, periods, fill)
        .into_iter()
        .map(|sums| gain_of_sums(2, basis.len(), sums))
        .collect()
}

/// [`gram_gain`] of one sin/cos pair whose row i is `phasors[·][idx[i]]` (one value per distinct
/// position), the same bits, without the pair's two whole columns (`gram::pair_sums_gathered`).
pub fn gram_gain_gathered(
    basis: &[Vec<f64>],
    r0: &[f64],
    phasors: [&[f64]; 2],
    idx: &[u32],
) -> (f64, usize) {
    gain_of_sums(
        2,
        basis.len(),
        gram::pair_sums_gathered(basis, r0, phasors, idx),
    )
}

/// The gain and columns kept of [`gram_gain`] from its sums (XᵀX, BᵀX, Xᵀr0; q columns, b basis
/// columns).
fn gain_of_sums(q: usize, b: usize, (g, cb, h): (Vec<f64>, Vec<f64>, Vec<f64>)) -> (f64, usize) {
    // M = XᵀX − CᵀC (lower triangle), then Cholesky with dropping; y = L⁻¹h, gain = ‖y‖².
    let mut m = vec![0.0; q * q];
    for a in 0..q {
        for a2 in 0..=a {
            m[a * q + a2] =
                g[a * q + a2] - (0..b).map(|k| cb[k * q + a] * cb[k * q + a2]).sum::<f64>();
        }
    }
    cgs::cholesky_gain(&m, &h, |j, d| !(d.is_nan() || d <= 1e-10 * g[j * q + j]))
}

/// `r0` minus its projection on orthonormal `u`.
pub fn deflate(u: &[Vec<f64>], r0: &[f64]) -> Vec<f64> {
    let mut r = r0.to_vec();
    for c in u {
        let d = dot(c, r0);
        axpy(-d, c, &mut r);
    }
    r
}

/// Effective number of independent samples of a residual: n / (long-run variance factor), the
/// factor 1 + 2·Σ_k w_k·ρ_k over lags k ≤ L = 4·n^{1/3} with Bartlett weights w_k = 1 − k/(L+1)
/// (Newey–West). Used for every test and criterion, because recordings sampled faster than their
/// noise decorrelates would otherwise make any smooth candidate "significant". A lag-1 (AR(1))
/// estimate is not enough: white + AR(1) noise mixtures have ρ₁ well below their long-run memory.
pub fn effective_n(r: &[f64]) -> f64 {
    let n = r.len();
    let nf = n as f64;
    if n < 8 {
        return nf;
    }
    let mean = r.iter().sum::<f64>() / nf;
    // Σ (r − mean)², term by term as `dot` of the centred copy would sum it.
    let den: f64 = r
        .iter()
        .map(|v| {
            let d = v - mean;
            d * d
        })
        .sum();
    if den.is_nan() || den <= 0.0 {
        return nf;
    }
    // Short records (tens of laser targets) cannot estimate long lags: cap L at n/10.
    let lags = newey_west_lags(n);
    // Long records: all L autocovariances from one FFT (O(n log n) instead of L·n: 400 lags of
    // 10⁶ samples were a quarter of a 1M-row diagnosis), centred into the FFT buffer without a
    // centred copy; short ones keep the direct sums.
    let acov = if n >= FFT_MIN_N {
        autocovariances_fft(r, mean, lags)
    } else {
        let c: Vec<f64> = r.iter().map(|v| v - mean).collect();
        (0..=lags).map(|k| dot(&c[..n - k], &c[k..])).collect()
    };
    let mut factor = 1.0;
    for (k, a) in acov.iter().enumerate().skip(1) {
        let rho = a / den;
        factor += 2.0 * (1.0 - k as f64 / (lags + 1) as f64) * rho;
    }
    (nf / factor.max(1.0)).max(nf.min(5.0))
}

/// Lag-1 autoregression coefficient of `r` (least-squares slope of r_t on r_{t−1} after removing
/// the mean), clamped to [0, 1]: the ρ of an AR(1) error model for the Cochrane–Orcutt transform
/// ([`quasi_difference`]). Negative ρ is taken as 0 (no transform), since overdifferencing would
/// only add noise; a random walk gives ρ ≈ 1 (the transform is then the first difference).
pub fn ar1_coefficient(r: &[f64]) -> f64 {
    let n = r.len();
    if n < 3 {
        return 0.0;
    }
    let mean = r.iter().sum::<f64>() / n as f64;
    let (mut num, mut den) = (0.0, 0.0);
    for w in r.windows(2) {
        let (a, b) = (w[0] - mean, w[1] - mean);
        num += a * b;
        den += a * a;
    }
    if den.is_nan() || den <= 0.0 {
        return 0.0;
    }
    (num / den).clamp(0.0, 1.0)
}

/// v_t − ρ·v_{t−1} for t ≥ 1 (one row fewer): the Cochrane–Orcutt quasi-difference. Applied to a
/// residual and to the columns explaining it, it turns an AR(1) error with coefficient ρ into white
/// innovations, so an F-test or criterion on the transformed rows counts independent samples
/// (generalised least squares); ρ = 1 is the first difference (random-walk errors).
pub fn quasi_difference(v: &[f64], rho: f64) -> Vec<f64> {
    v.windows(2).map(|w| w[1] - rho * w[0]).collect()
}

/// The Newey–West window of [`effective_n`]: L = 4·n^{1/3} lags, at most n/10 (short records
/// cannot estimate long lags), at least 1.
pub fn newey_west_lags(n: usize) -> usize {
    crate::numeric::trunc_usize(4.0 * (n as f64).cbrt())
        .min(n / 10)
        .max(1)
}

/// Records at least this long get their autocovariances by FFT in [`effective_n`], cyclic
/// candidates their screening gain from [`gram_gain`] and the others theirs from
/// [`projected_gain`], and [`orthonormalize`]'s sums over parallel spans of rows; shorter ones
/// keep the direct sums and one-chain modified Gram–Schmidt (the bits their shipped models and
/// suites were written with).
pub const FFT_MIN_N: usize = 200_000;

/// Σ_i c_i·c_{i+k} for k = 0…lags of c = r − mean, by the Wiener–Khinchin route: zero-pad to
/// m ≥ n + lags (no wrap-around), |FFT|², and back. The power spectrum P is real and even, so its
/// inverse transform is (1/m)·Σ_j P_j·cos(2πjk/m), the real part of the forward transform of P
/// laid out over all m frequencies: one real forward plan serves both ways.
fn autocovariances_fft(r: &[f64], mean: f64, lags: usize) -> Vec<f64> {
    use realfft::RealFftPlanner;
    use std::sync::{Mutex, PoisonError};
    // One plan kept for the process: its twiddles (16 MB at 10⁶ rows) were recomputed at every
    // call, half of its time.
    static PLANS: Mutex<Option<RealFftPlanner<f64>>> = Mutex::new(None);
    let m = (r.len() + lags + 1).next_power_of_two();
    let fft = PLANS
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .get_or_insert_with(RealFftPlanner::new)
        .plan_fft_forward(m);
    let mut buf: Vec<f64> = r
        .iter()
        .map(|&v| v - mean)
        .chain(std::iter::repeat(0.0))
        .take(m)
        .collect();
    let mut spectrum = fft.make_output_vec();
    fft.process(&mut buf, &mut spectrum)
        .expect("buffers sized by the plan");
    // P_j at j and at m − j (m ≥ 2: r holds at least 8 values).
    buf[0] = spectrum[0].norm_sqr();
    for (j, z) in spectrum.iter().enumerate().skip(1) {
        buf[j] = z.norm_sqr();
        buf[m - j] = buf[j];
    }
    fft.process(&mut buf, &mut spectrum)
        .expect("buffers sized by the plan");
    spectrum[..=lags].iter().map(|z| z.re / m as f64).collect()
}

fn gram(
    cols: &[&[f64]],
    r: &[f64],
    rows: impl Iterator<Item = usize> + Clone,
) -> (DMatrix<f64>, DVector<f64>) {
    gram_by(cols.len(), rows, |a, i| cols[a][i], |i| r[i])
}

/// [`fn@gram`] of columns read through `x(a, i)` (column `a`, row `i`) and target `y(i)`, so a
/// transformed column (demeaned within cells) need not be stored: the same sums in the same order.
fn gram_by(
    p: usize,
    rows: impl Iterator<Item = usize>,
    x: impl Fn(usize, usize) -> f64,
    y: impl Fn(usize) -> f64,
) -> (DMatrix<f64>, DVector<f64>) {
    let mut sums = RowSums::new(p);
    for i in rows {
        sums.add_row(|a| x(a, i), y(i));
    }
    sums.into_gram()
}

/// Gram sums taken row by row: g_ab += x_a·x_b for b ≤ a and h_a += x_a·y, each sum in the
/// order its rows are added (so sums taken through here have the bits of their row order). The
/// lower triangle is packed (row a at a(a+1)/2) and the row's values are read once into `row`:
/// the triangle's sums of one row are then independent adds over contiguous memory, where
/// indexing a matrix per product (a bounds check and a column-major offset each) was 11 % of a
/// 10⁶-row diagnosis' CPU (`perf`: `adf_tau`, `gram_by`, the block Grams).
pub(super) struct RowSums {
    g: Vec<f64>,
    h: Vec<f64>,
    row: Vec<f64>,
}

impl RowSums {
    pub(super) fn new(p: usize) -> Self {
        Self {
            g: vec![0.0; p * (p + 1) / 2],
            h: vec![0.0; p],
            row: vec![0.0; p],
        }
    }

    /// One row's products; `x(a)` is column a at the row, `y` the target.
    pub(super) fn add_row(&mut self, x: impl Fn(usize) -> f64, y: f64) {
        for (a, v) in self.row.iter_mut().enumerate() {
            *v = x(a);
        }
        self.add_values(y);
    }

    /// One row's products of the values already in [`RowSums::row_mut`].
    pub(super) fn add_values(&mut self, y: f64) {
        let mut off = 0;
        for (a, &xa) in self.row.iter().enumerate() {
            self.h[a] += xa * y;
            let ga = &mut self.g[off..=off + a];
            for (g, &xb) in ga.iter_mut().zip(&self.row[..=a]) {
                *g += xa * xb;
            }
            off += a + 1;
        }
    }

    /// The row [`RowSums::add_values`] reads.
    pub(super) fn row_mut(&mut self) -> &mut [f64] {
        &mut self.row
    }

    /// The symmetric Gram matrix (the upper triangle a copy of the lower: x_a·x_b and x_b·x_a
    /// are the same product, so the copy is the bits the upper sums would have) and h.
    pub(super) fn into_gram(self) -> (DMatrix<f64>, DVector<f64>) {
        let p = self.h.len();
        let mut g = DMatrix::zeros(p, p);
        let mut off = 0;
        for a in 0..p {
            for b in 0..=a {
                g[(a, b)] = self.g[off + b];
                g[(b, a)] = self.g[off + b];
            }
            off += a + 1;
        }
        (g, DVector::from_vec(self.h))
    }
}

fn pinv_solve(g: &DMatrix<f64>, h: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
    let svd = g.clone().svd(true, true);
    let smax = svd.singular_values.max();
    let inv = svd
        .pseudo_inverse(smax * 1e-12)
        .unwrap_or_else(|_| DMatrix::zeros(g.nrows(), g.ncols()));
    (&inv * h, inv)
}

/// Least-squares fit of `r` on `cols`: coefficients, their covariance (σ² scaled by n/n_eff for
/// correlated residuals), the residual and n_eff of the residual.
#[derive(Debug)]
pub struct Fit {
    pub coef: Vec<f64>,
    pub cov: DMatrix<f64>,
    pub resid: Vec<f64>,
    pub rss: f64,
    pub n_eff: f64,
}

pub fn fit(cols: &[&[f64]], r: &[f64]) -> Fit {
    fit_dof(cols, r, 0)
}

/// The coefficients of [`fit`] alone (no residual, covariance or n_eff).
pub fn coef(cols: &[&[f64]], r: &[f64]) -> Vec<f64> {
    let (g, h) = gram(cols, r, 0..r.len());
    pinv_solve(&g, &h).0.iter().copied().collect()
}

/// `r − Σ_a beta_a·cols_a`, row by row: [`fit`]'s residual for its coefficients.
pub fn residual(cols: &[&[f64]], beta: &[f64], r: &[f64]) -> Vec<f64> {
    (0..r.len())
        .map(|i| {
            r[i] - cols
                .iter()
                .enumerate()
                .map(|(a, c)| beta[a] * c[i])
                .sum::<f64>()
        })
        .collect()
}

/// [`fit`] with `extra` nuisance parameters already removed from `cols` and `r`.
fn fit_dof(cols: &[&[f64]], r: &[f64], extra: usize) -> Fit {
    let (g, h) = gram(cols, r, 0..r.len());
    let (beta, inv) = pinv_solve(&g, &h);
    let coef: Vec<f64> = beta.iter().copied().collect();
    let resid = residual(cols, &coef, r);
    fit_of(coef, inv, resid, cols.len() + extra)
}

/// The [`Fit`] of solved coefficients: `inv` the pseudo-inverse of the Gram matrix, `resid` the
/// residual, `params` the parameters spent (columns and nuisance).
fn fit_of(coef: Vec<f64>, inv: DMatrix<f64>, resid: Vec<f64>, params: usize) -> Fit {
    let n = resid.len();
    let rss = dot(&resid, &resid);
    let n_eff = effective_n(&resid);
    let dof = (n_eff - params as f64).max(1.0);
    let sigma2 = rss / n as f64 * n_eff / dof; // per-sample variance, corrected for lost dof
    let inflate = n as f64 / n_eff;
    Fit {
        coef,
        cov: inv * (sigma2 * inflate),
        resid,
        rss,
        n_eff,
    }
}

/// [`fit`] of `r` on `cols` plus the means of the `k` cells (`cell` per sample), returning only the
/// `cols` part: by Frisch–Waugh–Lovell the coefficients, residual and the `cols` block of the
/// covariance equal those of the fit with one indicator column per cell, here computed on `cols`
/// and `r` demeaned within cells (the cells count in the lost degrees of freedom). No dense
/// indicator columns: 32 of them were 0.25 GB on a 1M-row recording.
pub fn fit_within_cells(cols: &[&[f64]], r: &[f64], cell: &[usize], k: usize) -> Fit {
    let cell_means = |v: &[f64]| {
        let mut sum = vec![0.0; k];
        let mut cnt = vec![0usize; k];
        for (x, &c) in v.iter().zip(cell) {
            sum[c] += x;
            cnt[c] += 1;
        }
        for (m, &c) in sum.iter_mut().zip(&cnt) {
            *m /= c.max(1) as f64;
        }
        sum
    };
    // Demeaned as each row is read, not stored: a stored copy was 8 MB per column at 10⁶ rows,
    // the peak of the whole diagnosis (issue 36 point 7).
    let r_means = cell_means(r);
    let col_means: Vec<Vec<f64>> = cols.iter().map(|c| cell_means(c)).collect();
    let x = |a: usize, i: usize| cols[a][i] - col_means[a][cell[i]];
    let y = |i: usize| r[i] - r_means[cell[i]];
    let (g, h) = gram_by(cols.len(), 0..r.len(), x, y);
    let (beta, inv) = pinv_solve(&g, &h);
    let coef: Vec<f64> = beta.iter().copied().collect();
    let resid = (0..r.len())
        .map(|i| y(i) - (0..cols.len()).map(|a| coef[a] * x(a, i)).sum::<f64>())
        .collect();
    // Every cell counts as a parameter, as its indicator column did (even an empty one).
    fit_of(coef, inv, resid, cols.len() + k)
}

#[cfg(test)]
mod tests {
    #[test]
    fn gram_gain_equals_the_gram_schmidt_gain() {
        let n = 3000;
        let col =
            |f: &dyn Fn(f64) -> f64| -> Vec<f64> { (0..n).map(|i| f(f64::from(i))).collect() };
        let basis = orthonormalize(
            &[],
            vec![
                col(&|_| 1.0),
                col(&|t| t / 3000.0),
                col(&|t| (t * 0.01).sin()),
            ],
            2,
        );
        let r = col(&|t| (t * 0.05).sin() * 2.0 + (t * 0.7).cos() + t / 1000.0);
        let r0 = deflate(&basis, &r);
        let cols = vec![col(&|t| (t * 0.05).sin()), col(&|t| (t * 0.05).cos())];
        let want = gain(&orthonormalize(&basis, cols.clone(), 1), &r0);
        let (got, q) = gram_gain(&basis, &cols, &r0);
        assert_eq!(q, 2);
        assert!((got - want).abs() < 1e-9 * want, "{got} vs {want}");
        // A column inside the basis' span is dropped.
        let (g1, q1) = gram_gain(&basis, &[col(&|t| 2.0 + t / 1500.0)], &r0);
        assert_eq!((q1, g1), (0, 0.0));
    }

    #[test]
    fn fft_autocovariances_equal_the_direct_sums() {
        let c: Vec<f64> = (0..5000)
            .map(|i| ((f64::from(i) * 0.37).sin() + (f64::from(i) * 1.91).cos() * 0.5).powi(3))
            .collect();
        // Read with an offset the mean removes, as `effective_n` hands it over.
        let shifted: Vec<f64> = c.iter().map(|v| v + 0.25).collect();
        let fft = autocovariances_fft(&shifted, 0.25, 40);
        assert_eq!(fft.len(), 41);
        for (k, a) in fft.iter().enumerate() {
            let direct = dot(&c[..c.len() - k], &c[k..]);
            assert!(
                (a - direct).abs() < 1e-9 * direct.abs().max(1.0),
                "lag {k}: {a} vs {direct}"
            );
        }
    }

    use super::*;

    /// The packed sums are a matrix's row-by-row sums bit for bit, upper triangle included, and
    /// `add_row` and `add_values` take the same row.
    #[test]
    fn row_sums_are_the_matrix_sums_bit_for_bit() {
        let p = 5;
        let x = |a: usize, i: usize| {
            ((i * (a + 3)) as f64 * 0.37).sin() * [1.0, 10.0, 100.0, 1e3, 1e4][a]
        };
        let y = |i: usize| (i as f64 * 0.11).cos() + 0.3;
        let (mut g, mut h) = (DMatrix::<f64>::zeros(p, p), DVector::<f64>::zeros(p));
        let (mut by_fn, mut by_values) = (RowSums::new(p), RowSums::new(p));
        for i in 0..1000 {
            for a in 0..p {
                h[a] += x(a, i) * y(i);
                for b in 0..p {
                    g[(a, b)] += x(a, i) * x(b, i);
                }
            }
            by_fn.add_row(|a| x(a, i), y(i));
            for (a, v) in by_values.row_mut().iter_mut().enumerate() {
                *v = x(a, i);
            }
            by_values.add_values(y(i));
        }
        let bits = |(g, h): (DMatrix<f64>, DVector<f64>)| -> Vec<u64> {
            g.iter().chain(h.iter()).map(|v| v.to_bits()).collect()
        };
        let want = bits((g, h));
        assert_eq!(bits(by_fn.into_gram()), want);
        assert_eq!(bits(by_values.into_gram()), want);
    }

    #[test]
    fn fit_recovers_exact_coefficients_and_projection_matches_fit() {
        let x: Vec<f64> = (0..50).map(f64::from).collect();
        let one = vec![1.0; 50];
        let r: Vec<f64> = x
            .iter()
            .map(|v| 3.0 + 0.5 * v + ((v * 1.7).sin() * 0.1))
            .collect();
        let f = fit(&[&one, &x], &r);
        assert!((f.coef[1] - 0.5).abs() < 0.01, "{:?}", f.coef);
        let basis = orthonormalize(&[], vec![one.clone()], 2);
        let r0 = deflate(&basis, &r);
        let u = orthonormalize(&basis, vec![x.clone()], 2);
        let rss1 = dot(&r0, &r0) - gain(&u, &r0);
        assert!(
            (rss1 - f.rss).abs() < 1e-9 * dot(&r0, &r0),
            "{rss1} vs {}",
            f.rss
        );
        // A column already in the span is dropped.
        assert!(orthonormalize(&basis, vec![vec![2.0; 50]], 2).is_empty());
    }

    #[test]
    fn ar1_coefficient_and_quasi_difference_whiten_an_ar1() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut a = 0.0;
        let r: Vec<f64> = (0..20_000)
            .map(|_| {
                a = 0.95 * a + rng.random_range(-1.0..1.0);
                a
            })
            .collect();
        let rho = ar1_coefficient(&r);
        assert!((rho - 0.95).abs() < 0.01, "rho {rho}");
        let w = quasi_difference(&r, rho);
        assert_eq!(w.len(), r.len() - 1);
        assert!(
            ar1_coefficient(&w) < 0.05,
            "the transform leaves white innovations: {}",
            ar1_coefficient(&w)
        );
        assert!(effective_n(&w) > 0.8 * w.len() as f64);
        assert!(effective_n(&r) < 0.1 * r.len() as f64);
        assert_eq!(quasi_difference(&[1.0, 3.0, 6.0], 1.0), vec![2.0, 3.0]);
    }

    #[test]
    fn effective_n_matches_ar1_long_run_variance() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 20_000;
        let white: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let ne = effective_n(&white);
        assert!(
            ne > 0.85 * f64::from(n),
            "white noise keeps n_eff ≈ n: {ne}"
        );
        // AR(1) with ρ = 0.9: long-run variance factor (1+ρ)/(1−ρ) = 19 → n_eff ≈ 1053. Bartlett
        // weights bias it up a little at L = 4·n^{1/3} ≈ 108.
        let mut a = 0.0;
        let ar: Vec<f64> = white
            .iter()
            .map(|e| {
                a = 0.9 * a + e;
                a
            })
            .collect();
        let ne = effective_n(&ar);
        assert!((800.0..1800.0).contains(&ne), "AR(1) n_eff {ne}");
    }
}
