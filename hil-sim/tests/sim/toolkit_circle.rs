//! Issue 6 item 3 on simulator output: the circular-test diagnosis (`retrocomp_analysis::circular`)
//! recovers the hidden errors injected into hil-sim, each within 10 %, from CW and CCW circles
//! recorded like a ballbar would see them, and the terms that were not injected come out near zero.
//!
//! Trace: actual tool tip = nominal (`x_mm`, `y_mm`) + recorded error (`ex_um`, `ey_um`, actual −
//! nominal); Δr = |actual − centre| − R (µm), θ = angle of the actual position about the nominal centre
//! (the ballbar pivot). Only the second revolution of each direction is used (the first one is the
//! run-in: servo transient and backlash take-up after the approach move).
//!
//! Injected → analysis parameter (conventions in `circular.rs` and `truth.rs`):
//! - `[hidden.backlash.x] b_um` → `backlash_x.b_um` (sim: after a + move the error is −b/2; analysis:
//!   ex = −(b/2)·sgn vx), same for Y.
//! - `ec0y_urad` (built-in: ex += ec0y·y) → `squareness.urad` (ex = α·y).
//! - `exx_ppm − eyy_ppm` → `scale_mismatch.ppm`.
//! - `[hidden.cyclic.x] amplitude_um` → `cyclic_x.amplitude_um` (period given to the analysis).
//!
//! Servo mismatch cannot be injected: the simulator has one `[servo]` gain for all axes, so τx = τy
//! and the analysis must report Δτ ≈ 0 although each axis lags by 1/kv = 33 ms.

use crate::sim_common;
use std::collections::BTreeMap;
use std::f64::consts::{PI, TAU};

use hil_sim::World;
use hil_sim::recording::run_to_end;
use retrocomp_analysis::circular::{CircleReport, CircleSetup, CircleTrace, Rotation, analyse};
use sim_common::{cfg, col, read_csv};

const R_MM: f64 = 50.0;
const FEED_MM_MIN: f64 = 600.0;

/// Hidden truth of the simulated machine (the numbers are the test's; the analysis never sees them).
const B_X_UM: f64 = 6.0;
const B_Y_UM: f64 = 4.0;
const EC0Y_URAD: f64 = 30.0;
const EXX_PPM: f64 = 20.0;
const EYY_PPM: f64 = -10.0;
const CYCLIC_X_UM: f64 = 1.5;
const CYCLIC_PERIOD_MM: f64 = 4.0;

fn config(backlash: bool, geometry: bool, cyclic: bool) -> String {
    let mut s = format!(
        r#"
seed = 11
[clock]
servo_hz = 1000.0
[program]
tool_mm = 100.0
start_mm = [0.0, 0.0, 0.0]
gcode = """
G90 G21
G1 F2000 X{R_MM} Y0
G3 F{FEED_MM_MIN} X{R_MM} Y0 I-{R_MM} J0
G3 X{R_MM} Y0 I-{R_MM} J0
G4 P0.5
G2 X{R_MM} Y0 I-{R_MM} J0
G2 X{R_MM} Y0 I-{R_MM} J0
M30
"""
[servo]
kv_per_s = 30.0
feedforward = 0.0
velocity_tau_s = 0.002
count_um = 0.1
[hidden]
error_noise_um = 0.1
[record]
every_s = 0.01
"#
    );
    if geometry {
        s += &format!(
            "[truth.builtin]\nexx_ppm = {EXX_PPM}\neyy_ppm = {EYY_PPM}\nec0y_urad = {EC0Y_URAD}\n"
        );
    }
    if backlash {
        s += &format!(
            "[hidden.backlash.x]\nb_um = {B_X_UM}\n[hidden.backlash.y]\nb_um = {B_Y_UM}\n"
        );
    }
    if cyclic {
        s += &format!(
            "[hidden.cyclic.x]\nperiod_mm = {CYCLIC_PERIOD_MM}\namplitude_um = {CYCLIC_X_UM}\nphase_rad = 0.7\n"
        );
    }
    s
}

