//! Item 7: with noise off the recorded error equals the truth model's error exactly, and every hidden
//! term in the world's breakdown equals its closed form.

#![allow(clippy::needless_range_loop)] // per-axis loops over several [f64; 3]

use crate::sim_common;
use hil_sim::World;
use hil_sim::recording::run_to_end;
use hil_sim::truth::TruthModel;
use sim_common::{cfg, col, read_csv};

const GEOMETRY: &str = r#"
[truth.builtin]
exx_ppm = 25.0
eyy_ppm = -15.0
ezz_ppm = 8.0
ec0y_urad = 40.0
eb0z_urad = -20.0
ea0z_urad = 12.0
eyx_um_per_m2 = 300.0
ebx_urad_per_m = 80.0
"#;

#[test]
fn noise_off_ideal_servo_records_exactly_the_truth_model() {
    let toml = format!(
        r#"
[program]
tool_mm = 150.0
gcode = """
G1 F3000 X120 Y40 Z-30
G2 X140 Y60 I0 J20
G1 X10 Y90 Z10
M30
"""
[servo]
ideal = true
{GEOMETRY}"#
    );
    let c = cfg(&toml);
    let mut truth = c.truth.builtin.clone();
    let mut w = World::new(c).unwrap();
    let (bytes, rows) = run_to_end(&mut w, Vec::new(), |_| {}).unwrap();
    assert!(rows > 100, "{rows} rows");
    let (h, data) = read_csv(&bytes);
    let (x, ex) = (col(&h, "x_mm"), col(&h, "ex_um"));
    let mut max_abs = 0.0f64;
    for row in &data {
        let q: [f64; 3] = std::array::from_fn(|k| row[x + k].parse().unwrap());
        let expect = truth.static_error_um(q, [0; 3], 150.0);
        for k in 0..3 {
            let got: f64 = row[ex + k].parse().unwrap();
            assert_eq!(
                got.to_bits(),
                expect[k].to_bits(),
                "axis {k} at {q:?}: {got} vs {}",
                expect[k]
            );
            max_abs = max_abs.max(got.abs());
        }
    }
    assert!(
        max_abs > 5.0,
        "the model must produce sizeable errors for this test to mean anything: {max_abs}"
    );
}

