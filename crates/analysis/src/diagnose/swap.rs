//! The exchange step after greedy forward selection ([`super::select`]): each accepted term is
//! tried against every other candidate given all the OTHER accepted terms, and replaced when a
//! candidate explains the residual better. Greedy forward selection cannot undo an early choice:
//! with two effects, a term that absorbs parts of both (a lagged spindle temperature standing in
//! for a column temperature plus a time drift) wins the first step, and the nested-family rule then
//! keeps the right sensor out. After an exchange, forward selection resumes, so the effect the
//! wrong term had been absorbing can enter. It runs only when the residual after selection still
//! holds structure no candidate explains (`locate::unexplained`), the sign of such a wrong turn.
//!
//! A replacement (one candidate, or one plus the best second candidate: a pure swap cannot help
//! when the wrong term alone explains more than the right one alone) must beat the term it
//! replaces by ΔBIC ≥ [`MIN_GAIN_BIC`] (one effective sample size for both), each new term must
//! pass the forward bar as a partial test given all others (ΔBIC > `min_delta_bic`, F-test ×
//! candidates tried < α), and the held-out RMS must not get worse.

use rayon::prelude::*;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::candidates::{Candidate, Kind};
use super::features::Context;
use super::lsq::{self, dot};
use super::selection::{Options, Term};

/// ΔBIC by which a replacement must beat the term it replaces ("positive" evidence).
pub const MIN_GAIN_BIC: f64 = 6.0;

/// Replacement candidates (best single gains) tried per accepted term, each alone and with the
/// best second candidate.
const TOP_REPLACEMENTS: usize = 4;

/// An exchange under consideration: BIC improvement, the term replaced, the new (candidate, θ).
type Choice = (f64, usize, Vec<(Candidate, f64)>);

/// The best exchange found: replace `terms[k]` with these terms (one or two).
#[derive(Debug)]
pub struct Exchange {
    pub k: usize,
    pub terms: Vec<Term>,
}

/// Columns: intercept plus every accepted term except `skip`.
fn others(terms: &[Term], skip: usize, n: usize) -> Vec<Vec<f64>> {
    let mut v = vec![vec![1.0; n]];
    for (j, t) in terms.iter().enumerate() {
        if j != skip {
            v.extend(t.cols.iter().cloned());
        }
    }
    v
}

fn gain(
    ctx: &Context,
    c: &Candidate,
    th: f64,
    basis: &[Vec<f64>],
    r0: &[f64],
) -> Option<(f64, usize)> {
    gain_cols(c, c.columns(ctx, th), basis, r0).0
}

/// [`gain`] of columns already built (the grid sweep's).
fn gain_cols(
    c: &Candidate,
    cols: Vec<Vec<f64>>,
    basis: &[Vec<f64>],
    r0: &[f64],
) -> (Option<(f64, usize)>, Vec<Vec<f64>>) {
    let u = lsq::orthonormalize(basis, cols, 1);
    let g = (!u.is_empty()).then(|| (lsq::gain(&u, r0), u.len() + usize::from(c.is_nonlinear())));
    (g, u)
}

/// Held-out RMS of the model made of a set of (candidate, θ) (and a constant).
pub type HeldOut<'a> = dyn Fn(&[(&Candidate, f64)]) -> f64 + 'a;

/// Every term but `terms[k]`, as (candidate, θ).
fn kept(terms: &[Term], k: usize) -> Vec<(&Candidate, f64)> {
    terms
        .iter()
        .enumerate()
        .filter(|(j, _)| *j != k)
        .map(|(_, t)| (&t.cand, t.theta))
        .collect()
}

