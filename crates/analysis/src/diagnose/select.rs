//! Forward selection of candidate terms for one residual signal r = measured − sim (µm).
//!
//! Each step: every candidate (at every grid value of its nonlinear parameter) is screened by the RSS
//! drop it gives on top of what is already fitted (score/ERR test via an orthonormal basis); the best
//! by ΔBIC is tested with an F-test whose p-value is multiplied by the number of (candidate, grid)
//! pairs tried (Holm's first step), both on the effective sample size of the AR(1) residual; its
//! nonlinear parameter is refined by golden-section on the profile RSS (linear gains solved inside:
//! variable projection); it is kept only if block cross-validation (leave one run / time block out,
//! or interleaved position cells for a forward + a reverse run: [`Context::blocks_for`]) improves.
//! On thermal-only recordings the blocks are validated forward (rolling origin), each later block
//! scored with lag states carried and restarted at its first row ([`restarted`]), as a new file
//! fed to `retrocomp eval` would start them.
//! Candidates of another family that explain the same residual almost as well and almost
//! collinearly are recorded as ambiguous alternatives.
//!
//! Backlash and reversal profile (functions of position and the latched approach direction only)
//! are screened and tested both as usual and WITHIN own-axis position cells — the cell means are
//! a nuisance in its null model, as in the two-way (position × direction) layout of an ISO 230-2
//! reversal value. Where both directions are read at a position, a direction-odd column is
//! orthogonal to every function of position alone, so an unmodelled positioning error (a shape no
//! candidate names) no longer counts as noise against a reversal. Where the directions are not
//! balanced within cells (one-way passes) the cells also absorb part of a real reversal, so the
//! better of the two nulls (by ΔBIC) is used and both count in the Holm correction (`tried`).
//! Every other candidate keeps the plain test (a reversal spike is not a
//! function of position and direction alone: the cell means near the reversal points would absorb
//! part of it).

use super::candidates::Candidate;
use super::features::Context;
use super::lsq;
use super::null_model::without_cell_means;
use super::select_step::Selector;

pub use super::select_step::FirstScreen;

pub use super::heldout::restarted;
pub use super::selection::{Alternative, Exchanged, Options, SignalSelection, Term, set_of};

/// Run forward selection on residual `r` of the signal of axis `axis`.
///
/// `sim_inputs`: the simulation's thermal inputs when it is a machine model (else empty); forward
/// validation then refits its gains per fold (`super::heldout::Heldout`), and a term is kept only if it improves
/// that score AND does not worsen the forward error against the simulation as given (the guard
/// below).
pub fn select(
    ctx: &Context,
    axis: char,
    r: &[f64],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
) -> SignalSelection {
    select_pooled(ctx, axis, r, sim_inputs, opts, None, None)
}

/// The unit-root statistics of one signal's residual `r` before any term (ADF τ of `r`, and of
/// what its first step's strongest candidate leaves: `null_model::recording_rejects_unit_root`),
/// with that first step's screening for [`select_pooled`] to reuse; `None` when the slow-noise
/// model does not apply (thermal-only recordings, validated forward) or nothing can be screened.
pub fn unit_root_taus(
    ctx: &Context,
    axis: char,
    r: &[f64],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
) -> Option<((f64, f64), FirstScreen)> {
    Selector::new(ctx, axis, r, sim_inputs, opts, None, None).unit_root_taus()
}

