//! What forward selection ([`super::select`]) takes and gives: its options and the terms it accepts,
//! with their evidence. Kept apart from the search so that the held-out score ([`super::heldout`])
//! and the exchange step ([`super::swap`]), which the search calls, can name them without importing
//! the search back (issue 14 point 2: no file cycle). Units: RMS and RSS in µm and µm².

use super::candidates::Candidate;

/// Forward selection's thresholds and block counts.
#[derive(Clone, Debug)]
pub struct Options {
    /// Family-wise significance level of a step.
    pub alpha: f64,
    /// Minimum ΔBIC (on n_eff) for a term to enter ("strong" evidence).
    pub min_delta_bic: f64,
    pub max_terms: usize,
    /// Contiguous time blocks when there is no usable `run` column.
    pub cv_blocks: usize,
    /// The same on recordings with no axis column (thermal tests), validated forward: block k is
    /// predicted from blocks 0…k−1. Finer than `cv_blocks` so the rolling origin moves in steps
    /// shorter than a machine's heat-up (on FL_THERMAL's emulated judge, 10 was the only count of
    /// 4, 5, 6, 8, 10 with no channel worse than the static regression on any split:
    /// `tests/diagnose/fl_judge.rs`, docs/diagnose.md).
    pub forward_blocks: usize,
    /// Minimum relative held-out RMS improvement for a term to stay.
    pub cv_min_gain: f64,
    /// Refit the simulation's gains inside each forward fold when its inputs are known
    /// (`heldout.rs`), with the in-sample guard in [`super::select::select`]. Off: on FL_THERMAL it lowered the
    /// emulated judge's median cut at 50 % from 34.5 to 15.8 % and the strict split's from 35.1
    /// to 15.8 %, and found nothing more at 60/70 % (docs/diagnose.md).
    pub refit_sim: bool,
    /// Alternatives within this ΔBIC of the winner and correlated above `ambiguity_corr` are ambiguous.
    pub ambiguity_bic: f64,
    pub ambiguity_corr: f64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            alpha: 0.01,
            min_delta_bic: 10.0,
            max_terms: 4,
            cv_blocks: 5,
            forward_blocks: 10,
            cv_min_gain: 0.01,
            refit_sim: false,
            ambiguity_bic: 10.0,
            ambiguity_corr: 0.95,
        }
    }
}

#[derive(Clone, Debug)]
pub struct Alternative {
    pub cand: Candidate,
    pub theta: f64,
    pub delta_bic: f64,
    pub corr: f64,
}

/// One accepted term with the evidence from the step that accepted it.
#[derive(Clone, Debug)]
pub struct Term {
    pub cand: Candidate,
    pub theta: f64,
    pub cols: Vec<Vec<f64>>,
    pub delta_bic: f64,
    pub p_value: f64,
    /// RSS drop at acceptance (µm²), for ordering by importance.
    pub gain_rss: f64,
    pub rms_after_um: f64,
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
    pub ambiguous_with: Vec<Alternative>,
    /// Accepted by the test within own-axis position cells (its CI comes from the same null).
    pub within_cells: bool,
}

#[cfg(test)]
impl Term {
    /// A term as if accepted with ΔBIC 100 (parsimony tests judge only its columns).
    pub(super) fn accepted(cand: Candidate, theta: f64, cols: Vec<Vec<f64>>) -> Term {
        Term {
            cand,
            theta,
            cols,
            delta_bic: 100.0,
            p_value: 0.0,
            gain_rss: 0.0,
            rms_after_um: 0.0,
            heldout_rms_before_um: 0.0,
            heldout_rms_after_um: 0.0,
            ambiguous_with: vec![],
            within_cells: false,
        }
    }
}

#[derive(Clone, Debug)]
pub struct SignalSelection {
    pub axis: char,
    pub n: usize,
    pub terms: Vec<Term>,
    /// Candidates screened at the first step, best first (label, ΔBIC) — the "why not" list.
    pub runners_up: Vec<(Candidate, f64)>,
    /// Candidate/grid pairs screened per step.
    pub tried: usize,
    /// The term accepted at the first step (label, ΔBIC), even if an exchange removed it later.
    pub first_choice: Option<(String, f64)>,
    /// Terms accepted at some step and later replaced by the exchange step ([`super::swap`]), in
    /// order: a term accepted and removed must be reported (issue 12 point 3).
    pub exchanged: Vec<Exchanged>,
}

/// A term accepted by forward selection and replaced by an exchange.
#[derive(Clone, Debug)]
pub struct Exchanged {
    pub term: Term,
    /// Labels of the term(s) that replaced it.
    pub by: Vec<String>,
    /// Held-out RMS (µm) of the accepted set before and after the exchange.
    pub heldout_rms_before_um: f64,
    pub heldout_rms_after_um: f64,
}

/// The accepted terms as (candidate, θ), for the held-out score.
pub fn set_of(terms: &[Term]) -> Vec<(&Candidate, f64)> {
    terms.iter().map(|t| (&t.cand, t.theta)).collect()
}
