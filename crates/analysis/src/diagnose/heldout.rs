//! The held-out error of a set of terms on one residual signal r = measured − sim (µm): what a
//! term must improve to be accepted ([`super::select`]) and what its removal must hurt to stay
//! after the final joint refit (parsimony, [`super::diagnose_with_sim`]). One definition for both.
//!
//! Folds that follow time (contiguous time blocks, or `run` blocks in recording order, each kept
//! whole) on recordings with no axis column (thermal tests) are validated FORWARD (rolling
//! origin): block k is predicted from the fit on blocks 0…k−1 only, scored the two ways a later
//! recording may be fed to `retrocomp eval` — with the history before it (lag states carried) and
//! alone (every first-order lag restarted at steady state on the block's first row, as `eval`
//! starts a new file: [`restarted`]); the held-out RMS is the root of the mean of both mean
//! squares. Elsewhere (interleaved position-cell folds of a forward + reverse laser run, and for
//! now every recording with axis columns) leave-one-block-out. Gains are µm per the column's unit.
//!
//! **The simulation's own forward error** (issue 12 point 7, cause 1 in docs/diagnose.md): when
//! the simulation is a machine model (`diagnose --model`), its thermal inputs (each sensor state it
//! reads: [`super::model_sim::regressors`]) are given here, and with `Options::refit_sim` (off by
//! default: it did not help on FL_THERMAL, docs/diagnose.md) the forward score refits the
//! simulation's gains inside each fold too, two-stage as the written model is built: on blocks
//! 0…k−1 the residual is regressed on the simulation's inputs (its gains refitted there), the
//! terms on what is left; block k is predicted by both. A simulation fitted on every row of the fit
//! file (a static regression) otherwise never shows its extrapolation error to later blocks: its
//! in-sample residual has it removed from every block. [`Heldout::rms`] is that score;
//! [`Heldout::rms_in_sample`] keeps the simulation as given (the score without the inputs).

use std::borrow::Cow;

use super::candidates::{Candidate, Kind};
use super::features::Context;
use super::lsq;
use super::selection::Options;

/// The validation folds of one signal and how they are scored.
#[derive(Debug)]
pub(super) struct Heldout<'a> {
    ctx: &'a Context,
    r: &'a [f64],
    /// The simulation's inputs, refitted per forward fold when `Options::refit_sim` (else empty:
    /// the simulation as given).
    sim: &'a [Vec<f64>],
    block: Vec<usize>,
    n_blocks: usize,
    /// Rolling-origin (forward) validation, else leave-one-block-out.
    pub forward: bool,
    /// First block predicted in forward validation (1: every origin is scored). Scoring only
    /// origins with half the record behind them (n_blocks / 2) was tried on FL_THERMAL's emulated
    /// judge and made a channel worse (d3 at 70 %: −38 %), so it is not used (docs/diagnose.md).
    first: usize,
}

impl<'a> Heldout<'a> {
    /// The folds of signal `axis`'s residual `r`: `opts.forward_blocks` time blocks on thermal
    /// tests (no axis column), else `opts.cv_blocks` (or the `run` blocks, or position cells:
    /// [`Context::blocks_for`]).
    pub(super) fn new(
        ctx: &'a Context,
        axis: char,
        r: &'a [f64],
        sim: &'a [Vec<f64>],
        opts: &Options,
    ) -> Self {
        let thermal_only = ctx.axes.iter().all(Option::is_none);
        let (block, n_blocks) = ctx.blocks_for(
            axis,
            if thermal_only {
                opts.forward_blocks
            } else {
                opts.cv_blocks
            },
        );
        // Restricted for now to recordings with no axis column: on the generated motion cases,
        // forward folds reject real thermal lags whose warm-up fills the first block (hil-sim
        // hil-sim's cases/model_out.rs, case 14); they keep leave-one-block-out until that is resolved.
        let forward = n_blocks >= 3 && thermal_only && block.windows(2).all(|w| w[1] >= w[0]);
        Heldout {
            ctx,
            r,
            sim: if opts.refit_sim { sim } else { &[] },
            block,
            n_blocks,
            forward,
            first: 1,
        }
    }

    /// Intercept + the terms' columns, per row.
    fn columns(&self, set: &[(&Candidate, f64)]) -> Vec<Vec<f64>> {
        let mut cols = vec![vec![1.0; self.r.len()]];
        for (c, th) in set {
            cols.extend(c.columns(self.ctx, *th));
        }
        cols
    }

