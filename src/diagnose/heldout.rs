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

use super::candidates::{Candidate, Kind};
use super::features::Context;
use super::lsq;
use super::select::Options;

/// The validation folds of one signal and how they are scored.
#[derive(Debug)]
pub struct Heldout<'a> {
    ctx: &'a Context,
    r: &'a [f64],
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
    pub fn new(ctx: &'a Context, axis: char, r: &'a [f64], opts: &Options) -> Self {
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
        // cases_model_out case 14); they keep leave-one-block-out until that is resolved.
        let forward = n_blocks >= 3 && thermal_only && block.windows(2).all(|w| w[1] >= w[0]);
        Heldout {
            ctx,
            r,
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

    /// Held-out RMS (µm) of the intercept plus `set` (candidate, nonlinear parameter).
    pub fn rms(&self, set: &[(&Candidate, f64)]) -> f64 {
        let cols = self.columns(set);
        let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
        if !self.forward {
            let n = self.r.len();
            return (lsq::cv_rss(&refs, self.r, &self.block, self.n_blocks) / n as f64).sqrt();
        }
        let mut pred = vec![cols[0].clone()];
        let mut j = 1;
        for (c, th) in set {
            let q = c.columns(self.ctx, *th).len();
            pred.extend(restarted(self.ctx, c, *th, &cols[j..j + q], &self.block));
            j += q;
        }
        let prefs: Vec<&[f64]> = pred.iter().map(Vec::as_slice).collect();
        let carried = lsq::forward_block_rss(&refs, &refs, self.r, &self.block, self.n_blocks);
        let fresh = lsq::forward_block_rss(&refs, &prefs, self.r, &self.block, self.n_blocks);
        let (rss, m) = carried
            .iter()
            .zip(&fresh)
            .skip(self.first)
            .fold((0.0, 0), |(s, m), (h, a)| (s + (h.0 + a.0) / 2.0, m + h.1));
        (rss / m.max(1) as f64).sqrt()
    }
}

/// The columns of `c` as a NEW recording starting at each block would compute them: a first-order
/// lag restarts at its first reading there (steady state, as `retrocomp eval` starts every lag),
/// instead of carrying the state from the rows before. The reference (the fit's first reading)
/// stays: it is the model's `reference_C`. The filter is linear, so the restarted lag differs from
/// the carried one by the start-up difference decaying as e^(−(t − t_start)/τ). Columns of every
/// other candidate have no state and are returned as they are.
pub fn restarted(
    ctx: &Context,
    c: &Candidate,
    tau_s: f64,
    cols: &[Vec<f64>],
    block: &[usize],
) -> Vec<Vec<f64>> {
    let (Kind::ThermalLag { sensor }, Some(y)) = (&c.kind, cols.first()) else {
        return cols.to_vec();
    };
    let Some(u) = ctx.temp(sensor) else {
        return cols.to_vec();
    };
    let mut start = 0;
    vec![
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
    ]
}