/// Runs the simulator and cuts the recording into the second CCW and the second CW revolution.
fn traces(toml: &str) -> Vec<CircleTrace> {
    let mut w = World::new(cfg(toml)).unwrap();
    let (bytes, _) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    let (h, rows) = read_csv(&bytes);
    let idx: Vec<usize> = ["x_mm", "y_mm", "ex_um", "ey_um"]
        .iter()
        .map(|c| col(&h, c))
        .collect();
    let mut ccw = CircleTrace {
        rotation: Rotation::Ccw,
        angle_rad: vec![],
        dr_um: vec![],
    };
    let mut cw = CircleTrace {
        rotation: Rotation::Cw,
        angle_rad: vec![],
        dr_um: vec![],
    };
    // Unwrapped nominal angle: 0 → 4π (two CCW turns), then back to 0 (two CW turns).
    let (mut phi, mut last, mut reached_top) = (0.0f64, None::<f64>, false);
    for row in &rows {
        let v: Vec<f64> = idx.iter().map(|&i| row[i].parse().unwrap()).collect();
        let (xn, yn) = (v[0], v[1]);
        if ((xn.hypot(yn)) - R_MM).abs() > 1e-6 {
            continue; // approach move
        }
        let a = yn.atan2(xn);
        if let Some(l) = last {
            let mut d = a - l;
            d -= TAU * (d / TAU).round();
            phi += d;
        }
        last = Some(a);
        if phi > 2.0 * TAU - 1e-9 {
            reached_top = true;
        }
        let (xa, ya) = (xn + v[2] / 1000.0, yn + v[3] / 1000.0);
        let theta = ya.atan2(xa);
        let dr_um = (xa.hypot(ya) - R_MM) * 1000.0;
        let in_second_turn = phi > TAU + 1e-9 && phi < 2.0 * TAU - 1e-9;
        let in_first_turn = phi > 1e-9 && phi < TAU - 1e-9;
        if !reached_top && in_second_turn {
            ccw.angle_rad.push(theta);
            ccw.dr_um.push(dr_um);
        } else if reached_top && in_first_turn {
            cw.angle_rad.push(theta);
            cw.dr_um.push(dr_um);
        }
    }
    // One revolution at 600 mm/min and 100 Hz sampling: 2π·50/10 s · 100 = 3140 samples.
    for t in [&ccw, &cw] {
        assert!(
            t.angle_rad.len() > 3000,
            "{:?}: {} samples",
            t.rotation,
            t.angle_rad.len()
        );
        let span = t.angle_rad.iter().cloned().fold(-PI, f64::max)
            - t.angle_rad.iter().cloned().fold(PI, f64::min);
        assert!(span > 6.2, "{:?} covers {span} rad", t.rotation);
    }
    vec![ccw, cw]
}

fn run(backlash: bool, geometry: bool, cyclic: bool) -> CircleReport {
    let setup = CircleSetup {
        radius_mm: R_MM,
        feed_mm_per_min: FEED_MM_MIN,
        cyclic_period_x_mm: Some(CYCLIC_PERIOD_MM),
        cyclic_period_y_mm: Some(CYCLIC_PERIOD_MM),
    };
    let rep = analyse(&traces(&config(backlash, geometry, cyclic)), &setup).unwrap();
    eprintln!("{}", retrocomp_analysis::circular::to_text(&rep));
    rep
}

fn params(rep: &CircleReport) -> BTreeMap<String, f64> {
    rep.terms
        .iter()
        .flat_map(|t| {
            t.params
                .iter()
                .map(move |(k, v)| (format!("{}.{k}", t.effect), *v))
        })
        .collect()
}

fn within_10pct(p: &BTreeMap<String, f64>, key: &str, injected: f64) {
    let got = p[key];
    assert!(
        (got - injected).abs() <= 0.1 * injected.abs(),
        "{key}: recovered {got}, injected {injected}"
    );
}

fn contribution(rep: &CircleReport, effect: &str) -> f64 {
    rep.terms
        .iter()
        .find(|t| t.effect == effect)
        .unwrap_or_else(|| panic!("{effect} not reported"))
        .contribution_um
}

