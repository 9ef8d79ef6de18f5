//! The spatial resolution of an artefact identification: along each machine axis, the shortest
//! wavelength of a component the fit can follow, and what shorter content does to it.
//!
//! Two limits, the larger wins (mm):
//! - sampling: the artefacts read each axis only at their probing positions; a periodic error
//!   shorter than twice the largest gap between neighbouring positions (2 × the hole pitch on a
//!   plate grid; Spaan: "the sampling density is limited to the grid size of the plate") is
//!   aliased, not seen;
//! - basis: a C¹ piecewise quadratic with knots h apart follows no wave shorter than ≈ 2h, h the
//!   spacing of the candidate knots (`--knot-step-mm`, at most `max_knots` per axis).
//!
//! Shorter content (a ball-screw pitch wave, a linearised table of a short sine) is not
//! identifiable from these artefacts: it shows as residual above the probing repeatability
//! (duplicate probings give that repeatability, Spaan's "pure error"). The remedy is a direct
//! measurement of that axis at steps ≤ λ/4 (laser) fitted with `retrocomp fit`.

use serde::Serialize;

use super::Identification;
use super::design::Obs;

/// One machine axis.
#[derive(Debug, Clone, Serialize)]
pub struct AxisResolution {
    pub axis: char,
    /// Largest gap between neighbouring probing positions along the axis, mm.
    pub largest_gap_mm: f64,
    /// Spacing of the candidate knots, mm.
    pub knot_spacing_mm: f64,
    /// max(2 × gap, 2 × knot spacing): shorter waves are not identifiable, mm.
    pub shortest_wavelength_mm: f64,
}

/// What the fit can resolve and whether the data show content it could not follow.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Resolution {
    pub axes: Vec<AxisResolution>,
    /// Probing repeatability from duplicate probings (σ of one probing), µm; None without repeats.
    pub repeatability_um: Option<f64>,
    /// Fit residual σ over that repeatability: well above 1 means content the model cannot follow
    /// (sub-resolution errors, or a component outside the model).
    pub lack_of_fit_ratio: Option<f64>,
    /// What the report says about it.
    pub note: String,
}

/// Positions closer than this count as one (mm): repeats and a plate's row of holes.
const SAME_MM: f64 = 0.5;
/// Residual σ above this multiple of the repeatability is reported as lack of fit.
pub(super) const LACK_OF_FIT_LIMIT: f64 = 1.25;

fn largest_gap(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > SAME_MM)
        .fold(0.0, f64::max)
}

/// Probing repeatability: duplicate probings of one hole, σ = 1.4826 · median |difference| / √2.
fn repeatability_um(obs: &[Obs]) -> Option<f64> {
    use std::collections::HashMap;
    let mut first: HashMap<(usize, &str, Option<usize>), f64> = HashMap::new();
    let mut diffs = Vec::new();
    for o in obs {
        match first.get(&(o.artefact, o.key.as_str(), o.dir)) {
            Some(y) => diffs.push((o.y_um - y).abs()),
            None => {
                first.insert((o.artefact, o.key.as_str(), o.dir), o.y_um);
            }
        }
    }
    if diffs.len() < 10 {
        return None;
    }
    diffs.sort_by(f64::total_cmp);
    Some(1.4826 * diffs[diffs.len() / 2] / std::f64::consts::SQRT_2)
}

/// The resolution of `id`; `knot_step_mm`, `max_knots` as in [`super::Options`].
pub(super) fn resolution(id: &Identification, knot_step_mm: f64, max_knots: usize) -> Resolution {
    let axes: Vec<AxisResolution> = (0..3)
        .map(|k| {
            let (lo, hi) = id.range_mm[k];
            let n = crate::numeric::ceil_usize((hi - lo) / knot_step_mm)
                .saturating_sub(1)
                .min(max_knots);
            let knot_spacing_mm = (hi - lo) / (n + 1) as f64;
            let largest_gap_mm = largest_gap(id.obs.iter().map(|o| o.pos_mm[k]).collect());
            AxisResolution {
                axis: ['x', 'y', 'z'][k],
                largest_gap_mm,
                knot_spacing_mm,
                shortest_wavelength_mm: 2.0 * largest_gap_mm.max(knot_spacing_mm),
            }
        })
        .collect();
    let repeatability_um = repeatability_um(&id.obs);
    let lack_of_fit_ratio = repeatability_um
        .filter(|r| *r > 0.0)
        .map(|r| id.solve.sigma_um / r);
    let waves: Vec<String> = axes
        .iter()
        .map(|a| {
            format!(
                "{} {:.0} mm",
                a.axis.to_ascii_uppercase(),
                a.shortest_wavelength_mm
            )
        })
        .collect();
    let mut note = format!(
        "shortest wavelength identified: {} (2 × the larger of the probing gap and the knot \
         spacing); shorter errors (e.g. a ball-screw pitch wave) are not identifiable from these \
         artefacts: measure such an axis directly (laser at steps ≤ λ/4) and fit it with \
         `retrocomp fit`",
        waves.join(", ")
    );
    match id.bases.iter().find_map(|b| b.lead_mm) {
        Some(l) => note.push_str(&format!(
            "; except the ball screws' {l} mm lead wave, fitted as a term of its own (--lead-mm)"
        )),
        None => note.push_str(
            "; a ball-screw lead wave of known lead is identifiable from plates whose pitch is not \
             a whole number of leads, with --lead-mm (docs/identify.md, \"Lead wave\")",
        ),
    }
    if let Some(r) = lack_of_fit_ratio.filter(|r| *r > LACK_OF_FIT_LIMIT) {
        note.push_str(&format!(
            "; the fit's residual σ is {r:.1} × the probing repeatability: the data hold errors \
             the model cannot follow, likely below that resolution"
        ));
    }
    Resolution {
        axes,
        repeatability_um,
        lack_of_fit_ratio,
        note,
    }
}