/// [`select`] with the recording's noise statistic: whether it rejects a unit root
/// (`null_model::recording_rejects_unit_root` over its signals' [`unit_root_taus`]; `None` for a
/// single signal), and the first step's screening that pre-pass did on this same `r`.
pub fn select_pooled(
    ctx: &Context,
    axis: char,
    r: &[f64],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
    recording_rejects: Option<bool>,
    first_screen: Option<FirstScreen>,
) -> SignalSelection {
    let mut s = Selector::new(
        ctx,
        axis,
        r,
        sim_inputs,
        opts,
        recording_rejects,
        first_screen,
    );
    loop {
        while s.terms.len() < opts.max_terms && r.len() > s.n_raw + 3 {
            let step = s.terms.len() + 1;
            super::progress::stage(|| format!("e{axis}_um: selection step {step}"));
            if !s.step() {
                break;
            }
        }
        // Exchange step (swap.rs), then forward selection again; at most two exchanges per signal.
        super::progress::stage(|| format!("e{axis}_um: exchange step"));
        if s.terms.is_empty() || s.exchanges >= 2 || !s.exchange() {
            break;
        }
    }
    SignalSelection {
        axis,
        n: r.len(),
        terms: s.terms,
        runners_up: s.runners_up,
        tried: s.tried,
        first_choice: s.first_choice,
        exchanged: s.exchanged,
    }
}

/// The exchange step after forward selection.
impl Selector<'_> {
    /// The exchange step (swap.rs): true when a term was exchanged (forward selection runs
    /// again).
    fn exchange(&mut self) -> bool {
        let (ctx, r, axis, n) = (self.ctx, self.r, self.axis, self.r.len());
        // The terms' own columns, borrowed (a copy of them was the peak of a 1M-row diagnosis).
        let ones = vec![1.0; n];
        let mut refs: Vec<&[f64]> = vec![&ones];
        for t in &self.terms {
            refs.extend(t.cols.iter().map(Vec::as_slice));
        }
        let resid = lsq::fit(&refs, r).resid;
        // Only where structure is left that no candidate explains (the same test as the report's
        // "unexplained structure"): a clean fit is not revisited, which keeps the cost where it helps.
        if super::locate::unexplained(ctx, &format!("e{axis}_um"), &resid).is_empty() {
            return false;
        }
        let n_eff = lsq::effective_n(&without_cell_means(ctx, axis, &resid));
        drop(resid);
        // The running basis is rebuilt after an exchange and not read without one: freed while
        // the exchange search builds its own (75 MB each on a 1M-row recording).
        drop(std::mem::take(&mut self.basis));
        let guard_before = self.guard_before;
        let Some(ex) = super::swap::best_exchange(
            ctx,
            r,
            &self.lib,
            &self.terms,
            n_eff,
            self.tried,
            self.opts,
            self.cv_before,
            // The same guard as a new term: an exchange must not worsen the forward error
            // against the simulation as given (on FL_THERMAL d2 at 50 % an unguarded exchange
            // brought in T_3 + T_16 + T_8 and made the later rows 51 % worse).
            &|set: &[(&Candidate, f64)]| {
                if self.guard_ok(set, guard_before) {
                    self.cv(set)
                } else {
                    f64::INFINITY
                }
            },
        ) else {
            return false;
        };
        self.exchanges += 1;
        let by = ex.terms.iter().map(|t| t.cand.label()).collect();
        let old = self.terms.remove(ex.k);
        self.terms.extend(ex.terms);
        let mut raw_cols = vec![vec![1.0; n]];
        for t in &self.terms {
            raw_cols.extend(t.cols.iter().cloned());
        }
        self.n_raw = raw_cols.len();
        self.basis = lsq::orthonormalize(&[], raw_cols, 2);
        let cv_after = self.cv(&set_of(&self.terms));
        self.exchanged.push(Exchanged {
            term: old,
            by,
            heldout_rms_before_um: self.cv_before,
            heldout_rms_after_um: cv_after,
        });
        self.cv_before = cv_after;
        self.guard_before = self.in_sample(&set_of(&self.terms));
        self.mark_used();
        true
    }

    /// After an exchange: every candidate of a fitted kind, or of a fitted family (nested
    /// forms), is not tried again.
    fn mark_used(&mut self) {
        self.used = vec![false; self.lib.len()];
        for t in &self.terms {
            for (j, c) in self.lib.iter().enumerate() {
                if c.kind == t.cand.kind
                    || (c.family() == t.cand.family()
                        && c.effect_id() != "reversal_spike"
                        && t.cand.effect_id() != "reversal_spike")
                {
                    self.used[j] = true;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
