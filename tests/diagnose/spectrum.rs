//! Issue 36 points 3 and 6 on their own benchmark families (generators in
//! `diagnose_spectrum_support`):
//!
//! * 3 — pitch errors are found wherever the positions can show them: the cyclic candidate scans
//!   the residual's least-squares periodogram over position down to ≈ 2 samples per period, and a
//!   second harmonic is fitted with its fundamental. Target: recall ≥ 0.95 with the period within
//!   1 % on steps that are not fractions of the period, periods 3–12 mm, ± a second harmonic.
//! * 6 — a step-and-dwell run offers no `servo_lag` (no reading at a commanded feed), so backlash
//!   under AR(0.99) noise is found at effect/noise 3.
//!
//! The CI tests run a few dozen cases; the full tables of docs/diagnose-results.md come from the
//! ignored `benchmark` test: `cargo test --workspace --test diagnose spectrum::benchmark --
//! --ignored --nocapture`.

use crate::diagnose_spectrum_support;

use diagnose_spectrum_support::{
    Pitch, Truth, ar099_backlash_case, pitch_case, pitch_recording, rng_for,
};
use retrocomp_analysis::diagnose::candidates::{Kind, library};
use retrocomp_analysis::diagnose::features::Context;
use retrocomp_analysis::diagnose::report::Report;
use retrocomp_analysis::diagnose::{diagnose, select::Options};
use retrocomp_model::recording::Recording;

/// The cyclic finding on X whose period is within 1 % of the truth, if any.
fn pitch_found(report: &Report, t: &Truth) -> Option<f64> {
    report
        .findings
        .iter()
        .filter(|f| f.effect == "cyclic_error" && f.axis == "x")
        .filter_map(|f| f.params["period_mm"].as_f64())
        .find(|p| (p - t.period_mm).abs() <= 0.01 * t.period_mm)
}

fn backlash_found(report: &Report, t: &Truth) -> bool {
    report.findings.iter().any(|f| {
        f.effect == "backlash"
            && f.axis == "x"
            && f.params["b_um"]
                .as_f64()
                .is_some_and(|b| (b - t.b_um).abs() <= 0.3 * t.b_um.abs())
    })
}

/// The findings as `effect params`, for failure messages.
fn listed(r: &Report) -> Vec<String> {
    r.findings
        .iter()
        .map(|f| format!("{} {:?}", f.effect, f.params))
        .collect()
}

fn run(rec: &Recording) -> Report {
    diagnose(rec, &Options::default())
        .expect("diagnose runs")
        .report
}

/// Pitch cases `0..n` of `seed`: (hits, misses as text).
fn pitch_recall(seed: u64, n: usize) -> (usize, Vec<String>) {
    let mut hits = 0;
    let mut misses = vec![];
    for i in 0..n {
        let (rec, t) = pitch_case(seed, i);
        let r = run(&rec);
        if pitch_found(&r, &t).is_some() {
            hits += 1;
        } else {
            let got = listed(&r);
            misses.push(format!(
                "pitch seed {seed} case {i}: period {:.3} mm, amplitude {:.2}, harmonic {:.2}, \
                 min step {:.3} mm, effect/noise {:.2}: verdict {}, found {got:?}",
                t.period_mm, t.amplitude_um, t.harmonic2_um, t.min_step_mm, t.snr, r.verdict
            ));
        }
    }
    (hits, misses)
}

#[test]
fn pitch_family_recall_is_at_least_095_with_the_period_within_1_percent() {
    let n = 24;
    let (hits, misses) = pitch_recall(36, n);
    assert!(
        hits as f64 >= 0.95 * n as f64,
        "recall {hits}/{n}:\n{}",
        misses.join("\n")
    );
}

