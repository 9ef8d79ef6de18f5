//! The null model a candidate is screened against in forward selection (`select.rs`): the fitted
//! terms as an orthonormal basis, optionally with own-axis position-cell means as a nuisance, and
//! the RSS drop (µm²) a candidate's columns give on top of it; ΔBIC on the effective sample size,
//! the golden-section refinement of a nonlinear parameter, a candidate's explained part, and the
//! winner's test under the step's model of slow noise ([`unit_root`]).
//! Residuals are measured − sim, µm.

use super::candidates::{Candidate, Kind};
use super::features::Context;
use super::lsq::{self, dot};

mod unit_root;

pub(super) use unit_root::{NoiseModel, adf_lags, adf_tau, recording_rejects_unit_root};

/// Whether candidate `c` is tested within own-axis position cells (see the module comment).
pub(super) fn within_cells(c: &Candidate) -> bool {
    matches!(c.kind, Kind::Backlash | Kind::ReversalProfile { .. })
}

/// The null a candidate is screened against: orthonormal basis, residual on it, its RSS, and the
/// number of nuisance columns beyond the fitted terms.
pub(super) struct Null<'a> {
    pub(super) basis: std::borrow::Cow<'a, [Vec<f64>]>,
    pub(super) r0: Vec<f64>,
    pub(super) rss0: f64,
    pub(super) extra: usize,
    /// Own-axis position cell per sample and the cell count, when the null holds the cell means.
    /// They are applied implicitly: a column is demeaned within cells, then projected on `basis`
    /// (the fitted terms demeaned within cells). The same projection as with one-hot cell
    /// columns in the basis, without the 32 dense columns per step (0.5 GB and much of the time
    /// on a 1M-row recording).
    pub(super) cells: Option<(&'a [usize], usize)>,
}

impl<'a> Null<'a> {
    /// The null of `basis` (orthonormal, holding the intercept) plus the cell means.
    pub(super) fn within_cells(
        basis: &[Vec<f64>],
        r: &[f64],
        cell: &'a [usize],
        k: usize,
    ) -> Null<'a> {
        let demeaned = basis
            .iter()
            .map(|b| {
                let mut v = b.clone();
                demean_in_cells(&mut v, cell, k);
                v
            })
            // Unit vectors of the basis inside the cells' span (the intercept, any function of
            // the cell) are gone up to rounding: dropped as `orthonormalize` would.
            .filter(|v: &Vec<f64>| dot(v, v).sqrt() >= 1e-7)
            .collect();
        let dense = lsq::orthonormalize(&[], demeaned, 2);
        let mut occupied = vec![false; k];
        cell.iter().for_each(|&c| occupied[c] = true);
        let dim = occupied.iter().filter(|o| **o).count() + dense.len();
        let mut rc = r.to_vec();
        demean_in_cells(&mut rc, cell, k);
        let r0 = lsq::deflate(&dense, &rc);
        let rss0 = dot(&r0, &r0);
        Null {
            basis: dense.into(),
            r0,
            rss0,
            extra: dim.saturating_sub(basis.len()),
            cells: Some((cell, k)),
        }
    }
}

/// `v` minus its mean within each of the `k` cells.
pub(super) fn demean_in_cells(v: &mut [f64], cell: &[usize], k: usize) {
    let mut sum = vec![0.0; k];
    let mut cnt = vec![0usize; k];
    for (x, &c) in v.iter().zip(cell) {
        sum[c] += x;
        cnt[c] += 1;
    }
    for (m, &c) in sum.iter_mut().zip(&cnt) {
        *m /= c.max(1) as f64;
    }
    v.iter_mut().zip(cell).for_each(|(x, &c)| *x -= sum[c]);
}

/// Screen one candidate at one θ: RSS drop and parameter count (θ counts as one).
pub(super) fn score(
    ctx: &Context,
    c: &Candidate,
    theta: f64,
    nl: &Null<'_>,
) -> Option<(f64, usize)> {
    // A cyclic pair by its sums (as `score_cols` scores it) needs no columns: its rows are
    // gathered block by block from one value per distinct position (the same bits).
    if pair_by_sums(c, nl)
        && let Some(gq) = c.pair_gram_gain(ctx, theta, &nl.basis, &nl.r0)
    {
        return pair_scored(c, nl, gq);
    }
    score_cols(c, c.columns(ctx, theta), nl).0
}

