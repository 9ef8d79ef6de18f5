//! Refinement of a selection step's nonlinear parameters ([`Selector`]): the winner's between
//! its grid neighbours, and every cyclic candidate's periodogram peak before the step's ranking.

use super::super::null_model::{Null, delta_bic, golden_refine, score};
use super::{Nulls, Scored, Selector};

impl Scored {
    /// A value to swap out while a scored entry is refined in place.
    fn placeholder() -> Self {
        Scored {
            idx: 0,
            theta: f64::NAN,
            gain: 0.0,
            q: 0,
            delta_bic: 0.0,
            cells: false,
        }
    }
}

impl Selector<'_> {
    /// The periodogram's peaks are compared at their refined periods: a cyclic error with its
    /// second harmonic at twice a pure period P would otherwise beat the single period on the
    /// grid's discretisation alone (its harmonic samples frequency twice as finely). Peaks below
    /// the ΔBIC bar keep their grid value.
    pub(super) fn refine_cyclic_peaks(&self, scored: &mut [Scored], nulls: &Nulls<'_>, n_eff: f64) {
        // Only peaks that pass the bar can win; the others are not worth their evaluations (each
        // is a sin/cos per distinct position and a projection over every row).
        // Each peak is refined on its own (in parallel: one peak's refinement at 1M rows is ≈ 20
        // sweeps of every row), so the result is the same with any number of threads.
        use rayon::prelude::*;
        let bar = self.opts.min_delta_bic;
        scored
            .par_iter_mut()
            .filter(|s| self.lib[s.idx].is_cyclic() && s.delta_bic > bar)
            .for_each(|s| {
                let nl = nulls.of(s.cells);
                *s = self.refine(std::mem::replace(s, Scored::placeholder()), nl, n_eff);
            });
    }

    /// Refine the winner's nonlinear parameter between its grid neighbours (golden section on
    /// the profile RSS drop); kept when it does not explain less.
    #[allow(
        clippy::float_cmp,
        reason = "the winner's θ is copied from the grid, so on-grid means bit-equal"
    )]
    pub(super) fn refine(&self, win: Scored, nl: &Null<'_>, n_eff: f64) -> Scored {
        let cand = &self.lib[win.idx];
        if !cand.is_nonlinear() {
            return win;
        }
        let g = &cand.grid;
        // Off the grid: refined already (cyclic peaks are refined before ranking).
        let Some(i) = g.iter().position(|&v| v == win.theta) else {
            return win;
        };
        let lo = g[i.saturating_sub(1)];
        let hi = g[(i + 1).min(g.len() - 1)];
        if hi <= lo {
            return win;
        }
        let ctx = self.ctx;
        let th = golden_refine(
            |t| score(ctx, cand, t, nl).map_or(f64::NEG_INFINITY, |s| s.0),
            lo,
            hi,
            18,
        );
        match score(ctx, cand, th, nl) {
            Some((g2, q)) if g2 >= win.gain => Scored {
                idx: win.idx,
                theta: th,
                gain: g2,
                q,
                delta_bic: delta_bic(n_eff, nl.rss0, g2, q),
                cells: win.cells,
            },
            _ => win,
        }
    }
}