#[test]
fn a_pitch_with_a_strong_harmonic_read_below_four_steps_per_period_is_found_as_one_fundamental() {
    // The shape of the confident wrong answer: a 6.35 mm pitch whose second harmonic is
    // stronger than the fundamental, read at steps of 2.6 and 2.9 mm (2.4 and 2.2 samples per
    // period: the harmonic is beyond the steps' Nyquist and aliases to a long period when it is
    // fitted on its own; the old rule scanned nothing below 4 steps on dense targets).
    let mut rng = rng_for(0x36, 36, 0);
    let p = Pitch {
        period_mm: 6.35,
        amplitude_um: 1.5,
        phase_rad: 0.4,
        harmonic2_um: 2.0,
        harmonic2_phase_rad: -1.1,
    };
    let (rec, t) = pitch_recording(&mut rng, &p, 150.0, &[2.6, 2.9], 3.0);
    let lib = library(&Context::from_recording(&rec), 'x');
    let shortest = lib
        .iter()
        .filter(|c| c.kind == Kind::CyclicHarmonic)
        .flat_map(|c| c.grid.iter().copied())
        .fold(f64::INFINITY, f64::min);
    assert!(
        shortest < 2.0 * t.min_step_mm,
        "shortest period scanned {shortest} mm"
    );
    let r = run(&rec);
    let f = r
        .findings
        .iter()
        .find(|f| f.effect == "cyclic_error")
        .unwrap_or_else(|| panic!("{}", r.to_text()));
    let period = f.params["period_mm"].as_f64().unwrap();
    let h2 = f.params["harmonic2_um"].as_f64().unwrap_or(0.0);
    assert!(
        (period - 6.35).abs() <= 0.01 * 6.35 && (h2 - 2.0).abs() < 0.3 * 2.0,
        "{}",
        r.to_text()
    );
}

#[test]
fn step_and_dwell_offers_no_servo_lag_and_ar099_backlash_is_found_at_effect_noise_3() {
    let n = 12;
    let mut misses = vec![];
    for i in 0..n {
        let (rec, t) = ar099_backlash_case(36, i, 3.0);
        let lib = library(&Context::from_recording(&rec), 'x');
        assert!(
            !lib.iter().any(|c| c.kind == Kind::ServoLag),
            "case {i}: servo_lag offered on a step-and-dwell run"
        );
        let r = run(&rec);
        if !backlash_found(&r, &t) {
            misses.push(format!(
                "case {i}: b {:.2} µm: verdict {}, {:?}",
                t.b_um,
                r.verdict,
                listed(&r)
            ));
        }
    }
    assert!(misses.is_empty(), "{}", misses.join("\n"));
}

/// The full tables of docs/diagnose-results.md (two seeds; recall per period band and harmonic,
/// backlash recall per effect/noise). Asserts only that every case was diagnosed.
#[test]
#[ignore = "benchmark: cargo test --workspace --test diagnose spectrum::benchmark -- --ignored --nocapture"]
fn benchmark() {
    let per_seed = 100;
    for seed in [1u64, 2] {
        let mut bands = [[(0usize, 0usize); 2]; 3];
        for i in 0..per_seed {
            let (rec, t) = pitch_case(seed, i);
            let r = run(&rec);
            let band = ((t.period_mm - 3.0) / 3.0).floor().clamp(0.0, 2.0) as usize;
            let cell = &mut bands[band][usize::from(t.harmonic2_um != 0.0)];
            cell.1 += 1;
            if pitch_found(&r, &t).is_some() {
                cell.0 += 1;
            } else {
                eprintln!(
                    "miss: pitch seed {seed} case {i}: period {:.3}, harmonic {:.2}, min step {:.3}, snr {:.2}, {:?}",
                    t.period_mm,
                    t.harmonic2_um,
                    t.min_step_mm,
                    t.snr,
                    listed(&r)
                );
            }
        }
        println!("pitch seed {seed}: | period band | fundamental only | + 2nd harmonic |");
        for (b, name) in ["3–6 mm", "6–9 mm", "9–12 mm"].iter().enumerate() {
            let [a, h] = bands[b];
            println!("| {name} | {}/{} | {}/{} |", a.0, a.1, h.0, h.1);
        }
        let (hit, all) = bands
            .iter()
            .flatten()
            .fold((0, 0), |s, c| (s.0 + c.0, s.1 + c.1));
        println!("| all | {hit}/{all} = {:.3} |", hit as f64 / all as f64);
        for snr in [1.0, 2.0, 3.0, 4.0] {
            let n = 40;
            let hits = (0..n)
                .filter(|&i| {
                    let (rec, t) = ar099_backlash_case(seed, i, snr);
                    let r = run(&rec);
                    let found = backlash_found(&r, &t);
                    if !found {
                        eprintln!(
                            "miss: ar099 backlash seed {seed} case {i} effect/noise {snr}: b {:.2} µm, verdict {}, {:?}",
                            t.b_um,
                            r.verdict,
                            listed(&r)
                        );
                    }
                    found
                })
                .count();
            println!("ar099 backlash seed {seed} effect/noise {snr}: {hits}/{n}");
        }
    }
}