/// [`score`] on columns already computed (a candidate's grid sweep); the column buffers come
/// back for the sweep's next θ (`Candidate::par_sweep_map`).
pub(super) fn score_cols(
    c: &Candidate,
    mut cols: Vec<Vec<f64>>,
    nl: &Null<'_>,
) -> (Option<(f64, usize)>, Vec<Vec<f64>>) {
    let (basis, r0, rss0) = (&nl.basis, &nl.r0, nl.rss0);
    if let Some((cell, k)) = nl.cells {
        // A column (numerically) inside the span of the cell means explains nothing new: the
        // same 1e-7 relative cut as `orthonormalize`, against the column's own norm.
        cols.retain_mut(|v| {
            let n0 = dot(v, v).sqrt();
            demean_in_cells(v, cell, k);
            dot(v, v).sqrt() >= 1e-7 * n0
        });
    }
    // Long recordings: a cyclic sin/cos pair (never nearly inside the basis' span) is scored from
    // dot products, without orthonormalised copies (most of a 1M-row diagnosis' screening).
    if pair_by_sums(c, nl) {
        return (pair_scored(c, nl, lsq::gram_gain(basis, &cols, r0)), cols);
    }
    // Long recordings: every other candidate (thermal lags at each τ of their grid, most of the
    // rest of the screening) without orthonormalised copies either (`lsq::projected_gain`).
    if r0.len() >= lsq::FFT_MIN_N {
        let (g, q) = lsq::projected_gain(basis, &cols, r0);
        let scored = (q > 0).then(|| {
            (
                g.min(rss0 * (1.0 - 1e-12)),
                q + usize::from(c.is_nonlinear()),
            )
        });
        return (scored, cols);
    }
    let (u, g) = lsq::orthonormalize_gain(basis, cols, r0);
    if u.is_empty() {
        return (None, u);
    }
    let g = g.min(rss0 * (1.0 - 1e-12));
    (Some((g, u.len() + usize::from(c.is_nonlinear()))), u)
}

/// Whether a cyclic pair is scored from its sums (`lsq::gram_gain`) under `nl`: on long
/// recordings, without cell means.
pub(super) fn pair_by_sums(c: &Candidate, nl: &Null<'_>) -> bool {
    nl.cells.is_none() && c.is_cyclic() && nl.r0.len() >= lsq::FFT_MIN_N
}

/// A cyclic pair's score from its [`lsq::gram_gain`] (gain, columns kept) under `nl`.
pub(super) fn pair_scored(
    c: &Candidate,
    nl: &Null<'_>,
    (g, q): (f64, usize),
) -> Option<(f64, usize)> {
    (q > 0).then(|| {
        (
            g.min(nl.rss0 * (1.0 - 1e-12)),
            q + usize::from(c.is_nonlinear()),
        )
    })
}

/// The part of `r0` a candidate explains (for collinearity between candidates).
pub(super) fn contribution(
    ctx: &Context,
    c: &Candidate,
    theta: f64,
    basis: &[Vec<f64>],
    r0: &[f64],
) -> Vec<f64> {
    let u = lsq::orthonormalize(basis, c.columns(ctx, theta), 1);
    let r1 = lsq::deflate(&u, r0);
    r0.iter().zip(&r1).map(|(a, b)| a - b).collect()
}

