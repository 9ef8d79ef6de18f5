//! Real data: M. Asad Ullah (2013), Studer S-36, Table 6.2 "Measured Data (X-axis)" (thesis p. 42),
//! δxx forward (F) and reverse (R) laser readings at 0–170 mm, as a recording
//! (`tests/data/asadullah_table_6_2_x.csv`: F run then R run, one row per target, error µm) whose
//! simulation is linear positioning error only (the least-squares line through the F/R mean:
//! −0.85 µm + 94.3 ppm·x). What diagnose must say about it (docs/diagnose.md records it in words):
//! a reversal (backlash) of ≈ 9 µm — the thesis' F−R is 8.2–9.8 µm over 0–130 mm, collapsing beyond
//! 140 mm — that the table cannot separate from servo lag (no standstill information), and
//! unexplained structure in x ∈ [149, 170] mm, the steep δxx rise no library term names.

use std::path::Path;

use retrocomp::diagnose::{diagnose, select::Options};
use retrocomp::recording::Recording;

fn rec() -> Recording {
    Recording::read_path(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/asadullah_table_6_2_x.csv"),
    )
    .unwrap()
}

#[test]
fn fixture_is_table_6_2_with_a_linear_simulation() {
    let r = rec();
    assert_eq!(r.n_rows(), 36);
    let e = r.col("ex_um").unwrap();
    // Table 6.2: F at 0 mm = 0.0084 mm, F at 170 = 0.0305; R at 170 = 0.0290, R at 0 = −0.0004.
    assert_eq!((e[0], e[17], e[18], e[35]), (8.4, 30.5, 29.0, -0.4));
    let sim = r.col("sim_ex_um").unwrap();
    let slope_ppm = (sim[17] - sim[0]) / 170.0 * 1e3;
    assert!((slope_ppm - 94.3).abs() < 0.1, "{slope_ppm}");
}

#[test]
fn diagnose_reports_the_reversal_and_the_unnamed_rise_beyond_140_mm() {
    let d = diagnose(&rec(), &Options::default()).unwrap();
    let r = &d.report;
    assert!((r.rms_before_um - 6.89).abs() < 0.01, "{}", r.rms_before_um);
    let f = &r.findings[0];
    assert_eq!(
        (f.effect.as_str(), f.axis.as_str()),
        ("backlash", "x"),
        "{}",
        r.to_text()
    );
    let b = f.params["b_um"].as_f64().unwrap();
    // Mean F−R over all 18 targets of Table 6.2 is 6.6 µm; over 0–130 mm 9.3 µm; the fit sits between.
    assert!((6.0..=10.5).contains(&b), "b_um {b}");
    assert!(f.heldout_rms_after_um < f.heldout_rms_before_um);
    // One row per target, no dwell rows: velocity and direction coincide, so servo lag is an
    // honest alternative and the verdict is ambiguous, naming the experiment.
    assert_eq!(r.verdict, "ambiguous");
    let alt = r
        .alternatives
        .iter()
        .find(|a| a.effect == "servo_lag")
        .expect("servo_lag alternative");
    assert!(alt.experiment.as_deref().unwrap().contains("standstill"));
    // The rise beyond 140 mm is reported as unexplained structure, not forced into a name.
    let u = r
        .mismatch
        .iter()
        .find(|m| m.where_.starts_with("unexplained structure vs x_mm"))
        .expect("unexplained");
    assert!(u.where_.contains("[148.8, 170.0]"), "{}", u.where_);
}