/// Look for the best exchange: replace `terms[k]` by a candidate c, or by c plus one more
/// candidate d (the effect the old term had been absorbing). `n_eff` is the effective sample size
/// of the current residual; `tried` the number of candidate/grid pairs (Holm-corrected F-test);
/// `cv_now` the held-out RMS of the current set, `cv_of` the held-out RMS of a column set.
#[allow(clippy::too_many_arguments)]
pub fn best_exchange(
    ctx: &Context,
    r: &[f64],
    lib: &[Candidate],
    terms: &[Term],
    n_eff: f64,
    tried: usize,
    opts: &Options,
    cv_now: f64,
    cv_of: &HeldOut<'_>,
) -> Option<Exchange> {
    let (_, k, set) = best_choice(ctx, r, lib, terms, n_eff)?;
    if terms.len() - 1 + set.len() > opts.max_terms {
        return None;
    }
    let bar = Bar { n_eff, tried, opts };
    let out = confirmed(ctx, r, terms, k, &set, &bar, cv_of)?;
    let mut all = kept(terms, k);
    all.extend(set.iter().map(|(c, th)| (c, *th)));
    let cv_after = cv_of(&all);
    if cv_after.is_nan() || cv_after > cv_now {
        return None;
    }
    Some(Exchange { k, terms: out })
}

/// The exchange that improves BIC most: for each term k, the best single replacement among the
/// TOP_REPLACEMENTS strongest candidates on the others' residual, and the best pair starting
/// with one of them; `None` when none gains MIN_GAIN_BIC.
fn best_choice(
    ctx: &Context,
    r: &[f64],
    lib: &[Candidate],
    terms: &[Term],
    n_eff: f64,
) -> Option<Choice> {
    let n = r.len();
    let ln_n = n_eff.ln();
    // The two cyclic forms are one slot (one fundamental per signal).
    let same_slot =
        |a: &Candidate, b: &Candidate| a.kind == b.kind || (a.is_cyclic() && b.is_cyclic());
    // The exchange undoes a wrong early choice among forms of physics; a cyclic error's second
    // harmonic (two more columns) is a refinement forward selection adds, not a replacement: on
    // a 36-row laser table it replaced the reversal profile by fitting the positions' noise.
    let taken = |c: &Candidate| {
        c.kind == Kind::CyclicHarmonic
            || terms
                .iter()
                .any(|t| same_slot(&t.cand, c) && t.cand.axis == c.axis)
    };
    // Best grid value of candidate c on `basis` (residual r0): (gain, q, θ). The grid is swept
    // as forward selection screens it (`Candidate::par_sweep_map`: a cyclic candidate's sin/cos
    // rotated from the previous period instead of recomputed, 70 % of the exchange's time at 10⁵
    // rows); on equal gains the last θ wins, as `max_by` picked it.
    let best_of = |c: &Candidate, basis: &[Vec<f64>], r0: &[f64]| {
        let thetas: Vec<f64> = if c.grid.is_empty() {
            vec![f64::NAN]
        } else {
            c.grid.clone()
        };
        let mut best: Option<(f64, usize, f64)> = None;
        let scores = c.par_sweep_map(ctx, &thetas, |_, cols| gain_cols(c, cols, basis, r0));
        for (&th, scored) in thetas.iter().zip(scores) {
            if let Some((g, q)) = scored
                && best.is_none_or(|b| g.total_cmp(&b.0).is_ge())
            {
                best = Some((g, q, th));
            }
        }
        best
    };
    // (improvement in BIC, k, [(cand, θ)]).
    let mut best: Option<Choice> = None;
    for k in 0..terms.len() {
        let mut basis = lsq::orthonormalize(&[], others(terms, k, n), 2);
        let r0 = lsq::deflate(&basis, r);
        let rss0 = dot(&r0, &r0);
        if rss0.is_nan() || rss0 <= 0.0 {
            continue;
        }
        let Some((g_cur, q_cur)) = gain(ctx, &terms[k].cand, terms[k].theta, &basis, &r0) else {
            continue;
        };
        let rss_cur = rss0 - g_cur;
        // Candidates profiled in parallel, collected in library order (rayon's `collect` keeps
        // it): the same exchange with any number of threads.
        let mut singles: Vec<(f64, usize, f64, &Candidate)> = lib
            .par_iter()
            .filter(|c| !taken(c))
            .filter_map(|c| best_of(c, &basis, &r0).map(|(g, q, th)| (g, q, th, c)))
            .collect();
        singles.sort_by(|a, b| b.0.total_cmp(&a.0));
        for &(g_c, q_c, th_c, c) in singles.iter().take(TOP_REPLACEMENTS) {
            let score = |rss_new: f64, q: usize| {
                n_eff * (rss_cur / rss_new.max(1e-300)).ln() - (q as f64 - q_cur as f64) * ln_n
            };
            let mut consider = |imp: f64, set: Vec<(Candidate, f64)>| {
                if imp >= MIN_GAIN_BIC && best.as_ref().is_none_or(|b| imp > b.0) {
                    best = Some((imp, k, set));
                }
            };
            consider(score(rss0 - g_c, q_c), vec![(c.clone(), th_c)]);
            // c's orthonormalised columns go onto the basis in place and come off after: a copy
            // of the basis was the largest allocation of a 1M-row diagnosis (9 columns, 75 MB).
            let m = basis.len();
            let u = lsq::orthonormalize(&basis, c.columns(ctx, th_c), 1);
            basis.extend(u);
            let r1 = lsq::deflate(&basis, r);
            let seconds: Vec<(&Candidate, (f64, usize, f64))> = lib
                .par_iter()
                .filter(|d| !taken(d) && !same_slot(d, c))
                .filter_map(|d| best_of(d, &basis, &r1).map(|b| (d, b)))
                .collect();
            for (d, (g_d, q_d, th_d)) in seconds {
                consider(
                    score(rss0 - g_c - g_d, q_c + q_d),
                    vec![(c.clone(), th_c), (d.clone(), th_d)],
                );
            }
            basis.truncate(m);
        }
    }
    best
}

