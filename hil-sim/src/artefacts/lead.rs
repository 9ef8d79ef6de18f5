//! A hidden machine that carries a ball-screw lead wave, and what measures it: hole plates whose
//! pitch is not a multiple of the lead (so the holes of one measurement sample every phase of the
//! wave; the fitted plate pose absorbs a wave that puts the same offset on every hole), and laser
//! runs at steps ≤ lead/4 (the direct path).
//!
//! The wave is added to a truth's positioning component (EXX, EYY, EZZ) and the sum tabulated every
//! [`TRUTH_STEP_MM`] (linear between nodes: at most 1.2 % of the amplitude off the analytic sine for
//! a 5 mm lead), in both approach directions alike. Convention as `retrocomp_analysis::fit::lead`:
//! A·sin(2πq/L + φ), q the axis position from 0, A µm, φ degrees.

use retrocomp_analysis::identify::contracts::Plane;
use retrocomp_analysis::iso230_2::Reading;
use retrocomp_analysis::table::Direction;
use retrocomp_model::{Axis, ErrorFunction, Interpolation, MachineModel, Motion, Table};

use super::{ID_PROBES_MM, PlatePlacement, plate, travel};
use crate::rng::Noise;

/// Node spacing of the hidden machine's positioning tables once a wave is added, mm (lead/20 for
/// a 5 mm lead).
pub const TRUTH_STEP_MM: f64 = 0.25;

/// One hidden lead wave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HiddenLead {
    pub axis: Axis,
    pub lead_mm: f64,
    pub amplitude_um: f64,
    pub phase_deg: f64,
}

impl HiddenLead {
    /// The wave at q, µm.
    pub fn eval(&self, q_mm: f64) -> f64 {
        self.amplitude_um
            * (std::f64::consts::TAU * q_mm / self.lead_mm + self.phase_deg.to_radians()).sin()
    }
}

/// The waves of [`with_lead_waves`]'s default machine: a 5 mm lead on every axis, 1.5 / 1.2 /
/// 1.0 µm at 30° / 140° / −110°.
pub const LEAD_WAVES: [HiddenLead; 3] = [
    HiddenLead {
        axis: Axis::X,
        lead_mm: 5.0,
        amplitude_um: 1.5,
        phase_deg: 30.0,
    },
    HiddenLead {
        axis: Axis::Y,
        lead_mm: 5.0,
        amplitude_um: 1.2,
        phase_deg: 140.0,
    },
    HiddenLead {
        axis: Axis::Z,
        lead_mm: 5.0,
        amplitude_um: 1.0,
        phase_deg: -110.0,
    },
];

/// `truth` with each wave added to its axis' positioning component, tabulated every
/// [`TRUTH_STEP_MM`] over the travel. Everything else unchanged.
pub fn with_lead_waves(truth: &MachineModel, waves: &[HiddenLead]) -> MachineModel {
    let tr = travel(truth);
    let mut spec = truth.spec().clone();
    for w in waves {
        let c = spec
            .components
            .iter_mut()
            .find(|c| c.id.axis == w.axis && c.id.motion == Motion::Translation(w.axis))
            .expect("the truth has the positioning component");
        let (lo, hi) = tr[w.axis.index()];
        let n = retrocomp_analysis::numeric::ceil_usize((hi - lo) / TRUTH_STEP_MM);
        let q: Vec<f64> = (0..=n)
            .map(|k| lo + (hi - lo) * k as f64 / n as f64)
            .collect();
        let at = |dir: i8| -> Vec<f64> {
            q.iter()
                .map(|&x| c.function.eval(x, dir).0 + w.eval(x))
                .collect()
        };
        let (fwd, rev) = (at(1), at(-1));
        c.function = ErrorFunction::Table(Table::new(q, fwd, rev, Interpolation::Linear));
    }
    MachineModel::from_spec(spec)
}

/// Fraction of a lead between neighbouring holes of [`lead_plates`]. 0.45: consecutive holes sit
/// almost half a turn apart, so at the holes the wave alternates (its alias has a period of 2.2
/// holes: 137 mm along a 62.25 mm pitch), far from the 200–300 mm errors a piecewise quadratic
/// with knots ≥ 50 mm apart leaves behind, while the ten holes of a row still sit at ten phases
/// spread over the whole turn. A quarter lead (61.25 mm) samples the phases as well but aliases
/// the wave to 4 holes (245 mm), where that misfit leaks into it (docs/identify.md, "Lead wave").
pub const LEAD_FRACTION: f64 = 0.45;

