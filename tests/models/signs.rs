//! One-term models lock the sign of every component (docs/model.md, Conventions: error = actual − nominal; a table
//! states its sign and a test locks it). Each case is a model with a single constant term; the
//! expected tool-tip error is written out by hand from the convention in `crates/model/src/lib.rs`.

use retrocomp_model::{MachineModel, ModelInput};

const MILL: &str = r#"
schema = 1
[machine]
name = "one-term"
chain = "X F Y Z"
[[tools]]
name = "T"
offset_mm = [0.0, 0.0, -100.0]
"#;

fn eval(model_text: &str, pos: [f64; 3]) -> ([f64; 3], [f64; 3], MachineModel) {
    let m = MachineModel::from_toml_str(model_text, "one-term")
        .unwrap_or_else(|e| panic!("{e}\n{model_text}"));
    let input = ModelInput {
        pos_mm: pos,
        ..m.new_input()
    };
    let (mut s1, mut s2) = (m.new_state(), m.new_state());
    let (mut exact, mut first) = (m.new_breakdown(), m.new_breakdown());
    m.evaluate(&input, &mut s1, &mut exact);
    m.evaluate_first_order(&input, &mut s2, &mut first);
    assert!(!exact.flags.any(), "{:?}", exact.flags);
    (exact.total_um, first.total_um, m)
}

fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
    (0..3).all(|i| (a[i] - b[i]).abs() <= tol)
}

fn component(chain_text: &str, name: &str, value: f64) -> String {
    let unit =
        if name.as_bytes()[1].is_ascii_digit() || "ABC".contains(name.chars().nth(1).unwrap()) {
            "urad"
        } else {
            "um"
        };
    format!("{chain_text}\n[[components]]\nname = \"{name}\"\ncoefficients_{unit} = [{value:?}]\n")
}

#[test]
fn translations_give_their_own_sign_on_every_axis_and_branch() {
    // EJK = +2.5 µm → e_J = +2.5 µm, whatever K and whichever side of the frame K sits on.
    for chain in ["X F Y Z", "F X Y Z", "X Y Z F", "Y F X Z"] {
        let base = MILL.replace("X F Y Z", chain);
        for k in ['X', 'Y', 'Z'] {
            for (j, dir) in ['X', 'Y', 'Z'].iter().enumerate() {
                let (exact, first, _) = eval(
                    &component(&base, &format!("E{dir}{k}"), 2.5),
                    [120.0, -40.0, 75.0],
                );
                let mut want = [0.0; 3];
                want[j] = 2.5;
                // Exact: mm ↔ µm rounding only (positions ~300 mm → ~1e-10 µm).
                assert!(close(exact, want, 1e-9), "{chain} E{dir}{k}: {exact:?}");
                assert!(
                    close(first, want, 1e-12),
                    "{chain} E{dir}{k} first order: {first:?}"
                );
            }
        }
    }
}