#[test]
fn every_injected_error_is_recovered_within_10_percent() {
    let rep = run(true, true, true);
    let p = params(&rep);
    within_10pct(&p, "backlash_x.b_um", B_X_UM);
    within_10pct(&p, "backlash_y.b_um", B_Y_UM);
    within_10pct(&p, "squareness.urad", EC0Y_URAD);
    within_10pct(&p, "scale_mismatch.ppm", EXX_PPM - EYY_PPM);
    within_10pct(&p, "cyclic_x.amplitude_um", CYCLIC_X_UM);
    // Not injected: each below 0.3 µm peak-to-valley of radial deviation, against ≥ 1.5 µm for the
    // injected ones; servo mismatch (equal gains) below 0.5 ms against τ = 33 ms per axis.
    for effect in [
        "lateral_play_x",
        "lateral_play_y",
        "cyclic_y",
        "straightness_x",
        "straightness_y",
        "servo_mismatch",
    ] {
        let c = contribution(&rep, effect);
        assert!(c < 0.3, "{effect}: {c} µm although not injected");
    }
    assert!(p["servo_mismatch.ms"].abs() < 0.5, "{p:?}");
    for effect in ["backlash_x", "backlash_y", "squareness", "scale_mismatch"] {
        assert!(contribution(&rep, effect) > 1.0, "{effect}");
    }
    takeup_is_reported_as_a_reversal_spike(&rep);
}

/// KNOWN LIMITATION of the diagnosis (not of the simulator): lost motion b is taken up over b of
/// axis travel, which on a circle near the reversal quadrant is a path of s_b = R·acos(1 − b/R)
/// ≈ √(2Rb) (0.77 mm for X, 0.63 mm for Y here). The analysis models backlash as a step at the
/// quadrant, so the take-up ramp is fitted as a `reversal_spike` (with a negative amplitude, i.e. the
/// error keeps its pre-reversal sign for a while) that the machine does not have. Asserted here as it
/// is, so that a change to the backlash model in `circular.rs` shows up: the spike decays within the
/// take-up path and only appears with backlash (see the geometry-only case).
fn takeup_is_reported_as_a_reversal_spike(rep: &CircleReport) {
    let p = params(rep);
    for (axis, b_um) in [("x", B_X_UM), ("y", B_Y_UM)] {
        let s_b_mm = R_MM * (1.0 - b_um / 1000.0 / R_MM).acos();
        let a = p[&format!("reversal_spike_{axis}.amplitude_um")];
        let decay = p[&format!("reversal_spike_{axis}.decay_mm")];
        assert!(a < -b_um / 2.0, "{axis}: spike amplitude {a}");
        assert!(
            decay > 0.0 && decay < s_b_mm,
            "{axis}: decay {decay} mm vs take-up {s_b_mm} mm"
        );
    }
}

#[test]
fn each_error_alone_is_recovered_and_nothing_else_appears() {
    // Backlash only: geometry and cyclic terms must vanish; geometry only: backlash must vanish.
    let rep = run(true, false, false);
    let p = params(&rep);
    within_10pct(&p, "backlash_x.b_um", B_X_UM);
    within_10pct(&p, "backlash_y.b_um", B_Y_UM);
    assert!(p["squareness.urad"].abs() < 0.1 * EC0Y_URAD, "{p:?}");
    assert!(
        p["scale_mismatch.ppm"].abs() < 0.1 * (EXX_PPM - EYY_PPM),
        "{p:?}"
    );
    assert!(p["cyclic_x.amplitude_um"] < 0.1 * CYCLIC_X_UM, "{p:?}");
    takeup_is_reported_as_a_reversal_spike(&rep);

    let rep = run(false, true, false);
    let p = params(&rep);
    within_10pct(&p, "squareness.urad", EC0Y_URAD);
    within_10pct(&p, "scale_mismatch.ppm", EXX_PPM - EYY_PPM);
    assert!(p["backlash_x.b_um"].abs() < 0.1 * B_X_UM, "{p:?}");
    assert!(p["backlash_y.b_um"].abs() < 0.1 * B_Y_UM, "{p:?}");
    for effect in ["reversal_spike_x", "reversal_spike_y", "servo_mismatch"] {
        let c = contribution(&rep, effect);
        assert!(c < 0.3, "{effect}: {c} µm without backlash");
    }
}