/// The winner's test repeated under the step's model of slow noise ([`NoiseModel`]): generalised
/// least squares on transformed rows. The null's residual and the candidate's new columns (its
/// part outside the null's span) are transformed and the partial F-test and ΔBIC are taken on the
/// transformed rows, on the effective sample size of the transformed residual.
///
/// Why on top of the Newey–West n_eff: with errors of very long memory (AR(0.99), a random walk)
/// the Newey–West window (4·n^{1/3} lags) sees only part of the long-run variance, so any smooth
/// column (a drift, a lagged temperature, a decoy random walk) looks significant. After the
/// transform a smooth column keeps only its increments, which must stand out against the noise's
/// innovations; a direction-odd step (backlash) or a cyclic term keeps most of its power.
/// Returns (ΔBIC, p-value).
pub(super) fn prewhitened_test(
    ctx: &Context,
    c: &Candidate,
    theta: f64,
    nl: &Null<'_>,
    p_cols: usize,
    model: &NoiseModel,
) -> Option<(f64, f64)> {
    use statrs::distribution::{ContinuousCDF, FisherSnedecor};
    let mut cols = c.columns(ctx, theta);
    if let Some((cell, k)) = nl.cells {
        cols.iter_mut().for_each(|v| demean_in_cells(v, cell, k));
    }
    let u = lsq::orthonormalize(&nl.basis, cols, 1);
    if u.is_empty() {
        return None;
    }
    let q = u.len() + usize::from(c.is_nonlinear());
    let wr0 = model.whiten(&nl.r0);
    // Each column is dropped once whitened: the peak is one column more than `u`, not twice `u`
    // (this test was the peak of a 1M-row diagnosis' heap).
    let wu: Vec<Vec<f64>> = u.into_iter().map(|v| model.whiten(&v)).collect();
    let wu = lsq::orthonormalize(&[], wu, 2);
    if wu.is_empty() {
        return None;
    }
    let rss0 = dot(&wr0, &wr0);
    let gain = lsq::gain(&wu, &wr0).min(rss0 * (1.0 - 1e-12));
    let n_eff = lsq::effective_n(&lsq::deflate(&wu, &wr0));
    let df2 = n_eff - (p_cols + q) as f64;
    let p = if df2 >= 1.0 && rss0 > 0.0 {
        let f = (gain / q as f64) / ((rss0 - gain) / df2);
        FisherSnedecor::new(q as f64, df2).map_or(1.0, |d| d.sf(f))
    } else {
        1.0
    };
    Some((delta_bic(n_eff, rss0, gain, q), p))
}

pub(super) fn delta_bic(n_eff: f64, rss0: f64, gain: f64, q: usize) -> f64 {
    n_eff * (rss0 / (rss0 - gain)).ln() - q as f64 * n_eff.ln()
}

pub(super) fn golden_refine(f: impl Fn(f64) -> f64, lo: f64, hi: f64, iters: usize) -> f64 {
    // Maximise f over log θ in [lo, hi].
    let (mut a, mut b) = (lo.ln(), hi.ln());
    let k = (5f64.sqrt() - 1.0) / 2.0;
    let mut c = b - k * (b - a);
    let mut d = a + k * (b - a);
    let (mut fc, mut fd) = (f(c.exp()), f(d.exp()));
    for _ in 0..iters {
        if fc > fd {
            b = d;
            d = c;
            fd = fc;
            c = b - k * (b - a);
            fc = f(c.exp());
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + k * (b - a);
            fd = f(d.exp());
        }
    }
    ((a + b) / 2.0).exp()
}

/// `r` minus its mean in each (own-axis position bin × direction) cell. The effective sample size
/// is estimated on this, so structure that is a function of position and direction (what the
/// library is looking for, or a smooth positioning error no candidate names) is not mistaken for
/// slowly correlated noise — which would make every test blind on short laser records.
pub(super) fn without_cell_means(ctx: &Context, axis: char, r: &[f64]) -> Vec<f64> {
    const BINS: usize = 8;
    let Some(f) = ctx.axis(axis) else {
        return r.to_vec();
    };
    let lo = f.pos_mm.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = f.pos_mm.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if hi - lo <= 1e-9 {
        return r.to_vec();
    }
    let cell = |i: usize| {
        let b = crate::numeric::bin(f.pos_mm[i], lo, hi, BINS);
        2 * b + usize::from(f.dir[i] > 0)
    };
    let mut sum = [0.0; 2 * BINS];
    let mut cnt = [0usize; 2 * BINS];
    for (i, v) in r.iter().enumerate() {
        sum[cell(i)] += v;
        cnt[cell(i)] += 1;
    }
    r.iter()
        .enumerate()
        .map(|(i, v)| v - sum[cell(i)] / cnt[cell(i)] as f64)
        .collect()
}