    /// The simulation's inputs are refitted per forward fold ([`Heldout`]'s top comment).
    pub(super) fn refits_sim(&self) -> bool {
        self.forward && !self.sim.is_empty()
    }

    /// Held-out RMS (µm) of the intercept plus `set` (candidate, nonlinear parameter); forward
    /// with the simulation's gains refitted per fold when its inputs are known.
    pub(super) fn rms(&self, set: &[(&Candidate, f64)]) -> f64 {
        self.score(set, self.refits_sim())
    }

    /// [`Heldout::rms`] with the simulation as given (fitted on every row, not refitted per fold).
    pub(super) fn rms_in_sample(&self, set: &[(&Candidate, f64)]) -> f64 {
        self.score(set, false)
    }

    fn score(&self, set: &[(&Candidate, f64)], refit_sim: bool) -> f64 {
        let cols = self.columns(set);
        let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
        if !self.forward {
            let n = self.r.len();
            return (lsq::cv_rss(&refs, self.r, &self.block, self.n_blocks) / n as f64).sqrt();
        }
        // Borrowed where nothing restarts (a copy of every column was the peak of a 10⁶-row run).
        let mut pred: Vec<Cow<'_, [f64]>> = vec![Cow::Borrowed(&cols[0])];
        let mut j = 1;
        for (c, th) in set {
            let q = c.columns(self.ctx, *th).len();
            pred.extend(restarted(self.ctx, c, *th, &cols[j..j + q], &self.block));
            j += q;
        }
        let prefs: Vec<&[f64]> = pred.iter().map(|c| &**c).collect();
        let (carried, fresh) = if refit_sim {
            let mut s: Vec<&[f64]> = vec![&cols[0]];
            s.extend(self.sim.iter().map(Vec::as_slice));
            let two =
                |p: &[&[f64]]| two_stage_rss(&s, &refs, p, self.r, &self.block, self.n_blocks);
            (two(&refs), two(&prefs))
        } else {
            (
                lsq::forward_block_rss(&refs, &refs, self.r, &self.block, self.n_blocks),
                lsq::forward_block_rss(&refs, &prefs, self.r, &self.block, self.n_blocks),
            )
        };
        let (rss, m) = carried
            .iter()
            .zip(&fresh)
            .skip(self.first)
            .fold((0.0, 0), |(s, m), (h, a)| (s + (h.0 + a.0) / 2.0, m + h.1));
        (rss / m.max(1) as f64).sqrt()
    }
}

/// Per block k ≥ 1: (RSS, rows) of the two-stage forward prediction. On blocks 0…k−1, `r` is
/// regressed on the simulation's inputs `s` (intercept first: its gains' correction γ), then what is
/// left, r − s·γ, on the terms' columns `x` (intercept first: β); block k is predicted as
/// s·γ + pred·β. Block 0 has no fit before it: (0, 0).
fn two_stage_rss(
    s: &[&[f64]],
    x: &[&[f64]],
    pred: &[&[f64]],
    r: &[f64],
    block: &[usize],
    n_blocks: usize,
) -> Vec<(f64, usize)> {
    use nalgebra::{DMatrix, DVector};
    let (ps, px) = (s.len(), x.len());
    // Per block: Gram of [s | x] and its products with r.
    let p = ps + px;
    let mut per: Vec<(DMatrix<f64>, DVector<f64>)> = (0..n_blocks)
        .map(|_| (DMatrix::zeros(p, p), DVector::zeros(p)))
        .collect();
    let mut row = vec![0.0; p];
    for i in 0..r.len() {
        for (a, v) in row.iter_mut().enumerate() {
            *v = if a < ps { s[a][i] } else { x[a - ps][i] };
        }
        let (g, h) = &mut per[block[i]];
        for a in 0..p {
            h[a] += row[a] * r[i];
            for b in 0..p {
                g[(a, b)] += row[a] * row[b];
            }
        }
    }
    let solve = |g: DMatrix<f64>, h: DVector<f64>| -> DVector<f64> {
        let svd = g.svd(true, true);
        let eps = svd.singular_values.max() * 1e-12;
        let m = h.len();
        match svd.pseudo_inverse(eps) {
            Ok(inv) => inv * h,
            Err(_) => DVector::zeros(m),
        }
    };
    let mut coefs: Vec<Option<(DVector<f64>, DVector<f64>)>> = vec![None; n_blocks];
    let (mut g, mut h) = (DMatrix::<f64>::zeros(p, p), DVector::<f64>::zeros(p));
    for k in 0..n_blocks {
        if k > 0 {
            let gamma = solve(
                g.view((0, 0), (ps, ps)).into_owned(),
                h.rows(0, ps).into_owned(),
            );
            // x'(r − s·γ) = x'r − (x's)·γ.
            let hx = h.rows(ps, px) - g.view((ps, 0), (px, ps)) * &gamma;
            let beta = solve(g.view((ps, ps), (px, px)).into_owned(), hx);
            coefs[k] = Some((gamma, beta));
        }
        g += &per[k].0;
        h += &per[k].1;
    }
    let mut out = vec![(0.0, 0usize); n_blocks];
    for i in 0..r.len() {
        if let Some((gamma, beta)) = &coefs[block[i]] {
            let fit: f64 = (0..ps).map(|a| gamma[a] * s[a][i]).sum::<f64>()
                + (0..px).map(|a| beta[a] * pred[a][i]).sum::<f64>();
            out[block[i]].0 += (r[i] - fit).powi(2);
            out[block[i]].1 += 1;
        }
    }
    out
}