#[test]
fn rotations_on_the_tool_side_swing_the_tool_arm() {
    // Exact results differ from these first-order values by ε²·arm/2 ≈ 5e-6 µm: tolerance 1e-4.
    // Mill "X F Y Z", tool 100 mm below the Z carriage, Z at 300: Z's arm is the tool (0, 0, −100).
    // EAZ = +10 µrad (about +X): (0,0,−100) → y' = −z·θ... tip moves +Y by 1 µm: x̂ × (0,0,−100) = (0, 100, 0).
    let pos = [100.0, 200.0, 300.0];
    let (e, f, _) = eval(&component(MILL, "EAZ", 10.0), pos);
    assert!(
        close(e, [0.0, 1.0, 0.0], 1e-4) && close(f, [0.0, 1.0, 0.0], 1e-12),
        "EAZ {e:?} {f:?}"
    );
    // EBZ = +10 µrad (about +Y): ŷ × (0,0,−100) = (−100, 0, 0) → ex = −1 µm.
    let (e, f, _) = eval(&component(MILL, "EBZ", 10.0), pos);
    assert!(
        close(e, [-1.0, 0.0, 0.0], 1e-4) && close(f, [-1.0, 0.0, 0.0], 1e-12),
        "EBZ {e:?}"
    );
    // ECZ about the tool axis through the tool: no arm, no error.
    let (e, _, _) = eval(&component(MILL, "ECZ", 10.0), pos);
    assert!(close(e, [0.0; 3], 1e-4), "ECZ {e:?}");
    // Y carries Z: Y's arm is Z's travel plus the tool: (0, 0, 300 − 100) = (0, 0, 200).
    // EAY = +10 µrad: x̂ × (0,0,200) = (0, −200, 0) → ey = −2 µm.
    let (e, _, _) = eval(&component(MILL, "EAY", 10.0), pos);
    assert!(close(e, [0.0, -2.0, 0.0], 1e-4), "EAY {e:?}");
    // ECY = +10 µrad (about +Z): ẑ × (0,0,200) = 0: no error.
    let (e, _, _) = eval(&component(MILL, "ECY", 10.0), pos);
    assert!(close(e, [0.0; 3], 1e-4), "ECY {e:?}");
}

#[test]
fn rotations_on_the_workpiece_side_include_the_tables_own_travel() {
    // The table (X) rotates about its own reference point: the tool is at (x, y, z) + tool =
    // (100, 200, 200) from it. ECX = +10 µrad: ẑ × (100, 200, 200) = (−200, 100, 0) → (−2, +1, 0) µm.
    let pos = [100.0, 200.0, 300.0];
    let (e, f, _) = eval(&component(MILL, "ECX", 10.0), pos);
    assert!(
        close(e, [-2.0, 1.0, 0.0], 1e-4) && close(f, [-2.0, 1.0, 0.0], 1e-12),
        "ECX {e:?} {f:?}"
    );
    // EBX = +10 µrad: ŷ × (100, 200, 200) = (200, 0, −100) → (+2, 0, −1) µm.
    let (e, _, _) = eval(&component(MILL, "EBX", 10.0), pos);
    assert!(close(e, [2.0, 0.0, -1.0], 1e-4), "EBX {e:?}");
    // EAX = +10 µrad: x̂ × (100, 200, 200) = (0, −200, 200) → (0, −2, +2) µm.
    let (e, _, _) = eval(&component(MILL, "EAX", 10.0), pos);
    assert!(close(e, [0.0, -2.0, 2.0], 1e-4), "EAX {e:?}");
}

#[test]
fn squareness_signs_for_each_kind_and_carrier() {
    let pos = [100.0, 200.0, 300.0];
    let sq = |name: &str, on: Option<&str>| {
        let on = on.map_or(String::new(), |a| format!("on_axis = \"{a}\"\n"));
        format!("{MILL}\n[[squareness]]\nname = \"{name}\"\n{on}value_urad = 10.0\n")
    };
    // µrad × mm × 1e-3 = µm. EC0Y on Y: ex = −S·y = −2; on X: ey = −S·x = −1.
    // EB0Z on Z: ex = +S·z = +3; on X: ez = +S·x = +1.
    // EA0Z on Z: ey = −S·z = −3; on Y: ez = −S·y = −2.
    let cases = [
        ("EC0Y", None, [-2.0, 0.0, 0.0]),
        ("EC0Y", Some("x"), [0.0, -1.0, 0.0]),
        ("EB0Z", None, [3.0, 0.0, 0.0]),
        ("EB0Z", Some("x"), [0.0, 0.0, 1.0]),
        ("EA0Z", None, [0.0, -3.0, 0.0]),
        ("EA0Z", Some("y"), [0.0, 0.0, -2.0]),
    ];
    for (name, on, want) in cases {
        let (e, f, m) = eval(&sq(name, on), pos);
        assert!(close(f, want, 1e-12), "{name} on {on:?}: first order {f:?}");
        assert!(close(e, want, 1e-4), "{name} on {on:?}: exact {e:?}");
        assert!(m.term_names().iter().any(|t| t.starts_with(name)));
    }
}