#[test]
fn every_hidden_term_matches_its_closed_form() {
    let toml = r#"
[program]
tool_mm = 100.0
start_mm = [0.0, 0.0, 5.0]
gcode = """
G0 Z2
S3000 M3
G1 F400 Z-1.5
G1 F900 X60 Y20
G1 X5
G1 X70
M30
"""
[servo]
kv_per_s = 40.0
[truth.builtin]
exx_ppm = 20.0
[hidden.backlash.x]
profile = [[0.0, 4.0], [100.0, 10.0]]
[hidden.cyclic.x]
period_mm = 4.0
amplitude_um = 1.2
phase_rad = 0.3
[hidden.thermal]
ambient_drift_C_per_h = 2.0
[[hidden.thermal.nodes]]
name = "screw"
tau_s = 5.0
rise_C_per_mm_s = { x = 0.5 }
[[hidden.thermal.nodes]]
name = "spindle"
tau_s = 8.0
rise_C_per_krpm = 3.0
[[hidden.thermal.effects]]
kind = "expansion"
node = "screw"
axis = "x"
ppm_per_K = 11.0
[[hidden.thermal.effects]]
kind = "growth"
node = "spindle"
axis = "z"
um_per_K = -5.0
[hidden.cutting]
stock_top_z_mm = 0.0
compliance_um_per_N = { x = 0.02, z = -0.01 }
"#;
    let c = cfg(toml);
    let geometry = c.truth.builtin.clone();
    let mut w = World::new(c).unwrap();
    let (mut saw_force, mut saw_reversal_both_ways, mut last_dir) = (false, [false; 2], 0i8);
    while !w.done() {
        let before = w.motor_mm(0);
        w.tick();
        let b = w.truth_error();
        let sp = *w.setpoint();
        let motor: [f64; 3] = std::array::from_fn(|k| w.motor_mm(k));
        let net = w.thermal().unwrap();
        let (screw_dt, spindle_dt) = (net.node_C(0) - 20.0, net.node_C(1) - 20.0);
        for k in 0..3 {
            assert_eq!(b.loop_um[k], (motor[k] - sp.pos_mm[k]) * 1000.0);
        }
        assert_eq!(
            b.cyclic_um[0],
            1.2 * (std::f64::consts::TAU * motor[0] / 4.0 + 0.3).sin()
        );
        assert!((b.expansion_um[0] - 11.0 * screw_dt * 1e-3 * motor[0]).abs() < 1e-12);
        assert!((b.growth_um[2] + 5.0 * spindle_dt).abs() < 1e-12);
        let force = if sp.feeding && sp.rpm > 0.0 {
            2000.0 * (0.0 - sp.pos_mm[2]).max(0.0) * sp.feed_mm_min / (sp.rpm * 2.0)
        } else {
            0.0
        };
        assert!(
            (b.force_um[0] - 0.02 * force).abs() < 1e-9
                && (b.force_um[2] + 0.01 * force).abs() < 1e-9
        );
        saw_force |= force > 100.0;
        // Backlash: after a move of more than the play, the slide trails by exactly b(x)/2.
        let play = 4.0 + 6.0 * motor[0].clamp(0.0, 100.0) / 100.0;
        let dir = (motor[0] - before).signum() as i8;
        if dir != 0 && dir == last_dir && b.backlash_um[0].abs() > 0.0 {
            assert!(b.backlash_um[0].abs() <= play / 2.0 + 1e-9);
        }
        if (b.backlash_um[0] + play / 2.0).abs() < 1e-9 {
            saw_reversal_both_ways[0] = true;
        }
        if (b.backlash_um[0] - play / 2.0).abs() < 1e-9 {
            saw_reversal_both_ways[1] = true;
        }
        last_dir = dir;
        let slide: [f64; 3] = std::array::from_fn(|k| {
            motor[k] + (b.backlash_um[k] + b.cyclic_um[k] + b.expansion_um[k]) / 1000.0
        });
        let mut g = geometry.clone();
        assert_eq!(
            b.geometric_um,
            g.static_error_um(slide, w.direction(), 100.0)
        );
        if w.sampled() {
            // Noise off: the recorded error is the breakdown's total, bit for bit.
            assert_eq!(w.readings().error_um, b.total_um);
            let sum: f64 = b.loop_um[0]
                + b.backlash_um[0]
                + b.cyclic_um[0]
                + b.expansion_um[0]
                + b.geometric_um[0]
                + b.growth_um[0]
                + b.force_um[0];
            assert_eq!(b.total_um[0], sum);
        }
    }
    assert!(saw_force, "the program cuts");
    assert_eq!(
        saw_reversal_both_ways,
        [true, true],
        "x moved both ways far enough to take up the play"
    );
}

#[test]
fn noise_off_records_exactly_the_projects_volumetric_model() {
    // The Studer S-36 model of Asad Ullah's tables (bidirectional EXX/EZZ): the truth is evaluated
    // with the world's latched direction, so forward and reverse tables both get exercised.
    let model_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/examples/studer-s36-positional.toml");
    let toml = format!(
        r#"
[program]
gcode = """
G1 F6000 X160 Z480
G1 X10 Z20
G1 X120 Z300
M30
"""
[servo]
ideal = true
[truth]
model_path = "{}"
"#,
        model_path.display()
    );
    let model = retrocomp_model::MachineModel::from_toml_path(&model_path).unwrap();
    let (mut state, mut input, mut out) =
        (model.new_state(), model.new_input(), model.new_breakdown());
    let mut w = World::new(cfg(&toml)).unwrap();
    let (mut rows, mut dirs_seen) = (0, std::collections::BTreeSet::new());
    while !w.done() {
        w.tick();
        if w.sampled() {
            let r = w.readings();
            input.pos_mm = r.nominal_mm;
            input.dir = w.direction();
            input.tool_mm = Some(0.0);
            model.evaluate(&input, &mut state, &mut out);
            assert_eq!(
                r.error_um, out.total_um,
                "at {:?} dir {:?}",
                r.nominal_mm, input.dir
            );
            dirs_seen.insert(input.dir[0]);
            rows += 1;
        }
    }
    assert!(rows > 50);
    assert!(
        dirs_seen.contains(&1) && dirs_seen.contains(&-1),
        "both table directions used"
    );
}