/// The forward bar of selection (ΔBIC, Holm-corrected F-test on n_eff).
struct Bar<'a> {
    n_eff: f64,
    tried: usize,
    opts: &'a Options,
}

/// The exchange's new terms, each tested as a partial term given all the others (the kept terms
/// and the rest of `set`); `None` when one fails the bar.
fn confirmed(
    ctx: &Context,
    r: &[f64],
    terms: &[Term],
    k: usize,
    set: &[(Candidate, f64)],
    bar: &Bar<'_>,
    cv_of: &HeldOut<'_>,
) -> Option<Vec<Term>> {
    let Bar { n_eff, tried, opts } = *bar;
    let n = r.len();
    let ln_n = n_eff.ln();
    // Every new term must pass the forward bar as a partial test given all the others.
    let new_cols: Vec<Vec<Vec<f64>>> = set.iter().map(|(c, th)| c.columns(ctx, *th)).collect();
    let mut out = vec![];
    for (i, (c, th)) in set.iter().enumerate() {
        // One copy of the other columns, consumed by the orthonormalisation (a kept base and
        // two clones of it were 3 × 75 MB on a 1M-row recording).
        let mut rest = others(terms, k, n);
        for (j, cols) in new_cols.iter().enumerate() {
            if j != i {
                rest.extend(cols.iter().cloned());
            }
        }
        let rest_len = rest.len();
        let basis = lsq::orthonormalize(&[], rest, 2);
        let r0 = lsq::deflate(&basis, r);
        let rss0 = dot(&r0, &r0);
        let (g, q) = gain(ctx, c, *th, &basis, &r0)?;
        let delta_bic = n_eff * (rss0 / (rss0 - g).max(1e-300)).ln() - q as f64 * ln_n;
        let df2 = n_eff - rest_len as f64 - q as f64;
        let p_value = if df2 >= 1.0 {
            let f = (g / q as f64) / ((rss0 - g) / df2);
            FisherSnedecor::new(q as f64, df2).map_or(1.0, |d| d.sf(f))
        } else {
            1.0
        };
        if !(delta_bic > opts.min_delta_bic && p_value * (tried as f64) < opts.alpha) {
            return None;
        }
        // The same set as (candidate, θ) for the held-out score.
        let mut rest_set: Vec<(&Candidate, f64)> = kept(terms, k);
        rest_set.extend(
            set.iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, (c, th))| (c, *th)),
        );
        let cv_without = cv_of(&rest_set);
        rest_set.push((c, *th));
        let cv_after = cv_of(&rest_set);
        out.push(Term {
            cand: c.clone(),
            theta: *th,
            cols: new_cols[i].clone(),
            delta_bic,
            p_value,
            gain_rss: g,
            rms_after_um: ((rss0 - g) / n as f64).sqrt(),
            heldout_rms_before_um: cv_without,
            heldout_rms_after_um: cv_after,
            ambiguous_with: vec![],
            within_cells: false,
        });
    }
    Some(out)
}