#[test]
fn thermal_and_load_terms_add_with_their_sign() {
    let text = format!(
        "{MILL}
[[sensors]]
name = \"spindle\"
[[sensors]]
name = \"scale\"
[[thermal]]
name = \"growth\"
target = \"EZZ\"
kind = \"polynomial_dt\"
sensors = [\"spindle\"]
e0_um = 1.0
b_um_per_K = [-2.0]
[[thermal]]
name = \"scale_x\"
target = \"EXX\"
kind = \"expansion\"
sensor = \"scale\"
alpha_ppm_per_K = 10.0
[[forces]]
name = \"cut\"
[[forces]]
name = \"weight\"
strain = \"guide\"
gain_N_per_ue = 2.0
offset_ue = 10.0
[[load]]
name = \"defl\"
target = \"EYZ\"
kind = \"compliance\"
force = \"cut\"
coefficients_um_per_N = [0.01]
[[load]]
name = \"sag\"
target = \"EYX\"
kind = \"compliance\"
force = \"weight\"
coefficients_um_per_N = [-0.005]
"
    );
    let m = MachineModel::from_toml_str(&text, "thermal-load").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(m.temperature_sensors(), ["spindle", "scale"]);
    assert_eq!(m.force_channels(), ["cut"]);
    assert_eq!(m.strain_channels(), ["guide"]);
    let mut input = m.new_input();
    input.pos_mm = [100.0, 0.0, 0.0];
    input.temps_c = vec![23.0, 30.0];
    input.forces_n = vec![100.0];
    input.strains_ue = vec![60.0];
    let mut st = m.new_state();
    let mut out = m.new_breakdown();
    m.evaluate(&input, &mut st, &mut out);
    // growth: 1 − 2·3 = −5 µm in Z; scale: 10 ppm/K · 100 mm · 10 K = 10 µm in X;
    // cut: 0.01 µm/N · 100 N = +1 µm in Y; weight: 2 N/µε · (60 − 10) µε = 100 N → −0.5 µm in Y.
    assert!(
        close(out.total_um, [10.0, 0.5, -5.0], 1e-9),
        "{:?}",
        out.total_um
    );
    let id = |n: &str| m.term_names().iter().position(|t| t == n).unwrap();
    assert!(close(out.terms_um[id("growth")], [0.0, 0.0, -5.0], 1e-12));
    assert!(close(out.terms_um[id("scale_x")], [10.0, 0.0, 0.0], 1e-12));
    assert!(close(out.terms_um[id("defl")], [0.0, 1.0, 0.0], 1e-12));
    assert!(close(out.terms_um[id("sag")], [0.0, -0.5, 0.0], 1e-12));
}

#[test]
fn bidirectional_table_direction_picks_forward_reverse_or_mean() {
    let text = format!(
        "{MILL}\n[[components]]\nname = \"EXX\"\npositions_mm = [0.0, 100.0]\nforward_um = [2.0, 2.0]\nreverse_um = [-2.0, -2.0]\n"
    );
    let m = MachineModel::from_toml_str(&text, "dir").unwrap();
    let mut st = m.new_state();
    let mut out = m.new_breakdown();
    for (dir, want) in [(1i8, 2.0), (-1, -2.0), (0, 0.0)] {
        let input = ModelInput {
            pos_mm: [50.0, 0.0, 0.0],
            dir: [dir, 0, 0],
            ..m.new_input()
        };
        m.evaluate_first_order(&input, &mut st, &mut out);
        assert_eq!(out.total_um[0], want, "dir {dir}");
    }
    // Outside the table: clamped to the end value and flagged.
    let input = ModelInput {
        pos_mm: [150.0, 0.0, 0.0],
        dir: [1, 0, 0],
        ..m.new_input()
    };
    m.evaluate_first_order(&input, &mut st, &mut out);
    assert_eq!(out.total_um[0], 2.0);
    assert!(out.flags.clamped[0] && !out.flags.clamped[1]);
    // A NaN position never produces a NaN: zero output, flagged invalid.
    let input = ModelInput {
        pos_mm: [f64::NAN, 0.0, 0.0],
        ..m.new_input()
    };
    m.evaluate(&input, &mut st, &mut out);
    assert_eq!(out.total_um, [0.0; 3]);
    assert!(out.flags.invalid_input);
}

#[test]
fn slope_stations_lag_and_weight_terms_follow_their_equations() {
    let text = format!(
        "{MILL}
[[sensors]]
name = \"screw\"
tau_s = 100.0
[[sensors]]
name = \"col\"
[[thermal]]
name = \"x_slope\"
target = \"EXX\"
kind = \"slope\"
sensors = [\"screw\"]
s0_um_per_m = 1.0
s_um_per_m_K = [10.0]
[[thermal]]
name = \"drift\"
target = \"EYZ\"
kind = \"stations\"
along = \"z\"
sensors = [\"col\"]
stations_mm = [0.0, 200.0, 400.0]
e0_um = [0.0, 1.0, 2.0]
b_um_per_K = [[1.0], [2.0], [3.0]]
[[forces]]
name = \"w\"
[[load]]
name = \"roll\"
target = \"EAX\"
kind = \"weight_angular\"
force = \"w\"
reference_force_N = 4800.0
lever_mm = 375.0
load_height_mm = 75.0
coefficients_urad = [8.0]
"
    );
    let m = MachineModel::from_toml_str(&text, "terms").unwrap_or_else(|e| panic!("{e}"));
    let id = |n: &str| m.term_names().iter().position(|t| t == n).unwrap();
    let mut st = m.new_state();
    let mut out = m.new_breakdown();
    let mut input = m.new_input();
    input.pos_mm = [500.0, 0.0, 100.0];
    input.forces_n = vec![2400.0];
    // t = 0: the first reading initialises the lag (steady state): screw ΔT = 0.
    input.temps_c = vec![20.0, 22.0];
    m.evaluate_first_order(&input, &mut st, &mut out);
    // (b) Ni: x·(s0 + s·ΔT)/1000 = 500·1/1000 = 0.5 µm.
    assert!((out.terms_um[id("x_slope")][0] - 0.5).abs() < 1e-12);
    // (e) Spaan stations at z = 100: halfway between (0 + 1·2) and (1 + 2·2) = 3.5 µm in Y.
    assert!((out.terms_um[id("drift")][1] - 3.5).abs() < 1e-12);
    // Spaan eq. 4.1: 8 µrad · 2400/4800 · (375 − 75)/375 = 3.2 µrad about X on the table (X, on
    // the workpiece side), arm = (500, 0, 100 − 100) → x̂ × arm = 0: no tip error at z = 100 …
    assert!(out.terms_um[id("roll")].iter().all(|v| v.abs() < 1e-12));
    input.pos_mm[2] = 300.0; // … and 3.2 µrad · 200 mm = 0.64 µm in −Y once the arm has a Z part.
    m.evaluate_first_order(&input, &mut st, &mut out);
    let roll = out.terms_um[id("roll")];
    assert!(
        (roll[1] + 0.64).abs() < 1e-12 && roll[2].abs() < 1e-12,
        "{roll:?}"
    );
    // (d) lag: screw steps to 30 °C; after one τ the lagged ΔT is 10·(1 − e⁻¹).
    input.pos_mm[2] = 100.0;
    input.temps_c = vec![30.0, 22.0];
    input.t_s = 100.0;
    m.evaluate_first_order(&input, &mut st, &mut out);
    let dt = 10.0 * (1.0 - (-1.0f64).exp());
    assert!((out.terms_um[id("x_slope")][0] - 500.0 * (1.0 + 10.0 * dt) / 1000.0).abs() < 1e-9);
}
