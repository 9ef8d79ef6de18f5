//! A selection step's screening: every unused candidate profiled over its grid against the step's
//! nulls ([`Selector::screen`]), and where it screens a cyclic error's harmonic form (fundamental + second harmonic,
//! four columns): at the peaks of its fundamental's periodogram, not over the whole period grid.
//! The form at period P fits the fundamental at P and its harmonic at P/2, so it explains much only
//! where the fundamental's periodogram has a peak at P or at P/2; sweeping the whole grid with four
//! columns was two thirds of a 1M-row diagnosis' screening. Periods mm.

use super::super::candidates::{Candidate, Kind};
use super::super::null_model::{pair_by_sums, pair_scored, score_cols, within_cells};
use super::{Nulls, Scored, Selector};

/// Fundamental peaks whose neighbourhoods (and their doubled periods) the harmonic form is
/// screened at, strongest first.
const PEAKS: usize = 4;

impl Selector<'_> {
    /// Profile every unused candidate over its grid (best θ by RSS drop: q is fixed within a
    /// candidate), under the plain null and, for the reversal family, within cells. Candidates
    /// are screened in parallel (rayon) and collected in library order, each candidate's grid
    /// swept in fixed chunks in parallel and read in grid order ([`Candidate::par_sweep_map`]),
    /// so the result is the same with any number of threads. The
    /// harmonic forms of cyclic errors are screened after the others, at the peaks of their
    /// fundamental's periodogram ([`peak_thetas`]).
    pub(super) fn screen(&self, nulls: &Nulls<'_>) -> Vec<Scored> {
        use rayon::prelude::*;
        let harmonic = |c: &Candidate| c.kind == Kind::CyclicHarmonic;
        let first: Vec<(Vec<Scored>, Option<Vec<f64>>)> = self
            .lib
            .par_iter()
            .enumerate()
            .map(|(idx, c)| {
                if self.used[idx] || harmonic(c) {
                    return (vec![], None);
                }
                let thetas = if c.grid.is_empty() {
                    vec![f64::NAN]
                } else {
                    c.grid.clone()
                };
                self.screen_one(idx, c, &thetas, nulls, c.kind == Kind::Cyclic)
            })
            .collect();
        let second: Vec<Vec<Scored>> = self
            .lib
            .par_iter()
            .enumerate()
            .map(|(idx, c)| {
                if self.used[idx] || !harmonic(c) {
                    return vec![];
                }
                let curve = self.fundamental_curve(c, &first, nulls);
                let thetas = peak_thetas(&c.grid, &curve);
                self.screen_one(idx, c, &thetas, nulls, false).0
            })
            .collect();
        first
            .into_iter()
            .zip(second)
            .flat_map(|((a, _), b)| a.into_iter().chain(b))
            .collect()
    }

    /// Candidate `c` (library index `idx`) profiled over `thetas`: its best θ under the plain
    /// null and, for the reversal family, within cells; with `keep_curve`, the plain null's gain
    /// at every θ (−∞ where it explains nothing), the periodogram of a cyclic candidate.
    pub(super) fn screen_one(
        &self,
        idx: usize,
        c: &Candidate,
        thetas: &[f64],
        nulls: &Nulls<'_>,
        keep_curve: bool,
    ) -> (Vec<Scored>, Option<Vec<f64>>) {
        let mut out = vec![];
        let mut curve = keep_curve.then(|| Vec::with_capacity(thetas.len()));
        for blocked in [false, true] {
            if blocked && !(nulls.cells_ok && within_cells(c)) {
                continue;
            }
            let nl = nulls.of(blocked);
            let mut best: Option<Scored> = None;
            // A cyclic pair on a long recording: every period of a chunk in one pass over the
            // rows (the same bits as one period at a time).
            let swept = pair_by_sums(c, nl)
                .then(|| c.par_sweep_gram_gains(self.ctx, thetas, &nl.basis, &nl.r0))
                .flatten();
            let scores = match swept {
                Some(gains) => gains.into_iter().map(|gq| pair_scored(c, nl, gq)).collect(),
                None => c.par_sweep_map(self.ctx, thetas, |_, cols| score_cols(c, cols, nl)),
            };
            for (&th, scored) in thetas.iter().zip(scores) {
                if !blocked && let Some(curve) = curve.as_mut() {
                    curve.push(scored.map_or(f64::NEG_INFINITY, |s| s.0));
                }
                if let Some((g, q)) = scored
                    && best.as_ref().is_none_or(|b| g > b.gain)
                {
                    best = Some(Scored {
                        idx,
                        theta: th,
                        gain: g,
                        q,
                        delta_bic: 0.0,
                        cells: blocked,
                    });
                }
            }
            out.extend(best);
        }
        (out, curve)
    }

    /// The plain null's periodogram (gain per grid period) of `harmonic`'s fundamental: the
    /// library's `Cyclic` candidate on the same axis and grid, from this step's first screening
    /// pass, or swept here when that candidate was not screened.
    pub(super) fn fundamental_curve(
        &self,
        harmonic: &Candidate,
        first: &[(Vec<Scored>, Option<Vec<f64>>)],
        nulls: &Nulls<'_>,
    ) -> Vec<f64> {
        let twin = self.lib.iter().position(|d| {
            d.kind == Kind::Cyclic && d.axis == harmonic.axis && d.grid == harmonic.grid
        });
        if let Some(curve) = twin.and_then(|j| first[j].1.clone()) {
            return curve;
        }
        let fundamental = Candidate {
            kind: Kind::Cyclic,
            ..harmonic.clone()
        };
        let idx = twin.unwrap_or(usize::MAX);
        self.screen_one(idx, &fundamental, &harmonic.grid, nulls, true)
            .1
            .unwrap_or_default()
    }
}

