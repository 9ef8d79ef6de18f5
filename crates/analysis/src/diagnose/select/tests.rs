//! Unit tests of [`super`] (selection on small synthetic recordings).

use super::*;
use crate::diagnose::candidates::Kind;
use retrocomp_model::recording::Recording;

/// Positions (mm) stepping `steps` × `step_mm` up and back down, 10 samples per dwell.
fn step_and_dwell(n: usize, steps: usize, step_mm: f64) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let k = (i / 10) % (2 * steps);
            step_mm
                * if k < steps {
                    k as f64
                } else {
                    (2 * steps - k) as f64
                }
        })
        .collect()
}

#[test]
fn finds_a_backlash_and_nothing_in_pure_noise() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let n = 2000;
    let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
    // Step-and-dwell up and down over 0..200 mm: 10 mm steps, 10 samples per dwell, so velocity
    // (servo lag) and latched direction (backlash) are not collinear.
    let x = step_and_dwell(n, 20, 10.0);
    let noise: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t),
        ("x_mm".into(), x),
        ("ex_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let ctx = Context::from_recording(&rec);
    let dir = &ctx.axis('x').unwrap().dir;
    let r: Vec<f64> = dir
        .iter()
        .zip(&noise)
        .map(|(&d, e)| 3.0 * f64::from(d) + e)
        .collect();
    let s = select(&ctx, 'x', &r, &[], &Options::default());
    assert_eq!(
        s.terms.len(),
        1,
        "{:?}",
        s.terms.iter().map(|t| t.cand.label()).collect::<Vec<_>>()
    );
    assert_eq!(s.terms[0].cand.effect_id(), "backlash");
    let none = select(&ctx, 'x', &noise, &[], &Options::default());
    assert!(
        none.terms.is_empty(),
        "{:?}",
        none.terms
            .iter()
            .map(|t| t.cand.label())
            .collect::<Vec<_>>()
    );
}

#[test]
fn restarted_lag_is_a_lag_started_fresh_at_each_block() {
    // What `retrocomp eval` computes on a new file starting at each block: the lag starts at
    // the block's first reading; the fit's reference (first reading of the whole record) stays.
    let n = 200;
    let t: Vec<f64> = (0..n).map(|i| 15.0 * i as f64).collect();
    let u: Vec<f64> = (0..n)
        .map(|i| if (i / 30) % 2 == 0 { 20.0 } else { 30.0 } + 0.01 * i as f64)
        .collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t.clone()),
        ("T_a_C".into(), u.clone()),
        ("ez_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let ctx = Context::from_recording(&rec);
    let c = Candidate {
        axis: 'z',
        kind: Kind::ThermalLag {
            sensor: "T_a_C".into(),
        },
        grid: vec![300.0, 900.0],
    };
    let tau = 900.0;
    let cols = c.columns(&ctx, tau);
    let block: Vec<usize> = (0..n).map(|i| i / 50).collect();
    let r = restarted(&ctx, &c, tau, &cols, &block);
    let mut moved = 0.0f64;
    for b in 0..4 {
        let s = 50 * b;
        let fresh = super::super::features::lowpass(&t[s..s + 50], &u[s..s + 50], tau);
        for i in 0..50 {
            assert!(
                (r[0][s + i] - (fresh[i] - u[0])).abs() < 1e-9,
                "block {b} row {i}: {} vs {}",
                r[0][s + i],
                fresh[i] - u[0]
            );
            moved = moved.max((r[0][s + i] - cols[0][s + i]).abs());
        }
    }
    // The restart matters here (the carried state differs at block starts).
    assert!(moved > 1.0, "{moved}");
}

/// The screening and the exchange run on rayon's pool and collect in library order, each cyclic
/// candidate's period grid swept in fixed parallel chunks, and the two error signals are diagnosed
/// side by side and merged in signal order: the whole diagnosis serialises to the same bytes on
/// one thread (signals in turn) and on two (issue 39 point 3). 7 mm steps give a period grid of
/// one chunk, 1 mm steps one of several.
#[test]
fn the_diagnosis_is_the_same_on_one_thread_and_on_two() {
    use crate::diagnose::candidates::SWEEP_CHUNK;
    assert!(same_on_one_thread_and_on_two(23, 7.0) <= SWEEP_CHUNK);
    assert!(same_on_one_thread_and_on_two(150, 1.0) > 3 * SWEEP_CHUNK);
}

/// The periods the cyclic candidate screens.
fn same_on_one_thread_and_on_two(steps: usize, step_mm: f64) -> usize {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(39);
    let n = 3000;
    let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let x = step_and_dwell(n, steps, step_mm);
    let temp: Vec<f64> = t.iter().map(|s| 20.0 + 3.0 * (s / 900.0).sin()).collect();
    let temp_lag = crate::diagnose::features::lowpass(&t, &temp, 120.0);
    let dir: Vec<f64> = Context::from_recording(
        &Recording::from_columns(vec![
            ("t_s".into(), t.clone()),
            ("x_mm".into(), x.clone()),
            ("ex_um".into(), vec![0.0; n]),
        ])
        .unwrap(),
    )
    .axis('x')
    .unwrap()
    .dir
    .iter()
    .map(|&d| f64::from(d))
    .collect();
    // Backlash, a 25 mm cyclic error, a lagged thermal drift, noise.
    let ex: Vec<f64> = (0..n)
        .map(|i| {
            2.0 * dir[i]
                + 1.5 * (std::f64::consts::TAU * x[i] / 25.0).sin()
                + 0.8 * (temp_lag[i] - 20.0)
                + rng.random_range(-0.5..0.5)
        })
        .collect();
    // Y follows X at half the stroke; its error is thermal only, with a different gain.
    let y: Vec<f64> = x.iter().map(|v| 0.5 * v).collect();
    let ey: Vec<f64> = (0..n)
        .map(|i| -1.3 * (temp_lag[i] - 20.0) + rng.random_range(-0.5..0.5))
        .collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t),
        ("x_mm".into(), x),
        ("y_mm".into(), y),
        ("T_spindle_C".into(), temp),
        ("ex_um".into(), ex),
        ("sim_ex_um".into(), vec![0.0; n]),
        ("ey_um".into(), ey),
        ("sim_ey_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let on = |threads: usize| {
        let pool = crate::diagnose::test_pool(threads);
        let d = pool.install(|| crate::diagnose::diagnose(&rec, &Options::default()).unwrap());
        serde_json::to_string(&d.report).unwrap()
    };
    let one = on(1);
    assert!(one.contains("backlash"), "{one}");
    assert!(one.contains(r#""signal":"ey_um""#), "{one}");
    assert_eq!(one, on(2));
    let ctx = Context::from_recording(&rec);
    let lib = crate::diagnose::candidates::library(&ctx, 'x');
    let cyclic = lib
        .iter()
        .find(|c| c.is_cyclic())
        .expect("a cyclic candidate");
    cyclic.grid.len()
}
