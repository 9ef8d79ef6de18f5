//! Indirect identification of a 3-axis machine's 21 geometric components from artefacts (Spaan
//! 1995 Ch3): hole-plate placements and static ball-bar spheres in, one joint least-squares fit
//! ΔP = Xβ + γ out, with β the C¹ piecewise quadratics of the 18 components plus 3 squareness
//! angles and γ each artefact's set-up (plate pose, sphere centre). Sans-IO: texts in, structs out;
//! `src/cli/identify.rs` does the files.
//!
//! Signs and units as in the machine model: error = actual − nominal of the tool tip relative to
//! the workpiece, µm; rotations µrad; positions mm. Components are 0 at the low end of their
//! identified range (artefacts cannot see constants); see `design.rs` for the other gauges.
//!
//! - [`contracts`]: the CSV + side-TOML readers and writers (docs/identify.md).
//! - `observe`: artefact → observations, thermal expansion removed.
//! - `design`: the chain's first-order design rows.
//! - `estimate`: the solve, knot elimination, outliers, F/t, null space.
//! - [`report`]: the fitted model, per-component significance and identifiability, verification.
//! - `resolution`: the shortest wavelength identified per axis, and lack of fit beyond it.
//! - [`vouch`]: the probe range and plate positions the model vouches for, and what would widen them.

pub mod contracts;
mod design;
mod estimate;
mod observe;
pub mod report;
mod resolution;
pub mod vouch;

pub use design::{ChainError, CompBasis, Geometry, Obs, Shape};
pub use estimate::{EstimateError, Solve};
pub use observe::Setup;
pub use resolution::{AxisResolution, Resolution};

use contracts::{BallBar, HolePlate};
use design::component_bases;
use estimate::{beta_len, duplicate_outliers, eliminate_knots, solve};
use observe::{ballbar_obs, plate_obs};

/// Options of the fit.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Spacing of candidate knots, mm (Spaan: 50 mm).
    pub knot_step_mm: f64,
    /// At most this many candidate knots per axis (keeps X small for the 2 s budget).
    pub max_knots: usize,
    /// Significance level of a knot (two-sided t), Spaan 99.99 %: 1e-4.
    pub alpha: f64,
    /// Include the rotation (Abbe) components. Off only to show what they are worth.
    pub rotations: bool,
    /// Use the probe length. Off only to show what it is worth.
    pub use_tool_length: bool,
    /// Relative eigenvalue of the column-scaled XᵀX below which a direction of β, γ counts as not
    /// seen by the data (its square root is the relative singular value). 1e-8: on Spaan's six
    /// plates a combination of table roll (EAX), Y pitch (EBY) and Z pitch (EBZ) that plates with a
    /// fitted pose cannot see sits at ~1e-10 (rounding keeps it off zero); at 1e-10 it was kept and
    /// amplified noise to hundreds of µrad (hil-sim/tests/sim/identify/truth.rs).
    pub rank_tol: f64,
    /// Lead of the ball screws, mm: each positioning component (EXX, EYY, EZZ) also gets a sin/cos
    /// pair at this period (docs/identify.md, "Lead wave"). None: no lead terms.
    pub lead_mm: Option<f64>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            knot_step_mm: 50.0,
            max_knots: 6,
            alpha: 1e-4,
            rotations: true,
            use_tool_length: true,
            rank_tol: 1e-8,
            lead_mm: None,
        }
    }
}

impl Options {
    /// The defaults for the artefacts given. Hole plates (any): Spaan's candidate knots every
    /// 50 mm, at most 6 per axis — plates sample each axis only at their hole rows (40–60 mm
    /// pitch), so closer knots would be guesses between rows. Ball-bar spheres only: every 30 mm,
    /// at most 16 per axis — a sphere samples its positions continuously (~2700 points for
    /// Spaan's eight), and the 200–300 mm pitch wave of an old mill's X needs knots closer than
    /// 50 mm spread as 6 (114 mm on 800 mm): with the default knots eight spheres trail the true
    /// model by 0.038–0.052, with these by 0.013–0.016 (docs/identify.md,
    /// hil-sim/tests/sim/identify/truth.rs).
    pub fn for_artefacts(n_plates: usize, n_bars: usize) -> Options {
        if n_plates == 0 && n_bars > 0 {
            Options {
                knot_step_mm: 30.0,
                max_knots: 16,
                ..Options::default()
            }
        } else {
            Options::default()
        }
    }
}

/// Everything a fit produced.
#[derive(Debug, Clone)]
pub struct Identification {
    pub geometry: Geometry,
    pub bases: Vec<CompBasis>,
    pub setups: Vec<Setup>,
    pub solve: Solve,
    pub obs: Vec<Obs>,
    /// Observations dropped as duplicate-probing outliers: (artefact name, hole, repeat).
    pub outliers: Vec<(String, String, u32)>,
    pub range_mm: [(f64, f64); 3],
    /// Shortest wavelength identified per axis, and lack of fit beyond it.
    pub resolution: Resolution,
}