/// Hole pitch near `base_mm` that is `frac` of a lead more than a whole number of leads.
pub fn lead_pitch(base_mm: f64, lead_mm: f64, frac: f64) -> f64 {
    ((base_mm / lead_mm).round() + frac) * lead_mm
}

/// Spaan's six identification measurements ([`super::Plan::Six`]: one placement per plane, both
/// probes) with pitches `frac` of a lead off whole leads (near 60 × 40 mm), 10 × 10 holes:
/// 62.25 × 42.25 mm for a 5 mm lead and [`LEAD_FRACTION`].
pub fn lead_plates(lead_mm: f64, frac: f64) -> Vec<PlatePlacement> {
    let (wide, narrow) = (
        lead_pitch(60.0, lead_mm, frac),
        lead_pitch(40.0, lead_mm, frac),
    );
    let places = [
        ("id_xy", Plane::Xy, [130.0, 50.0, 150.0], [wide, narrow]),
        ("id_xz", Plane::Xz, [130.0, 225.0, 50.0], [wide, narrow]),
        ("id_yz", Plane::Yz, [375.0, 50.0, 50.0], [narrow, narrow]),
    ];
    places
        .into_iter()
        .flat_map(|(name, plane, o, pitch)| {
            ID_PROBES_MM.map(|t| PlatePlacement {
                name: format!("{name}_t{t:.0}"),
                ..plate(name, plane, o, t, [10, 10], pitch)
            })
        })
        .collect()
}

/// Laser runs of one axis on `truth`, the other axes at 0 and no tool: `runs` bidirectional runs at
/// targets every `step_mm` over the travel, each reading the tool tip's error along the axis (the
/// whole model, approached in the run's direction) with `noise_um` (1 σ) per reading.
pub fn laser_runs(
    truth: &MachineModel,
    axis: Axis,
    step_mm: f64,
    runs: u32,
    noise_um: f64,
    seed: u64,
) -> Vec<Reading> {
    let (lo, hi) = travel(truth)[axis.index()];
    let mut input = truth.new_input();
    let mut state = truth.new_state();
    let mut out = truth.new_breakdown();
    input.tool_mm = Some(0.0);
    let mut rng = Noise::new(seed, &format!("laser/{}", axis.lower()));
    let n = retrocomp_analysis::numeric::trunc_usize((hi - lo) / step_mm);
    let mut readings = Vec::with_capacity(2 * (n + 1) * runs as usize);
    for run in 1..=runs {
        for (direction, dir) in [(Direction::Forward, 1i8), (Direction::Reverse, -1)] {
            for k in 0..=n {
                let k = if dir > 0 { k } else { n - k };
                let target_mm = lo + step_mm * k as f64;
                input.pos_mm = [0.0; 3];
                input.pos_mm[axis.index()] = target_mm;
                input.dir = [0; 3];
                input.dir[axis.index()] = dir;
                truth.evaluate(&input, &mut state, &mut out);
                readings.push(Reading {
                    target_mm,
                    run,
                    direction,
                    deviation_um: out.total_um[axis.index()] + rng.gauss(noise_um),
                });
            }
        }
    }
    readings
}

/// Laser runs of X, Y, Z on `truth` (five bidirectional runs every `step_mm`, 0.3 µm noise) as
/// `<dir>/{x,y,z}.csv` in the long layout `retrocomp fit axis` reads.
pub fn write_laser_runs(
    truth: &MachineModel,
    step_mm: f64,
    seed: u64,
    dir: &std::path::Path,
) -> anyhow::Result<()> {
    use std::fmt::Write as _;
    std::fs::create_dir_all(dir)?;
    for axis in Axis::ALL {
        let mut csv = String::from("target_mm,run,direction,deviation_um\n");
        for r in laser_runs(truth, axis, step_mm, 5, 0.3, seed) {
            let d = if r.direction == Direction::Forward {
                '+'
            } else {
                '-'
            };
            writeln!(csv, "{},{},{d},{:.4}", r.target_mm, r.run, r.deviation_um)?;
        }
        std::fs::write(dir.join(format!("{}.csv", axis.lower())), csv)?;
    }
    Ok(())
}
