//! The slow-noise side of a selection step ([`Selector`]): the residual the step's strongest
//! candidate leaves, the step's effective sample size and error model (`NoiseModel`), and the
//! unit-root statistics a signal gives before any term, from which the recording's noise type is
//! decided once (`null_model::recording_rejects_unit_root`). Residuals µm (measured − sim).

use super::super::lsq::{self, dot};
use super::super::null_model::{NoiseModel, adf_lags, adf_tau, contribution, without_cell_means};
use super::{FirstScreen, Nulls, Scored, Selector};

impl Selector<'_> {
    /// The residual the step's strongest candidate (the largest share of its null's RSS) leaves,
    /// cell means removed.
    fn top_noise(&self, scored: &[Scored], nulls: &Nulls<'_>) -> Vec<f64> {
        let (ctx, axis, r0) = (self.ctx, self.axis, &nulls.plain.r0);
        let share = |s: &Scored| s.gain / nulls.of(s.cells).rss0;
        let top = scored
            .iter()
            .max_by(|a, b| share(a).total_cmp(&share(b)))
            .expect("non-empty");
        let top_contrib = contribution(ctx, &self.lib[top.idx], top.theta, &self.basis, r0);
        let r1_top: Vec<f64> = r0.iter().zip(&top_contrib).map(|(a, b)| a - b).collect();
        without_cell_means(ctx, axis, &r1_top)
    }

    /// One effective sample size for the whole step (from the residual left by the candidate that
    /// explains the largest share of its null's RSS), so candidates are ranked on the same scale;
    /// and the error model of the prewhitened test, once per step (see `NoiseModel`).
    pub(super) fn scale(&self, scored: &[Scored], nulls: &Nulls<'_>) -> (f64, Option<NoiseModel>) {
        let noise_top = self.top_noise(scored, nulls);
        let n_eff = lsq::effective_n(&noise_top);
        let noise_model = (!self.heldout.forward).then(|| {
            NoiseModel::of(
                &without_cell_means(self.ctx, self.axis, &nulls.plain.r0),
                &noise_top,
                self.recording_rejects,
            )
        });
        (n_eff, noise_model)
    }

    /// This signal's unit-root statistics before any term: ADF τ of its residual, and of the
    /// residual its first step's strongest candidate leaves (cell means removed), with that
    /// step's screening for selection to reuse; `None` where the slow-noise model is not used
    /// (forward validation) or there is nothing to screen.
    pub(in crate::diagnose) fn unit_root_taus(&self) -> Option<((f64, f64), FirstScreen)> {
        let r0 = lsq::deflate(&self.basis, self.r);
        let rss0 = dot(&r0, &r0);
        if self.heldout.forward || rss0.is_nan() || rss0 <= 0.0 {
            return None;
        }
        let nulls = self.nulls(r0, rss0);
        let scored = self.screen(&nulls);
        if scored.is_empty() {
            return None;
        }
        // Each residual and each statistic is computed alone, side by side: the same bits with
        // any number of threads.
        let (null_noise, alt_noise) = rayon::join(
            || without_cell_means(self.ctx, self.axis, &nulls.plain.r0),
            || self.top_noise(&scored, &nulls),
        );
        let lags = adf_lags(null_noise.len());
        let taus = rayon::join(|| adf_tau(&null_noise, lags), || adf_tau(&alt_noise, lags));
        Some((taus, FirstScreen(scored)))
    }
}
