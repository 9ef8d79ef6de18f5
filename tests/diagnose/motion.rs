//! Issue 12.4: motion features are honest on a step-and-dwell recording read at standstill only.
//!
//! ISO 230-2-style laser runs: 21 targets over 0–500 mm (irregular spacing), three bidirectional
//! cycles (`run` 0, 1, 2), three readings 1 s apart at every visit, 6 s between visits (the move is
//! not recorded), and the turnaround target read three times per pass (two visits in a row). The
//! error is a hidden backlash of 4.98 µm (e = ±b/2 by the approach direction: error = actual −
//! nominal), a modelled scale error of 30 ppm that the simulation holds, and white noise of 0.3 µm
//! (a fixed ChaCha8 stream, so the test is deterministic). Before issue 12.4 the velocity taken
//! between two standstill readings (step / 6 s, signed like the approach) made `servo_lag` a near
//! copy of `backlash` (corr 0.975; one backlash came back 1.23 µm, truth 4.98).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use retrocomp_analysis::diagnose::candidates::{Kind, library};
use retrocomp_analysis::diagnose::features::Context;
use retrocomp_analysis::diagnose::{diagnose, select::Options};
use retrocomp_model::recording::Recording;

const B_UM: f64 = 4.98;

/// The recording and, per row, the true approach direction (+1 / −1).
fn step_and_dwell() -> (Recording, Vec<f64>) {
    let targets: Vec<f64> = (0..21)
        .map(|i| {
            let jitter = if i == 0 || i == 20 {
                0.0
            } else {
                [-6.0, 4.0, -2.0, 7.0, 1.0][i % 5]
            };
            25.0 * i as f64 + jitter
        })
        .collect();
    let mut noise = ChaCha8Rng::seed_from_u64(0x5eed_1234_abcd_0001);
    let (mut t, mut x, mut e, mut sim, mut run, mut truth_dir) =
        (vec![], vec![], vec![], vec![], vec![], vec![]);
    let mut now = 0.0;
    for cycle in 0..3 {
        let passes = [
            (1.0, targets.clone()),
            (-1.0, targets.iter().rev().copied().collect::<Vec<_>>()),
        ];
        for (dir, pass) in passes {
            for &p in &pass {
                now += 6.0;
                for _ in 0..3 {
                    let scale_um = 30e-6 * p * 1e3;
                    t.push(now);
                    x.push(p);
                    e.push(
                        scale_um + B_UM / 2.0 * dir + 0.3 * noise.sample::<f64, _>(StandardNormal),
                    );
                    sim.push(scale_um);
                    run.push(f64::from(cycle));
                    truth_dir.push(dir);
                    now += 1.0;
                }
            }
        }
    }
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t),
        ("x_mm".into(), x),
        ("ex_um".into(), e),
        ("sim_ex_um".into(), sim),
        ("run".into(), run),
    ])
    .unwrap();
    (rec, truth_dir)
}

#[test]
fn step_and_dwell_readings_have_no_velocity_and_the_latch_reads_every_approach() {
    let (rec, truth_dir) = step_and_dwell();
    let ctx = Context::from_recording(&rec);
    let f = ctx.axis('x').unwrap();
    assert!(
        f.vel_mm_s().iter().all(|v| *v == 0.0),
        "standstill readings got a velocity"
    );
    // The approach direction of every reading, including the second visit of each turnaround
    // target (read right after the first, with the overshoot in between not recorded).
    let wrong: Vec<usize> = (0..truth_dir.len())
        .filter(|&i| f.dir_f64(i) != truth_dir[i])
        .collect();
    assert!(wrong.is_empty(), "rows with the wrong direction: {wrong:?}");
    assert!(
        !library(&ctx, 'x').iter().any(|c| c.kind == Kind::ServoLag),
        "servo_lag offered where the axis never moves"
    );
}

#[test]
fn step_and_dwell_backlash_is_recovered_within_15_percent_and_servo_lag_stays_out() {
    let (rec, _) = step_and_dwell();
    let d = diagnose(&rec, &Options::default()).unwrap();
    let r = &d.report;
    assert_eq!(r.verdict, "found", "{}", r.to_text());
    let reversal: Vec<_> = r
        .findings
        .iter()
        .filter(|f| f.effect == "backlash")
        .collect();
    assert_eq!(reversal.len(), 1, "{}", r.to_text());
    let b = reversal[0].params["b_um"].as_f64().unwrap();
    assert!(
        (b - B_UM).abs() < 0.15 * B_UM,
        "backlash {b} µm, truth {B_UM}: {}",
        r.to_text()
    );
    assert!(
        !r.findings.iter().any(|f| f.effect == "servo_lag")
            && !r.alternatives.iter().any(|a| a.effect == "servo_lag"),
        "{}",
        r.to_text()
    );
}

#[test]
fn a_scan_has_velocity_only_while_moving() {
    // 1 mm/s scan 0 → 20 mm sampled at 1 Hz, a 10 s dwell, then back at 2 mm/s.
    let mut x: Vec<f64> = (0..=20).map(f64::from).collect();
    x.extend(std::iter::repeat_n(20.0, 10));
    x.extend((0..10).map(|k| 18.0 - 2.0 * f64::from(k)));
    let n = x.len();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), (0..n).map(|i| i as f64).collect()),
        ("x_mm".into(), x.clone()),
        ("ex_um".into(), vec![0.0; n]),
        ("sim_ex_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let ctx = Context::from_recording(&rec);
    let f = ctx.axis('x').unwrap();
    let vel = f.vel_mm_s();
    for i in 0..n {
        let still = (i > 0 && x[i] == x[i - 1]) || (i + 1 < n && x[i] == x[i + 1]);
        if still {
            assert_eq!(vel[i], 0.0, "row {i} at standstill");
        } else {
            let want = if i < 20 { 1.0 } else { -2.0 };
            assert!((vel[i] - want).abs() < 1e-9, "row {i}: {}", vel[i]);
        }
    }
    assert!(library(&ctx, 'x').iter().any(|c| c.kind == Kind::ServoLag));
}

#[test]
fn diagnose_owned_gives_the_report_of_diagnose() {
    // `retrocomp diagnose` without --out hands the recording over, so the error and sim columns
    // are freed once the residuals are formed (issue 12 item 10): the report must not change.
    let (rec, _) = step_and_dwell();
    let a = diagnose(&rec, &Options::default()).unwrap();
    let b = retrocomp_analysis::diagnose::diagnose_owned(rec, &Options::default()).unwrap();
    assert!(!a.report.findings.is_empty());
    assert_eq!(
        serde_json::to_string(&a.report).unwrap(),
        serde_json::to_string(&b.report).unwrap()
    );
}