/// The grid periods (ascending, a subset of `grid`) to screen a harmonic form at: around each of
/// the [`PEAKS`] strongest local maxima P of the fundamental's `curve` (gain per period of the
/// ascending `grid`), P's grid neighbours and the grid periods around 2P (where P is the harmonic).
pub(super) fn peak_thetas(grid: &[f64], curve: &[f64]) -> Vec<f64> {
    let n = grid.len().min(curve.len());
    let mut peaks: Vec<usize> = (0..n)
        .filter(|&k| {
            curve[k].is_finite()
                && (k == 0 || curve[k] >= curve[k - 1])
                && (k + 1 == n || curve[k] >= curve[k + 1])
        })
        .collect();
    // Strongest first; equal gains keep grid order (a stable sort: the same with any threads).
    peaks.sort_by(|&a, &b| curve[b].total_cmp(&curve[a]));
    let mut at: Vec<usize> = vec![];
    let around = |k: usize, at: &mut Vec<usize>| {
        at.extend(k.saturating_sub(1)..=(k + 1).min(n - 1));
    };
    for &k in peaks.iter().take(PEAKS) {
        around(k, &mut at);
        let m = grid[..n].partition_point(|&p| p < 2.0 * grid[k]);
        if m < n {
            around(m, &mut at);
        }
    }
    at.sort_unstable();
    at.dedup();
    at.into_iter().map(|k| grid[k]).collect()
}

#[cfg(test)]
mod tests {
    use super::peak_thetas;

    #[test]
    fn a_peak_and_its_doubled_period_are_screened() {
        let grid: Vec<f64> = (0..40).map(|k| 2.0 + 0.5 * f64::from(k)).collect();
        // One peak at 5.0 mm (index 6); its double, 10.0 mm, is index 16.
        let curve: Vec<f64> = grid.iter().map(|p| -((p - 5.0) * (p - 5.0))).collect();
        let at = peak_thetas(&grid, &curve);
        assert_eq!(at, vec![4.5, 5.0, 5.5, 9.5, 10.0, 10.5]);
    }

    #[test]
    fn no_finite_gain_screens_nothing() {
        let grid = [2.0, 3.0, 4.0];
        assert!(peak_thetas(&grid, &[f64::NEG_INFINITY; 3]).is_empty());
    }
}
