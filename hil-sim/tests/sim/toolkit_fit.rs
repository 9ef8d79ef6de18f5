//! Issue 6 item 6 on simulator output: `retrocomp_analysis::fit` on hil-sim recordings with known
//! truth, validated on data held out from the fit.
//!
//! - Thermal: a warm-up / cool-down cycle (spindle at two speeds, X shuttling at other times, ambient
//!   drifting) with the spindle growth on Z hidden in the machine. `fit_context` (subset selection by
//!   BIC over three temperature sensors) must pick exactly the sensor(s) the truth manifest lists for
//!   the `ez_um` effect, and reach Spaan's efficiency δ ≥ 0.9 on the last 30 % (the final cool-down,
//!   never seen by the fit).
//! - Axis: laser-style bidirectional runs of X (5 runs, targets every 15 mm, dwell at each) on a
//!   machine with scale error and lost motion that varies along X; `fit_axis` on runs 1–4 must predict
//!   run 5 with δ ≥ 0.9, and the fitted reversal must match the hidden lost-motion profile.
//!
//! Sign: error = actual − nominal (ISO 230-2), µm.

use crate::sim_common;
use std::fmt::Write;

use hil_sim::World;
use hil_sim::recording::run_to_end;
use retrocomp_analysis::fit::regression::Criterion;
use retrocomp_analysis::fit::workflow::{fit_axis, fit_context};
use retrocomp_analysis::iso230_2::Reading;
use retrocomp_analysis::table::Direction;
use retrocomp_model::recording::Recording;
use sim_common::{cfg, col, read_csv};

/// Appends `n` X round trips 0 → 200 → 0 mm at 3000 mm/min (8 s each).
fn shuttle(g: &mut String, n: usize) {
    for _ in 0..n {
        g.push_str("G1 F3000 X200\nG1 X0\n");
    }
}

fn thermal_config(sensor_tau_s: f64) -> String {
    let mut g = String::from("G90 G21\nG0 X0 Y50 Z0\nS6000 M3\nG4 P500\nM5\n");
    shuttle(&mut g, 38); // ≈ 300 s of X motion, spindle off: heats the X screw only
    g.push_str("G4 P300\nS3000 M3\n");
    shuttle(&mut g, 25); // ≈ 200 s: both sources together at another ratio
    g.push_str("G4 P300\nM5\nG4 P600\nM30\n");
    format!(
        r#"
seed = 5
[clock]
servo_hz = 100.0
[program]
tool_mm = 100.0
start_mm = [0.0, 50.0, 0.0]
gcode = """
{g}"""
[servo]
ideal = true
[hidden]
error_noise_um = 0.1
[hidden.thermal]
ambient_C = 20.0
ambient_drift_C_per_h = 0.5
[[hidden.thermal.nodes]]
name = "spindle"
tau_s = 300.0
rise_C_per_krpm = 2.0
[[hidden.thermal.nodes]]
name = "xscrew"
tau_s = 200.0
rise_C_per_mm_s = {{ x = 0.1 }}
[[hidden.thermal.sensors]]
name = "spindle"
node = "spindle"
tau_s = {sensor_tau_s}
noise_C = 0.02
[[hidden.thermal.sensors]]
name = "xscrew"
node = "xscrew"
tau_s = 2.0
noise_C = 0.02
[[hidden.thermal.sensors]]
name = "ambient"
node = "ambient"
noise_C = 0.02
[[hidden.thermal.effects]]
kind = "growth"
node = "spindle"
axis = "z"
um_per_K = -6.0
[[hidden.thermal.effects]]
kind = "expansion"
node = "xscrew"
axis = "x"
ppm_per_K = 11.5
[record]
every_s = 1.0
"#
    )
}

struct ThermalRun {
    rec: Recording,
    /// The sensors the truth manifest attaches to the effects on `ez_um`.
    truth: Vec<String>,
}

