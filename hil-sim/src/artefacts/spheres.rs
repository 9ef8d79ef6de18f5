//! hil-sim's static ball-bar spheres (Spaan Table 3.1): the set-ups, the grid of points on each
//! sphere, and the probing of one sphere on the hidden machine (see the parent module for the
//! metrology). The bar reads its length from a centre ball on the table to the ball at the tool tip;
//! dr = bar length − nominal, µm; positions mm.

use retrocomp_analysis::identify::contracts::{BallBar, BallPoint, REFERENCE_C};
use retrocomp_model::MachineModel;

use super::{Metrology, Probe, scale_reading, travel};
use crate::rng::Noise;

/// One ball-bar set-up (Spaan Table 3.1 style).
#[derive(Debug, Clone, PartialEq)]
pub struct SpherePlacement {
    pub name: String,
    pub r_nom_mm: f64,
    pub centre_mm: [f64; 3],
    pub tool_mm: f64,
}

/// Eight spheres, radii 150–300 mm, two tool vectors (Spaan Table 3.1 scaled to the mill).
pub fn spaan_spheres() -> Vec<SpherePlacement> {
    let s = |n: &str, r: f64, c: [f64; 3], t: f64| SpherePlacement {
        name: n.into(),
        r_nom_mm: r,
        centre_mm: c,
        tool_mm: t,
    };
    vec![
        s("bb_4", 300.0, [400.0, 250.0, 150.0], 110.0),
        s("bb_14", 150.0, [400.0, 250.0, 150.0], 110.0),
        s("bb_27", 300.0, [300.0, 200.0, 100.0], 110.0),
        s("bb_29", 250.0, [500.0, 250.0, 100.0], 110.0),
        s("bb_89", 300.0, [450.0, 300.0, 50.0], 110.0),
        s("bb_99", 150.0, [250.0, 150.0, 200.0], 245.0),
        s("bb_105", 300.0, [500.0, 200.0, 150.0], 245.0),
        s("bb_137", 300.0, [400.0, 250.0, 0.0], 245.0),
    ]
}

/// Which ball-bar set-ups `hil-sim artefacts --spheres` probes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SpherePlan {
    /// Spaan's eight spheres ([`spaan_spheres`]) on the default grid ([`SphereGrid::default`]:
    /// 10° rings of 36 to 20° below the equator, ~2700 points). Identify them with knots every
    /// 30 mm (`retrocomp identify --knot-step-mm 30 --max-knots 16`).
    #[default]
    Eight,
    /// The eight plus two spheres centred below the travel ([`low_spheres`]) that reach the
    /// bottom of Z, each on a 7.5° grid of 48 points per ring (~5000 points): with knots every
    /// 30 mm (`retrocomp identify --knot-step-mm 30 --max-knots 16`) within 0.03 of the true
    /// model on Spaan's plates (hil-sim/tests/sim/identify/truth.rs).
    Ten,
}

/// Two spheres (R 250 mm) centred 100 mm below the Z travel, tools 110 and 245 mm: their lower
/// rings reach z ≈ 0–60 mm, where Spaan's eight (centres at z ≥ 0, upper hemispheres) read Z
/// only at grazing angles — the Z directions of plates at the bottom of Z were what eight missed.
pub fn low_spheres() -> Vec<SpherePlacement> {
    [("bb_low_110", 110.0), ("bb_low_245", 245.0)]
        .into_iter()
        .map(|(n, t)| SpherePlacement {
            name: n.into(),
            r_nom_mm: 250.0,
            centre_mm: [400.0, 250.0, -100.0],
            tool_mm: t,
        })
        .collect()
}

/// The dense grid of [`SpherePlan::Ten`]: 7.5° rings of 48 points.
pub const DENSE_GRID: SphereGrid = SphereGrid {
    polar_step_deg: 7.5,
    azimuths: 48,
    max_polar_deg: 90.0,
};

/// The spheres of `plan`, probed on `truth`.
pub fn measure_spheres(
    truth: &MachineModel,
    m: &Metrology,
    seed: u64,
    plan: SpherePlan,
) -> Vec<BallBar> {
    let tr = travel(truth);
    let (set, grid) = match plan {
        SpherePlan::Eight => (spaan_spheres(), SphereGrid::default()),
        SpherePlan::Ten => ([spaan_spheres(), low_spheres()].concat(), DENSE_GRID),
    };
    set.iter()
        .map(|s| measure_sphere_on(truth, s, tr, m, seed, grid))
        .collect()
}

