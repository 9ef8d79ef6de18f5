//! Generators of the issue 36 benchmark families (points 3 and 6), shared by the CI test and the
//! full benchmark (`tests/diagnose/spectrum.rs`). Errors are actual − nominal (µm), positions
//! commanded (mm), time in s; every draw comes from a ChaCha8 stream seeded by (family, seed,
//! index), so a case is reproducible from its name.
//!
//! * `pitch`: bidirectional step-and-dwell laser runs on X, two or three runs each with its own
//!   step (drawn so a run reads 2.2–6 samples per period and the period is never a whole number
//!   of steps: the fractional part of period/step is in [0.2, 0.8]), 5–25 % target jitter, travel
//!   60–180 mm, two readings per visit read at standstill; a pitch error of period 3–12 mm, every
//!   second case with a second harmonic of 30–70 % of the fundamental; white noise at
//!   effect/noise 1.5–4 (centred RMS of the pitch error over the noise σ).
//! * `ar099_backlash`: the same kind of run on 0–300 mm with 21 targets, sampled at 1 Hz through
//!   the moves (20 mm/s: one moving row per step) and 8 s dwells, three bidirectional cycles
//!   (`run` 0, 1, 2); backlash of 2–8 µm (sign drawn) under AR(1) noise with ρ = 0.99 (stationary
//!   σ set by effect/noise, b/2 over σ).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use retrocomp_model::recording::Recording;

/// What a case hides.
#[derive(Clone, Debug)]
pub(crate) struct Truth {
    pub(crate) period_mm: f64,
    pub(crate) amplitude_um: f64,
    pub(crate) harmonic2_um: f64,
    pub(crate) b_um: f64,
    pub(crate) snr: f64,
    /// Shortest step of the runs (mm), for the table.
    pub(crate) min_step_mm: f64,
}

pub(crate) fn rng_for(family: u64, seed: u64, index: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(
        seed ^ family.rotate_left(29) ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    )
}

/// Targets of one run: `lo + k·step` plus a jitter of ±`jitter`·step (not at the ends).
fn targets(rng: &mut ChaCha8Rng, lo: f64, hi: f64, step: f64, jitter: f64) -> Vec<f64> {
    let n = ((hi - lo) / step).floor() as usize;
    (0..=n)
        .map(|k| {
            let j = if k == 0 || k == n {
                0.0
            } else {
                rng.random_range(-jitter..jitter) * step
            };
            lo + k as f64 * step + j
        })
        .collect()
}

/// A step for `period`: period/step has 2.2–6 samples and a fractional part in [0.2, 0.8].
fn step_for(rng: &mut ChaCha8Rng, period: f64) -> f64 {
    loop {
        let u: f64 = rng.random_range(2.2..6.0);
        if (0.2..=0.8).contains(&u.fract()) {
            return period / u;
        }
    }
}

/// Rows of a recording under construction.
#[derive(Default)]
struct Rows {
    t: Vec<f64>,
    x: Vec<f64>,
    run: Vec<f64>,
    dir: Vec<f64>,
}

impl Rows {
    fn push(&mut self, t: f64, x: f64, run: usize, dir: f64) {
        self.t.push(t);
        self.x.push(x);
        self.run.push(run as f64);
        self.dir.push(dir);
    }
}

/// Pitch case `index` of `seed`: the recording and its truth.
pub(crate) fn pitch_case(seed: u64, index: usize) -> (Recording, Truth) {
    let mut rng = rng_for(0x0057_17c4, seed, index);
    let period: f64 = rng.random_range(3.0..12.0);
    let amp: f64 = rng.random_range(1.0..4.0);
    let phase: f64 = rng.random_range(-3.1..3.1);
    let h2 = if index % 2 == 1 {
        amp * rng.random_range(0.3..0.7)
    } else {
        0.0
    };
    let phase2: f64 = rng.random_range(-3.1..3.1);
    let travel: f64 = rng.random_range(60.0..180.0);
    let runs = rng.random_range(2..=3usize);
    let steps: Vec<f64> = (0..runs).map(|_| step_for(&mut rng, period)).collect();
    let snr: f64 = rng.random_range(1.5..4.0);
    let p = Pitch {
        period_mm: period,
        amplitude_um: amp,
        phase_rad: phase,
        harmonic2_um: h2,
        harmonic2_phase_rad: phase2,
    };
    pitch_recording(&mut rng, &p, travel, &steps, snr)
}

/// A pitch error: fundamental and second harmonic (µm, rad).
pub(crate) struct Pitch {
    pub(crate) period_mm: f64,
    pub(crate) amplitude_um: f64,
    pub(crate) phase_rad: f64,
    pub(crate) harmonic2_um: f64,
    pub(crate) harmonic2_phase_rad: f64,
}