/// The joint fit of all artefacts.
pub fn identify(
    geo: &Geometry,
    plates: &[HolePlate],
    bars: &[BallBar],
    opts: &Options,
) -> Result<Identification, EstimateError> {
    let (mut obs, mut setups, n_setup) = observations(plates, bars, opts);
    if obs.is_empty() {
        return Err(EstimateError::TooFew { rows: 0, cols: 1 });
    }
    let range_mm: [(f64, f64); 3] = std::array::from_fn(|k| {
        obs.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), o| {
                (a.min(o.pos_mm[k]), b.max(o.pos_mm[k]))
            })
    });
    let mut bases = component_bases(range_mm, opts.knot_step_mm, opts.max_knots, opts.lead_mm);
    if !opts.rotations {
        bases.retain(|b| !b.id.is_rotation());
    }
    // A sphere's readings are linear in its centre only to first order: a centre δC off the
    // nominal adds (|δC|² − (n·δC)²)/2R, 2.5 µm for 0.87 mm on a 150 mm bar — more than the
    // machine's errors seen radially. So the centres are re-linearised about their estimates
    // (Gauss–Newton; two steps leave < 1 nm) before the fit proper.
    let mut moved = bars.to_vec();
    let mut shift_um = vec![[0.0; 3]; bars.len()];
    let steps = if bars.is_empty() {
        0
    } else {
        RELINEARISE_STEPS
    };
    for _ in 0..steps {
        let s = solve(geo, &bases, &obs, n_setup, opts.rank_tol)?;
        let beta = beta_len(&bases);
        for (k, bar) in moved.iter_mut().enumerate() {
            let first = setups[plates.len() + k].first;
            for (i, c) in bar.centre_mm.iter_mut().enumerate() {
                let d = s.coef[beta + first + i];
                *c += d * 1e-3;
                shift_um[k][i] += d;
            }
        }
        (obs, setups, _) = observations(plates, &moved, opts);
    }
    // Outliers first, with every candidate knot, so a pulse cannot buy itself a knot.
    let s0 = solve(geo, &bases, &obs, n_setup, opts.rank_tol)?;
    let limit = outlier_limit_um(&obs);
    let drop = duplicate_outliers(&obs, &s0.residual_um, limit);
    let mut outliers: Vec<(String, String, u32)> = Vec::new();
    for &i in &drop {
        let o = &obs[i];
        let e = (setups[o.artefact].name.clone(), o.key.clone(), o.repeat);
        if !outliers.contains(&e) {
            outliers.push(e);
        }
    }
    let obs: Vec<Obs> = obs
        .into_iter()
        .enumerate()
        .filter(|(i, _)| drop.binary_search(i).is_err())
        .map(|(_, o)| o)
        .collect();
    let mut solve = eliminate_knots(geo, &mut bases, &obs, n_setup, opts.alpha, opts.rank_tol)?;
    // Report each centre against the side file's nominal: add back what re-linearising moved.
    let beta = beta_len(&bases);
    for (k, d) in shift_um.iter().enumerate() {
        let s = &mut setups[plates.len() + k];
        s.nominal = bars[k].centre_mm.to_vec();
        for (i, d) in d.iter().enumerate() {
            solve.coef[beta + s.first + i] += d;
        }
    }
    let mut id = Identification {
        geometry: geo.clone(),
        bases,
        setups,
        solve,
        obs,
        outliers,
        range_mm,
        resolution: Resolution::default(),
    };
    id.resolution = resolution::resolution(&id, opts.knot_step_mm, opts.max_knots);
    Ok(id)
}

/// Gauss–Newton steps on the sphere centres before the fit.
const RELINEARISE_STEPS: usize = 2;

/// Observations and set-ups of all artefacts, γ columns numbered plates first, then spheres.
fn observations(
    plates: &[HolePlate],
    bars: &[BallBar],
    opts: &Options,
) -> (Vec<Obs>, Vec<Setup>, usize) {
    let mut obs = Vec::new();
    let mut setups = Vec::new();
    let mut first = 0;
    for p in plates {
        let (o, s) = plate_obs(p, setups.len(), first);
        first += s.names.len();
        obs.extend(o);
        setups.push(s);
    }
    for b in bars {
        let (o, s) = ballbar_obs(b, setups.len(), first);
        first += s.names.len();
        obs.extend(o);
        setups.push(s);
    }
    if !opts.use_tool_length {
        for o in &mut obs {
            o.tool_mm = 0.0;
        }
    }
    (obs, setups, first)
}

/// Disagreement of two probings of one hole beyond which one is an outlier: six robust σ of the
/// pair differences (never below 1 µm).
fn outlier_limit_um(obs: &[Obs]) -> f64 {
    use std::collections::HashMap;
    let mut first: HashMap<(usize, &str, Option<usize>), f64> = HashMap::new();
    let mut diffs = Vec::new();
    for o in obs {
        let k = (o.artefact, o.key.as_str(), o.dir);
        match first.get(&k) {
            Some(y) => diffs.push((o.y_um - y).abs()),
            None => {
                first.insert(k, o.y_um);
            }
        }
    }
    if diffs.is_empty() {
        return f64::INFINITY;
    }
    diffs.sort_by(f64::total_cmp);
    let med = diffs[diffs.len() / 2];
    (6.0 * 1.4826 * med).max(1.0)
}