/// Probes one ball-bar sphere on the default grid ([`SphereGrid::default`]); points outside
/// `travel_mm` are skipped.
pub fn measure_sphere(
    truth: &MachineModel,
    sp: &SpherePlacement,
    travel_mm: [(f64, f64); 3],
    m: &Metrology,
    seed: u64,
) -> BallBar {
    measure_sphere_on(truth, sp, travel_mm, m, seed, SphereGrid::default())
}

/// The points of a sphere: rings every `polar_step_deg` from the upper pole down to
/// `max_polar_deg` from it (90 = the equator), each ring `azimuths` points (the pole one).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SphereGrid {
    pub polar_step_deg: f64,
    pub azimuths: usize,
    pub max_polar_deg: f64,
}

impl Default for SphereGrid {
    /// 10° rings of 36 points from the pole to 110°, 20° below the equator: ~340 points per
    /// sphere inside the travel, ~2700 for Spaan's eight. The centre ball's support on the table
    /// blocks the lower cap; 20° below the equator is what a bar reaches beside it (the 220° arcs
    /// of ball-bar tests in vertical planes). Those low rings read Z at the bottom of the Z travel
    /// at 20° instead of at grazing angles; with knots every 30 mm they bring Spaan's eight spheres
    /// within 0.03 of the true model (hil-sim/tests/sim/identify/truth.rs). The earlier grid (15° rings
    /// of 24 to the equator, ~1000 points) trailed it by up to 0.044 with the same knots.
    fn default() -> Self {
        SphereGrid {
            polar_step_deg: 10.0,
            azimuths: 36,
            max_polar_deg: 110.0,
        }
    }
}

/// Probes one ball-bar sphere on `grid`; points outside `travel_mm` are skipped.
pub fn measure_sphere_on(
    truth: &MachineModel,
    sp: &SpherePlacement,
    travel_mm: [(f64, f64); 3],
    m: &Metrology,
    seed: u64,
    grid: SphereGrid,
) -> BallBar {
    let mut rng = Noise::new(seed, &format!("artefact/{}", sp.name));
    let mut u = |lo: f64, hi: f64| lo + (hi - lo) * rng.uniform();
    let centre = sp.centre_mm.map(|c| c + u(-0.5, 0.5));
    let t_bar = REFERENCE_C + u(-1.0, 1.0);
    let t_scale = [0; 3].map(|_| REFERENCE_C + u(-1.0, 1.0));
    let bar_mm = sp.r_nom_mm * (1.0 + m.plate_alpha_ppm_per_k * 1e-6 * (t_bar - REFERENCE_C));
    let mut rng = Noise::new(seed, &format!("artefact/{}/noise", sp.name));
    let mut probe = Probe::new(truth);
    let mut points = Vec::new();
    let rings =
        retrocomp_analysis::numeric::trunc_usize(grid.max_polar_deg / grid.polar_step_deg + 1e-9);
    for ring in 0..=rings {
        let polar = (ring as f64 * grid.polar_step_deg).to_radians();
        let n_az = if ring == 0 { 1 } else { grid.azimuths };
        for k in 0..n_az {
            let az = std::f64::consts::TAU * k as f64 / n_az as f64;
            let n = [polar.sin() * az.cos(), polar.sin() * az.sin(), polar.cos()];
            // The machine is sent to the nominal point on the nominal sphere.
            let r: [f64; 3] = std::array::from_fn(|i| sp.centre_mm[i] + sp.r_nom_mm * n[i]);
            if (0..3).any(|i| r[i] < travel_mm[i].0 || r[i] > travel_mm[i].1) {
                continue;
            }
            let e = probe.error_um(r, sp.tool_mm);
            let tip: [f64; 3] = std::array::from_fn(|i| r[i] + e[i] * 1e-3 - centre[i]);
            let len = (tip[0] * tip[0] + tip[1] * tip[1] + tip[2] * tip[2]).sqrt();
            points.push(BallPoint {
                point: format!("p{ring}_{k}"),
                pos_mm: scale_reading(r, t_scale, m.scale_alpha_ppm_per_k),
                dr_um: (len - bar_mm) * 1e3 + rng.gauss(m.probing_noise_um),
                tool_mm: sp.tool_mm,
                t_bar_c: Some(t_bar),
                t_scale_c: t_scale.map(Some),
                line: 0,
            });
        }
    }
    BallBar {
        name: sp.name.clone(),
        r_nom_mm: sp.r_nom_mm,
        centre_mm: sp.centre_mm,
        alpha_ppm_per_k: m.plate_alpha_ppm_per_k,
        scale_alpha_ppm_per_k: Some(m.scale_alpha_ppm_per_k),
        points,
    }
}