/// Bidirectional readings-only runs over 0..`travel`, one per step of `steps` (target jitter
/// 5–25 % of the step, two readings per visit), error = `p` + white noise at effect/noise `snr`.
pub(crate) fn pitch_recording(
    rng: &mut ChaCha8Rng,
    p: &Pitch,
    travel: f64,
    steps: &[f64],
    snr: f64,
) -> (Recording, Truth) {
    let mut rows = Rows::default();
    let mut now = 0.0;
    for (run, &step) in steps.iter().enumerate() {
        let jitter = rng.random_range(0.05..0.25);
        let tg = targets(rng, 0.0, travel, step, jitter);
        for (dir, pass) in [(1.0, tg.clone()), (-1.0, tg.into_iter().rev().collect())] {
            for x in pass {
                for _ in 0..2 {
                    now += 1.0;
                    rows.push(now, x, run, dir);
                }
                now += 3.0;
            }
        }
    }
    let w = std::f64::consts::TAU / p.period_mm;
    let pitch: Vec<f64> = rows
        .x
        .iter()
        .map(|x| {
            p.amplitude_um * (w * x + p.phase_rad).sin()
                + p.harmonic2_um * (2.0 * w * x + p.harmonic2_phase_rad).sin()
        })
        .collect();
    let sigma = rms_centered(&pitch) / snr;
    let e: Vec<f64> = pitch
        .iter()
        .map(|v| v + sigma * rng.sample::<f64, _>(StandardNormal))
        .collect();
    let truth = Truth {
        period_mm: p.period_mm,
        amplitude_um: p.amplitude_um,
        harmonic2_um: p.harmonic2_um,
        b_um: 0.0,
        snr,
        min_step_mm: steps.iter().copied().fold(f64::INFINITY, f64::min),
    };
    (recording(rows, e), truth)
}

/// AR(0.99) step-and-dwell backlash case `index` of `seed` at effect/noise `snr` (b/2 over the
/// noise's stationary σ).
pub(crate) fn ar099_backlash_case(seed: u64, index: usize, snr: f64) -> (Recording, Truth) {
    let mut rng = rng_for(0x00ba_c41a, seed, index);
    let b_um: f64 = rng.random_range(2.0..8.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let mut rows = Rows::default();
    let mut now = 0.0;
    let mut x = -2.0;
    // The approach direction: of the move into a row, kept through the dwell after it.
    let mut dir = 1.0;
    let tg = targets(&mut rng, 0.0, 300.0, 15.0, 0.3);
    for cycle in 0..3 {
        for (pass_dir, pass) in [
            (1.0, tg.clone()),
            (-1.0, tg.iter().rev().copied().collect::<Vec<_>>()),
        ] {
            // Overshoot so the first target of the pass is approached from its own side.
            let start = pass[0] - 2.0 * pass_dir;
            for p in std::iter::once(start).chain(pass) {
                if p != x {
                    dir = (p - x).signum();
                }
                // A move at 20 mm/s sampled at 1 Hz, landing on the target.
                let steps = ((p - x).abs() / 20.0).ceil().max(1.0) as usize;
                for k in 1..=steps {
                    now += 1.0;
                    rows.push(now, x + (p - x) * k as f64 / steps as f64, cycle, dir);
                }
                x = p;
                for _ in 0..8 {
                    now += 1.0;
                    rows.push(now, p, cycle, dir);
                }
            }
        }
    }
    let sigma = (b_um / 2.0).abs() / snr;
    let rho: f64 = 0.99;
    let innov = sigma * (1.0 - rho * rho).sqrt();
    let mut v = sigma * rng.sample::<f64, _>(StandardNormal);
    let e: Vec<f64> = rows
        .dir
        .iter()
        .map(|d| {
            v = rho * v + innov * rng.sample::<f64, _>(StandardNormal);
            b_um / 2.0 * d + v
        })
        .collect();
    let truth = Truth {
        period_mm: 0.0,
        amplitude_um: 0.0,
        harmonic2_um: 0.0,
        b_um,
        snr,
        min_step_mm: 15.0,
    };
    (recording(rows, e), truth)
}

fn recording(rows: Rows, e: Vec<f64>) -> Recording {
    let n = rows.t.len();
    Recording::from_columns(vec![
        ("t_s".into(), rows.t),
        ("x_mm".into(), rows.x),
        ("ex_um".into(), e),
        ("sim_ex_um".into(), vec![0.0; n]),
        ("run".into(), rows.run),
    ])
    .expect("generated recording is valid")
}

fn rms_centered(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}