fn thermal_run(sensor_tau_s: f64) -> ThermalRun {
    let mut w = World::new(cfg(&thermal_config(sensor_tau_s))).unwrap();
    let manifest = w.manifest();
    let (bytes, rows) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    assert!(rows > 2000, "{rows} rows");
    let text = String::from_utf8(bytes).unwrap();
    let rec = Recording::read_strict(text.as_bytes(), "thermal.csv").unwrap();
    let mut truth: Vec<String> = manifest["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["signal"] == "ez_um")
        .flat_map(|e| e["sensors"].as_array().cloned().unwrap_or_default())
        .map(|s| s["sensor"].as_str().unwrap().to_string())
        .collect();
    truth.sort();
    assert_eq!(truth, ["T_spindle_C"], "manifest: {manifest}");
    // The error must be sizeable and the decoy sensors must really move, else selection is trivial.
    let span = |name: &str| {
        let v = rec.col(name).unwrap();
        v.iter().cloned().fold(f64::MIN, f64::max) - v.iter().cloned().fold(f64::MAX, f64::min)
    };
    assert!(span("ez_um") > 30.0, "ez span {}", span("ez_um"));
    assert!(
        span("T_xscrew_C") > 3.0,
        "xscrew span {}",
        span("T_xscrew_C")
    );
    assert!(
        span("T_ambient_C") > 0.2,
        "ambient span {}",
        span("T_ambient_C")
    );
    ThermalRun { rec, truth }
}

fn chosen(fit: &retrocomp_analysis::fit::workflow::ContextFit) -> Vec<String> {
    let mut c: Vec<String> = fit.model.terms.iter().map(|t| t.signal.clone()).collect();
    c.sort();
    c
}

#[test]
fn thermal_fit_with_a_lag_free_sensor_selects_exactly_the_driving_sensor() {
    let run = thermal_run(0.0);
    for criterion in [Criterion::Bic, Criterion::Cp] {
        let fit = fit_context(&run.rec, "ez_um", true, false, &[0.0], 3, criterion, &[]).unwrap();
        eprintln!(
            "{criterion:?}: {:?}, δ = {:.4}, max residual {:.3} µm on {}",
            fit.model.terms, fit.heldout.delta, fit.heldout.max_residual_um, fit.heldout_rule
        );
        assert_eq!(chosen(&fit), run.truth, "{criterion:?}");
        let k = fit.model.terms[0].coef;
        assert!((k + 6.0).abs() < 0.12, "coef {k} µm/K vs the hidden −6");
        // δ ≥ 0.95: the held-out residual is 0.1 µm error noise and 6 µm/K × 0.02 °C sensor noise
        // (mean |.| ≈ 0.1 µm) against a mean |ez| of ≈ 10 µm on the final cool-down.
        assert!(fit.heldout.delta >= 0.95, "δ = {}", fit.heldout.delta);
    }
}

/// A sensor that reads its node through a 5 s lag (realistic) leaves a systematic residual
/// −6 µm/K × τ × dT/dt (up to ≈ 1 µm in the transients) that noise-based criteria (BIC, Cp) treat as
/// signal: both add the X-screw sensor (≈ +0.26 µm/K) to explain it during the X shuttle. What
/// holds and is asserted: the best single sensor is the driving one, it carries the model (its
/// coefficient within 3 % of the hidden one), and the held-out efficiency stays ≥ 0.9.
#[test]
fn thermal_fit_with_a_lagged_sensor_keeps_the_driving_sensor_and_predicts_the_cool_down() {
    let run = thermal_run(5.0);
    let single = fit_context(
        &run.rec,
        "ez_um",
        true,
        false,
        &[0.0],
        1,
        Criterion::Bic,
        &[],
    )
    .unwrap();
    let bic = fit_context(
        &run.rec,
        "ez_um",
        true,
        false,
        &[0.0],
        3,
        Criterion::Bic,
        &[],
    )
    .unwrap();
    for (name, fit) in [("best single", &single), ("BIC", &bic)] {
        eprintln!(
            "{name}: {:?}, δ = {:.4}, max residual {:.3} µm",
            fit.model.terms, fit.heldout.delta, fit.heldout.max_residual_um
        );
    }
    assert_eq!(chosen(&single), run.truth);
    assert!(
        (single.model.terms[0].coef + 6.0).abs() < 0.18,
        "{:?}",
        single.model
    );
    // δ ≥ 0.9: the lag residual is ≤ τ/τ_node ≈ 2 % of a transient, the noise ≈ 1 % of mean |ez|.
    assert!(single.heldout.delta >= 0.9, "δ = {}", single.heldout.delta);
    let main = bic
        .model
        .terms
        .iter()
        .max_by(|a, b| a.coef.abs().total_cmp(&b.coef.abs()))
        .unwrap();
    assert_eq!(main.signal, run.truth[0]);
    assert!(bic.heldout.delta >= 0.9, "δ = {}", bic.heldout.delta);
    // Whatever BIC adds is not confirmed by the held-out cool-down (observed: δ 0.977 alone, 0.954
    // with T_xscrew): it is fitted sensor lag, not physics. Validating the size on held-out data
    // (Spaan) instead of BIC would pick the right subset here.
    assert!(
        single.heldout.delta >= bic.heldout.delta,
        "single {} vs BIC {}",
        single.heldout.delta,
        bic.heldout.delta
    );
}

const TARGETS: usize = 11;
const STEP_MM: f64 = 15.0;
const RUNS: u32 = 5;

fn axis_config() -> String {
    // Each run: approach every target from below (overshoot 2 mm under the first), dwell 1 s, then
    // from above. Laser readings = ex at the end of each dwell.
    let mut g = String::from("G90 G21\nG0 X0 Y50 Z0\n");
    for _ in 0..RUNS {
        g.push_str("G1 F1500 X-2\n");
        for i in 0..TARGETS {
            let _ = writeln!(g, "G1 X{}\nG4 P1", 5.0 + i as f64 * STEP_MM);
        }
        let _ = writeln!(g, "G1 X{}", 5.0 + TARGETS as f64 * STEP_MM + 2.0);
        for i in (0..TARGETS).rev() {
            let _ = writeln!(g, "G1 X{}\nG4 P1", 5.0 + i as f64 * STEP_MM);
        }
    }
    g.push_str("M30\n");
    format!(
        r#"
seed = 9
[clock]
servo_hz = 200.0
[program]
tool_mm = 100.0
start_mm = [0.0, 50.0, 0.0]
gcode = """
{g}"""
[servo]
ideal = true
[truth.builtin]
exx_ppm = 40.0
[hidden]
error_noise_um = 0.2
[hidden.backlash.x]
b_um = 0.0
profile = [[0.0, 4.0], [80.0, 4.0], [160.0, 10.0]]
[record]
every_s = 0.05
"#
    )
}

#[test]
fn axis_fit_on_four_runs_predicts_the_fifth() {
    let mut w = World::new(cfg(&axis_config())).unwrap();
    let (bytes, _) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    let (h, rows) = read_csv(&bytes);
    let (tc, xc, exc) = (col(&h, "t_s"), col(&h, "x_mm"), col(&h, "ex_um"));
    let v: Vec<[f64; 3]> = rows
        .iter()
        .map(|r| [tc, xc, exc].map(|i| r[i].parse().unwrap()))
        .collect();
    // A reading is the last sample of a dwell: x unchanged for ≥ 0.9 s and about to move (or end).
    let mut readings: Vec<Reading> = Vec::new();
    let mut still_since = 0usize;
    let mut last_dir = Direction::Forward;
    let mut count = 0usize;
    for i in 1..v.len() {
        let dx = v[i][1] - v[i - 1][1];
        if dx != 0.0 {
            last_dir = if dx > 0.0 {
                Direction::Forward
            } else {
                Direction::Reverse
            };
            still_since = i;
            continue;
        }
        let ends = i + 1 == v.len() || v[i + 1][1] != v[i][1];
        let on_target = ((v[i][1] - 5.0) / STEP_MM).fract().abs() < 1e-9
            && v[i][1] >= 5.0
            && v[i][1] <= 5.0 + (TARGETS - 1) as f64 * STEP_MM + 1e-9;
        if ends && on_target && v[i][0] - v[still_since][0] >= 0.9 {
            readings.push(Reading {
                target_mm: v[i][1],
                run: (count / (2 * TARGETS)) as u32 + 1,
                direction: last_dir,
                deviation_um: v[i][2],
            });
            count += 1;
        }
    }
    assert_eq!(readings.len(), RUNS as usize * 2 * TARGETS);

    let fit = fit_axis(&readings, STEP_MM, 1e-4, Some(RUNS)).unwrap();
    let held = fit.heldout.unwrap();
    eprintln!(
        "axis fit: δ = {:.4}, max residual {:.3} µm, fit rms {:.3} µm",
        held.delta, held.max_residual_um, fit.fit_rms_um
    );
    // δ ≥ 0.9: noise 0.2 µm (mean |.| 0.16 µm) against a mean |ex| of ≈ 4 µm.
    assert!(held.delta >= 0.9, "δ = {}", held.delta);
    // Reversal (reverse − forward) = b(x): 4 µm up to 80 mm, rising to 10 µm at 160 mm.
    for (x, b) in [(20.0, 4.0), (65.0, 4.0), (125.0, 7.375), (155.0, 9.625)] {
        let got = fit.reverse.eval(x) - fit.forward.eval(x);
        assert!((got - b).abs() < 0.6, "reversal at {x} mm: {got} vs {b}");
    }
    // Mean slope = EXX scale error 40 ppm = 0.04 µm/mm (over the constant-b part).
    let slope = (fit.forward.eval(65.0) - fit.forward.eval(5.0)) / 60.0;
    assert!((slope - 0.04).abs() < 0.01, "slope {slope} µm/mm");
}
