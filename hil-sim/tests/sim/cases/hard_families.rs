//! The hard case families of `hil-sim gen-cases` (issue 12 item 6) have the properties they claim:
//! AR(0.99) noise, random-walk noise (unit root, i.i.d. increments), spurious random-walk decoys
//! that track the noise without sharing its increments, a heat source seen only through `rpm`
//! with no temperature channel near it, a drifting ambient, and an rpm regime the first 60 % never
//! shows. These are properties of the GENERATOR, checked on the recordings it writes (the
//! residual r = e − sim of a null case is its noise); diagnose's scores on these families are
//! `cases_hard_benchmark.rs`. The standard family's output is locked to what it was before the
//! families existed, so earlier benchmark figures stay comparable.

use std::process::Command;

use hil_sim::cases::{Family, generate_case, generate_family_case};
use retrocomp_analysis::diagnose::effects::EffectModel;
use retrocomp_analysis::diagnose::features::{Context, lowpass};
use retrocomp_analysis::diagnose::scoring::read_manifest;
use retrocomp_model::recording::Recording;

const NULLS: [usize; 6] = [0, 1, 2, 10, 11, 12];

fn col<'a>(rec: &'a Recording, name: &str) -> &'a [f64] {
    rec.col(name)
        .unwrap_or_else(|| panic!("recording has no `{name}`"))
}

fn residual(rec: &Recording, sig: &str) -> Vec<f64> {
    col(rec, sig)
        .iter()
        .zip(col(rec, &format!("sim_{sig}")))
        .map(|(a, b)| a - b)
        .collect()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn corr(a: &[f64], b: &[f64]) -> f64 {
    let (ma, mb) = (mean(a), mean(b));
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        ab += (x - ma) * (y - mb);
        aa += (x - ma).powi(2);
        bb += (y - mb).powi(2);
    }
    ab / (aa * bb).sqrt()
}

/// Least-squares AR(1) coefficient of the centred series.
fn ar1(v: &[f64]) -> f64 {
    let m = mean(v);
    let (mut num, mut den) = (0.0, 0.0);
    for w in v.windows(2) {
        num += (w[1] - m) * (w[0] - m);
        den += (w[0] - m).powi(2);
    }
    num / den
}

/// Dickey–Fuller t statistic: Δy_t = a + b·y_{t−1} + ε, t of b. A unit root is NOT rejected at
/// 1 % while t > −3.46 (with constant, n ≈ 200).
fn dickey_fuller_t(y: &[f64]) -> f64 {
    let x: Vec<f64> = y[..y.len() - 1].to_vec();
    let d: Vec<f64> = y.windows(2).map(|w| w[1] - w[0]).collect();
    let (mx, md) = (mean(&x), mean(&d));
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    let b = x
        .iter()
        .zip(&d)
        .map(|(a, c)| (a - mx) * (c - md))
        .sum::<f64>()
        / sxx;
    let rss: f64 = x
        .iter()
        .zip(&d)
        .map(|(a, c)| (c - md - b * (a - mx)).powi(2))
        .sum();
    let s2 = rss / (d.len() - 2) as f64;
    b / (s2 / sxx).sqrt()
}

fn every(v: &[f64], k: usize) -> Vec<f64> {
    v.iter().step_by(k).copied().collect()
}

fn diffs(v: &[f64]) -> Vec<f64> {
    v.windows(2).map(|w| w[1] - w[0]).collect()
}

