//! The ballbar diagnosis read back: the chosen least-squares fit as named terms with their
//! physical parameters (the conventions of the parent module's top comment) and each term's
//! peak-to-valley contribution to the radial deviation.

use nalgebra::DVector;

use super::{CircleSetup, Column, TermFit, p2v};

/// The chosen fit read back by effect name: coefficients and each term's peak-to-valley share.
pub(super) struct Fitted<'a> {
    pub(super) cols: &'a [Column],
    pub(super) beta: &'a DVector<f64>,
    /// Samples in all traces.
    pub(super) n: usize,
}

impl Fitted<'_> {
    /// The coefficient of a column, `None` when it was not fitted (servo mismatch with one
    /// rotation, cyclic terms without a period).
    pub(super) fn coef(&self, name: &str) -> Option<f64> {
        self.cols
            .iter()
            .position(|c| c.effect == name)
            .map(|j| self.beta[j])
    }

    /// The coefficient, 0 for a column that was not fitted.
    pub(super) fn c(&self, name: &str) -> f64 {
        self.coef(name).unwrap_or(0.0)
    }

    /// Peak-to-valley over all samples of the named columns' fitted sum: a term's share.
    fn contrib(&self, names: &[&str]) -> f64 {
        let v: Vec<f64> = (0..self.n)
            .map(|i| {
                names
                    .iter()
                    .filter_map(|n| {
                        self.cols
                            .iter()
                            .position(|c| c.effect == *n)
                            .map(|j| self.cols[j].values[i] * self.beta[j])
                    })
                    .sum()
            })
            .collect();
        p2v(&v)
    }

    /// One reported term; its share is set once every term's contribution is known.
    fn term(&self, effect: &str, params: Vec<(&str, f64)>, names: &[&str]) -> TermFit {
        TermFit {
            effect: effect.to_string(),
            params: params
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
            contribution_um: self.contrib(names),
            share_pct: 0.0,
        }
    }
}

/// The terms that act at axis reversals (backlash, lateral play, reversal spikes).
pub(super) fn reversal_terms(f: &Fitted<'_>, decay: f64) -> Vec<TermFit> {
    let c = |n: &str| f.c(n);
    vec![
        f.term(
            "backlash_x",
            vec![("b_um", -2.0 * c("backlash_x"))],
            &["backlash_x"],
        ),
        f.term(
            "backlash_y",
            vec![("b_um", -2.0 * c("backlash_y"))],
            &["backlash_y"],
        ),
        f.term(
            "lateral_play_x",
            vec![("p_um", 2.0 * c("lateral_play_x"))],
            &["lateral_play_x"],
        ),
        f.term(
            "lateral_play_y",
            vec![("p_um", 2.0 * c("lateral_play_y"))],
            &["lateral_play_y"],
        ),
        f.term(
            "reversal_spike_x",
            vec![
                ("amplitude_um", -c("reversal_spike_x")),
                ("decay_mm", decay),
            ],
            &["reversal_spike_x"],
        ),
        f.term(
            "reversal_spike_y",
            vec![
                ("amplitude_um", -c("reversal_spike_y")),
                ("decay_mm", decay),
            ],
            &["reversal_spike_y"],
        ),
    ]
}

/// The terms that shape the whole path (cyclic, servo mismatch, squareness, straightness, scale),
/// converted to their physical parameters.
pub(super) fn path_terms(f: &Fitted<'_>, setup: &CircleSetup) -> Vec<TermFit> {
    let c = |n: &str| f.c(n);
    let r = setup.radius_mm;
    let feed_mm_s = setup.feed_mm_per_min / 60.0;
    let mut terms = Vec::new();
    if let Some(p) = setup.cyclic_period_x_mm {
        terms.push(f.term(
            "cyclic_x",
            vec![
                ("amplitude_um", c("cyclic_x_sin").hypot(c("cyclic_x_cos"))),
                ("period_mm", p),
            ],
            &["cyclic_x_sin", "cyclic_x_cos"],
        ));
    }
    if let Some(p) = setup.cyclic_period_y_mm {
        terms.push(f.term(
            "cyclic_y",
            vec![
                ("amplitude_um", c("cyclic_y_sin").hypot(c("cyclic_y_cos"))),
                ("period_mm", p),
            ],
            &["cyclic_y_sin", "cyclic_y_cos"],
        ));
    }
    // Δr = d·(F·Δτ/2)·sin2θ with F in mm/s and Δτ in s → µm = F·Δτ·1000/2; Δτ in ms = 2β/F.
    if f.coef("servo_mismatch").is_some() {
        terms.push(f.term(
            "servo_mismatch",
            vec![("ms", 2.0 * c("servo_mismatch") / feed_mm_s)],
            &["servo_mismatch"],
        ));
    }
    // (R α / 2)·sin2θ: α [µrad] = 2β [µm] / R [mm] × 1000.
    terms.push(f.term(
        "squareness",
        vec![("urad", 2.0 * c("squareness") / r * 1000.0)],
        &["squareness"],
    ));
    terms.push(f.term(
        "straightness_x",
        vec![("bow_um", c("straightness_x"))],
        &["straightness_x"],
    ));
    terms.push(f.term(
        "straightness_y",
        vec![("bow_um", c("straightness_y"))],
        &["straightness_y"],
    ));
    terms.push(f.term(
        "scale_mismatch",
        vec![("ppm", 2.0 * c("scale_mismatch") / r * 1000.0)],
        &["scale_mismatch"],
    ));
    terms
}