/// The columns of `c` as a NEW recording starting at each block would compute them: a first-order
/// lag restarts at its first reading there (steady state, as `retrocomp eval` starts every lag),
/// instead of carrying the state from the rows before. The reference (the fit's first reading)
/// stays: it is the model's `reference_C`. The filter is linear, so the restarted lag differs from
/// the carried one by the start-up difference decaying as e^(−(t − t_start)/τ). Columns of every
/// other candidate have no state and are returned as they are (borrowed).
pub fn restarted<'c>(
    ctx: &Context,
    c: &Candidate,
    tau_s: f64,
    cols: &'c [Vec<f64>],
    block: &[usize],
) -> Vec<Cow<'c, [f64]>> {
    let as_they_are = || cols.iter().map(|c| Cow::Borrowed(&c[..])).collect();
    let (Kind::ThermalLag { sensor }, Some(y)) = (&c.kind, cols.first()) else {
        return as_they_are();
    };
    let Some(u) = ctx.temp(sensor) else {
        return as_they_are();
    };
    let mut start = 0;
    vec![Cow::Owned(
        (0..y.len())
            .map(|i| {
                if i > 0 && block[i] != block[i - 1] {
                    start = i;
                }
                // Column = LPF(u) − u(0): restarted state u(start) − u(0) against the carried y(start).
                let d0 = (u[start] - u[0]) - y[start];
                y[i] + d0 * (-(ctx.t_s[i] - ctx.t_s[start]) / tau_s).exp()
            })
            .collect::<Vec<f64>>(),
    )]
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_model::recording::Recording;

    #[test]
    fn refitting_the_simulation_per_fold_charges_its_gain_error_only_when_asked() {
        // A simulation with the wrong gain on its input s (residual r = 2·s + a small ripple):
        // with its inputs refitted per fold the forward error of "no term" is the ripple; as
        // given, it is the gain error extrapolated to later blocks.
        let n = 2000;
        let t: Vec<f64> = (0..n).map(|i| 15.0 * i as f64).collect();
        let s: Vec<f64> = (0..n).map(|i| 0.005 * i as f64).collect();
        let r: Vec<f64> = (0..n)
            .map(|i| 2.0 * s[i] + 0.1 * (i as f64 * 0.37).sin())
            .collect();
        let rec = Recording::from_columns(vec![
            ("t_s".into(), t),
            ("T_a_C".into(), s.clone()),
            ("ez_um".into(), vec![0.0; n]),
        ])
        .unwrap();
        let ctx = Context::from_recording(&rec);
        let sim = vec![s];
        let on = Options {
            refit_sim: true,
            ..Options::default()
        };
        let h = Heldout::new(&ctx, 'z', &r, &sim, &on);
        assert!(h.forward && h.refits_sim());
        let (refit, given) = (h.rms(&[]), h.rms_in_sample(&[]));
        assert!(refit < 0.2 && given > 2.0, "refit {refit}, given {given}");
        let off = Heldout::new(&ctx, 'z', &r, &sim, &Options::default());
        assert!(!off.refits_sim());
        assert_eq!(off.rms(&[]), given);
    }
}