fn csv_bytes(rec: &Recording) -> Vec<u8> {
    let mut w = vec![];
    rec.write_csv(&mut w).unwrap();
    w
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

#[test]
fn standard_family_output_is_unchanged_and_hard_families_are_deterministic() {
    // FNV-1a of the CSVs `hil-sim gen-cases --seed 1` writes: the standard cases, and so the
    // published figures, are these recordings. They were unchanged from commit c8d149a until
    // session 17, when the lag kernel's convention for readings (`models::lag::series`, each
    // reading held over the interval it ends, as the gateway runs it) moved the sensors' and the
    // effects' lags by one sample; the benchmark was measured again on the new recordings (seed 1
    // and 2: recall 0.985, FPR 0, unchanged; README).
    for (i, h) in [
        (0, 0xe4a5_e22d_f136_7500_u64),
        (3, 0xfd2b_1d07_6beb_6f87),
        (47, 0x3e28_4e7d_10ec_dd2c),
        (99, 0x46cd_5609_5d45_ba1f),
    ] {
        let (rec, m) = generate_family_case(Family::Standard, 1, i);
        assert_eq!(fnv1a(&csv_bytes(&rec)), h, "standard case {i} changed");
        assert_eq!(m.family, "standard");
        assert_eq!(m.case, format!("case_{i:04}"));
        assert!(m.family_params.is_empty());
    }
    let mut seen = vec![];
    for fam in Family::HARD {
        let (a, ma) = generate_family_case(fam, 3, 4);
        let (b, mb) = generate_family_case(fam, 3, 4);
        let (c, _) = generate_family_case(fam, 4, 4);
        let wa = csv_bytes(&a);
        assert_eq!(
            wa,
            csv_bytes(&b),
            "{fam:?}: same (seed, index) must be identical"
        );
        assert_eq!(ma, mb);
        assert_ne!(wa, csv_bytes(&c), "{fam:?}: another seed, another case");
        assert_eq!(ma.family, fam.name());
        assert_eq!(ma.case, format!("{}_0004", fam.name()));
        assert_eq!(ma.hidden.len(), 1, "index 4 is an effect case");
        assert!(
            (1.0..=4.0).contains(&ma.snr.unwrap()),
            "effect/noise in the targets' range"
        );
        assert!(!seen.contains(&wa), "{fam:?} repeats another family's case");
        seen.push(wa);
        assert!(generate_family_case(fam, 3, 0).1.hidden.is_empty());
    }
    // Standard through the family entry point is the old generator.
    assert_eq!(
        csv_bytes(&generate_family_case(Family::Standard, 5, 7).0),
        csv_bytes(&generate_case(5, 7).0)
    );
}

#[test]
fn ar099_noise_has_lag_one_autocorrelation_0_99() {
    let mut rhos = vec![];
    for i in NULLS {
        let (rec, m) = generate_family_case(Family::Ar099, 11, i);
        assert!(m.hidden.is_empty());
        assert_eq!(m.family_params["noise_ar_rho"], 0.99);
        for sig in ["ex_um", "ey_um"] {
            let r = residual(&rec, sig);
            let rho = ar1(&r);
            assert!((0.975..1.0).contains(&rho), "{} {sig}: rho {rho}", m.case);
            let sd =
                (r.iter().map(|v| (v - mean(&r)).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
            assert!(
                (0.5..1.5).contains(&(sd / m.noise_um)),
                "{} {sig}: sd {sd} vs noise_um {}",
                m.case,
                m.noise_um
            );
            rhos.push(rho);
        }
    }
    assert!(
        (mean(&rhos) - 0.99).abs() < 0.005,
        "mean rho {}",
        mean(&rhos)
    );
    // The standard family's noise is far less persistent (white + AR(0.9)).
    for i in NULLS {
        let rho = ar1(&residual(&generate_case(11, i).0, "ex_um"));
        assert!(rho < 0.8, "standard null {i}: rho {rho}");
    }
}

#[test]
fn random_walk_noise_has_a_unit_root_and_independent_increments() {
    for fam in [Family::RandomWalk, Family::RwDecoy] {
        let mut inc_corr = vec![];
        for i in NULLS {
            let (rec, m) = generate_family_case(fam, 12, i);
            for sig in ["ex_um", "ey_um"] {
                let r = residual(&rec, sig);
                let sd =
                    (r.iter().map(|v| (v - mean(&r)).powi(2)).sum::<f64>() / r.len() as f64).sqrt();
                assert!(
                    (sd / m.noise_um - 1.0).abs() < 0.05,
                    "{} {sig}: centred RMS {sd} vs noise_um {}",
                    m.case,
                    m.noise_um
                );
                // Every 20th sample: the 0.05 µm quantisation is small against 20 increments.
                let y = every(&r, 20);
                let t = dickey_fuller_t(&y);
                assert!(t > -3.46, "{} {sig}: unit root rejected, DF t {t}", m.case);
                let d = diffs(&y);
                inc_corr.push(corr(&d[1..], &d[..d.len() - 1]));
            }
        }
        let c = mean(&inc_corr);
        assert!(c.abs() < 0.08, "{fam:?}: increments correlated, lag-1 {c}");
    }
    // The same test rejects a unit root for the AR(0.99) family: it can tell them apart.
    for i in NULLS {
        let y = every(
            &residual(&generate_family_case(Family::Ar099, 12, i).0, "ex_um"),
            20,
        );
        let t = dickey_fuller_t(&y);
        assert!(t < -3.46, "ar099 null {i}: DF t {t}");
    }
}

#[test]
fn rw_decoy_channels_track_the_noise_without_sharing_its_increments() {
    let mut inc = vec![];
    for i in NULLS {
        let (rec, m) = generate_family_case(Family::RwDecoy, 13, i);
        for (decoy, sig, key) in [
            ("T_decoy_C", "ex_um", "decoy_corr_ex"),
            ("aux_V", "ey_um", "aux_corr_ey"),
        ] {
            let (d, r) = (col(&rec, decoy), residual(&rec, sig));
            let c = corr(d, &r);
            assert!(c.abs() >= 0.5, "{} {decoy}: corr with noise {c}", m.case);
            assert!(
                (c - m.family_params[key]).abs() < 0.05,
                "{} {decoy}: recorded {c}, manifest {}",
                m.case,
                m.family_params[key]
            );
            assert!(m.decoys.iter().any(|n| n == decoy));
            let (dd, dr) = (diffs(&every(d, 20)), diffs(&every(&r, 20)));
            inc.push(corr(&dd, &dr));
        }
    }
    // Correlated in level by selection, not by cause: the increments are independent.
    let c = mean(&inc);
    assert!(
        c.abs() < 0.08,
        "decoy and noise increments correlate: {c} ({inc:?})"
    );
}

#[test]
fn rpm_heat_source_has_no_temperature_channel_near_it() {
    let taus = [1.0, 60.0, 300.0, 1000.0, 3000.0];
    // 300 s changes every 30 s: a sensor near the source follows the rpm steps; a channel that
    // merely warms up over the day (the column, by axis friction) does not.
    let changes = |v: &[f64]| -> Vec<f64> {
        (300..v.len())
            .step_by(30)
            .map(|i| v[i] - v[i - 300])
            .collect()
    };
    let best_temp_corr = |rec: &Recording, h: &[f64]| -> (String, f64) {
        let t = col(rec, "t_s");
        let dh = changes(h);
        rec.temperature_channels()
            .into_iter()
            .flat_map(|n| {
                let v = col(rec, &n).to_vec();
                taus.iter()
                    .map(|&tau| (n.clone(), corr(&changes(&lowpass(t, &v, tau)), &dh).abs()))
                    .collect::<Vec<_>>()
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap()
    };
    for i in 3..10 {
        let (rec, m) = generate_family_case(Family::RpmHeat, 14, i);
        assert!(rec.col("T_spindle_C").is_none(), "no sensor at the spindle");
        let [h] = m.hidden.as_slice() else {
            panic!("{}: one hidden effect", m.case)
        };
        let EffectModel::ThermalLag { sensor, tau_s, .. } = &h.model else {
            panic!("{}: {:?}", m.case, h.model)
        };
        assert_eq!(sensor, "rpm");
        assert!((300.0..=1200.0).contains(tau_s));
        let rpm = col(&rec, "rpm");
        assert_eq!(rpm[0], 0.0, "the machine starts cold");
        let mut levels: Vec<i64> = rpm.iter().map(|v| *v as i64).filter(|v| *v > 0).collect();
        levels.sort_unstable();
        levels.dedup();
        assert!(levels.len() >= 3, "{}: rpm levels {levels:?}", m.case);
        let mut ctx = Context::from_recording(&rec);
        ctx.temps.push(("rpm".into(), rpm.into()));
        let term = h.model.evaluate('x', &ctx).unwrap();
        let (name, c) = best_temp_corr(&rec, &term);
        eprintln!(
            "{}: best temperature {name} |corr| of changes {c:.3}",
            m.case
        );
        assert!(
            c < 0.8,
            "{}: {name} tracks the rpm heat source (|corr| {c})",
            m.case
        );
    }
    // Contrast: where a spindle sensor exists (regime family) it does track its rpm through a lag.
    let (rec, _) = generate_family_case(Family::Regime, 14, 3);
    let t = col(&rec, "t_s");
    let heat = lowpass(t, col(&rec, "rpm"), 500.0);
    let (name, c) = best_temp_corr(&rec, &heat);
    eprintln!("regime contrast: {name} {c:.3}");
    assert!(c > 0.9, "regime: best temperature {name} |corr| {c}");
}

#[test]
fn ambient_drift_moves_the_ambient_sensor_by_kelvins() {
    for i in 0..6 {
        let (rec, m) = generate_family_case(Family::AmbientDrift, 15, i);
        let p = &m.family_params;
        let (ramp, amp, period, phase) = (
            p["ambient_ramp_K"],
            p["ambient_wave_K"],
            p["ambient_wave_period_s"],
            p["ambient_wave_phase_rad"],
        );
        assert!((1.0..=4.0).contains(&ramp.abs()), "{}: ramp {ramp}", m.case);
        let t = col(&rec, "t_s");
        let d = t[t.len() - 1];
        let amb: Vec<f64> = t
            .iter()
            .map(|&x| {
                20.0 + ramp * x / d + amp * (std::f64::consts::TAU * x / period + phase).sin()
                    - amp * phase.sin()
            })
            .collect();
        // The sensor reads that ambient through its 60 s lag, 0.02 °C noise and 0.1 °C steps.
        let seen = lowpass(t, &amb, 60.0);
        let worst = col(&rec, "T_amb_C")
            .iter()
            .zip(&seen)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            worst < 0.15,
            "{}: T_amb_C off the drifting ambient by {worst}",
            m.case
        );
        let amb_range = |r: &Recording| {
            let v = col(r, "T_amb_C");
            v.iter().copied().fold(f64::MIN, f64::max) - v.iter().copied().fold(f64::MAX, f64::min)
        };
        assert!(
            amb_range(&rec) >= 0.8,
            "{}: range {}",
            m.case,
            amb_range(&rec)
        );
        let std_range = amb_range(&generate_case(15, i).0);
        assert!(
            std_range < 0.7,
            "standard case {i}: ambient range {std_range}"
        );
    }
}

#[test]
fn regime_later_part_runs_faster_than_anything_before() {
    for i in 0..6 {
        let (rec, m) = generate_family_case(Family::Regime, 16, i);
        let t = col(&rec, "t_s");
        let split = m.family_params["regime_split_s"];
        assert!((split / t[t.len() - 1] - 0.6).abs() < 1e-9);
        let rpm = col(&rec, "rpm");
        let early_max = t
            .iter()
            .zip(rpm)
            .filter(|(x, _)| **x < split)
            .map(|(_, r)| *r)
            .fold(0.0, f64::max);
        let late: Vec<f64> = t
            .iter()
            .zip(rpm)
            .filter(|(x, r)| **x >= split && **r > 0.0)
            .map(|(_, r)| *r)
            .collect();
        assert!(
            early_max <= 3000.0 && early_max > 0.0,
            "{}: early max {early_max}",
            m.case
        );
        assert!(!late.is_empty(), "{}: the late part runs", m.case);
        let late_min = late.iter().copied().fold(f64::MAX, f64::min);
        assert!(late_min >= 4500.0, "{}: late min {late_min}", m.case);
        assert!(rec.col("T_spindle_C").is_some());
    }
}

#[test]
fn gen_cases_families_option_writes_one_file_pair_per_family_case() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("cases");
    let o = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["gen-cases", "--seed", "9", "--count", "2"])
        .args(["--families", "ar099,regime", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "ar099_0000.csv",
            "ar099_0000.json",
            "ar099_0001.csv",
            "ar099_0001.json",
            "regime_0000.csv",
            "regime_0000.json",
            "regime_0001.csv",
            "regime_0001.json"
        ]
    );
    let m = read_manifest(&out.join("regime_0001.json")).unwrap();
    assert_eq!((m.family.as_str(), m.seed), ("regime", 9));
    assert!(m.family_params.contains_key("regime_split_s"));
    let bad = Command::new(env!("CARGO_BIN_EXE_hil-sim"))
        .args(["gen-cases", "--families", "brownian", "--out"])
        .arg(tmp.path().join("x"))
        .output()
        .unwrap();
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("unknown family `brownian`"), "{err}");
}
