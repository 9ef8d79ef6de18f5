//! The toolkit subcommands end to end through the binary: text, `--json` and SVG outputs, and
//! located errors on bad input.

use std::path::PathBuf;
use std::process::Command;

use crate::runs;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

fn fx(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/analysis")
        .join(name)
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn iso230_2_text_json_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("z.svg");
    let text = run_ok(
        bin()
            .arg("iso230-2")
            .arg(fx("asadullah_z_iso230_2.csv"))
            .arg("--svg")
            .arg(&svg),
    );
    assert!(
        text.contains("ISO 230-2:2014")
            && text.contains("E = 11.60 µm")
            && text.contains("R = n/a"),
        "{text}"
    );
    let json: serde_json::Value = serde_json::from_str(&run_ok(
        bin()
            .arg("iso230-2")
            .arg(fx("asadullah_x_iso230_2.csv"))
            .arg("--json"),
    ))
    .unwrap();
    assert!((json["axis"]["E_um"].as_f64().unwrap() - 31.8).abs() < 0.05);
    assert!(json["axis"]["A_um"].is_null());
    let s = std::fs::read_to_string(&svg).unwrap();
    assert!(s.contains("E = 11.60 µm") && s.contains("target position / mm"));
}

#[test]
fn bad_rows_fail_with_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.csv");
    std::fs::write(
        &p,
        "target_mm,run,direction,deviation_um\n0,1,+,1\n0,1,?,2\n",
    )
    .unwrap();
    let out = bin().arg("iso230-2").arg(&p).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("bad.csv:3: column `direction`: expected `+` or `-`, found `?`"),
        "{err}"
    );
}

#[test]
fn import_fanuc_table_7_2_then_export_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("y.csv");
    let json: serde_json::Value = serde_json::from_str(&run_ok(
        bin()
            .args([
                "import", "--format", "fanuc", "--axis", "2", "--json", "--out",
            ])
            .arg(&table)
            .arg(fx("asadullah_table_7_2.tape")),
    ))
    .unwrap();
    assert_eq!(json["cumulative_sum_units"], 12);
    assert_eq!(json["backlash_1851_units"], 2);
    // Export the imported Y table again with the thesis layout: the same pitch values come back.
    let tape = run_ok(
        bin()
            .args([
                "export",
                "--format",
                "fanuc",
                "--axis-number",
                "2",
                "--ref-point",
                "200",
            ])
            .arg(&table),
    );
    let orig = std::fs::read_to_string(fx("asadullah_table_7_2.tape")).unwrap();
    for n in 171..=201 {
        let key = format!("N{} P", 10000 + n);
        let a = orig.lines().find(|l| l.starts_with(&key)).unwrap();
        let b = tape
            .lines()
            .find(|l| l.starts_with(&key))
            .unwrap_or_else(|| panic!("{key} missing:\n{tape}"));
        assert_eq!(a, b);
    }
    assert!(tape.contains("N1851 A2 P2"));
    // LinuxCNC and ISG outputs exist and carry the header / triplets.
    let comp = run_ok(bin().args(["export", "--format", "linuxcnc"]).arg(&table));
    assert_eq!(comp.lines().count(), 32);
    let isg = run_ok(
        bin()
            .args(["export", "--format", "isg", "--axis", "Y"])
            .arg(&table),
    );
    assert!(isg.contains("Y EXY EYY EZY EAY EBY ECY"));
}

#[test]
fn nc_rewrites_the_diagonal_program() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("comp.nc");
    let summary = run_ok(
        bin()
            .arg("nc")
            .arg(fx("asadullah_diagonal_uncompensated.nc"))
            .arg("--plane-model")
            .arg(fx("asadullah_plane_model.toml"))
            .arg("--diameter-x")
            .arg("--out")
            .arg(&out),
    );
    assert!(
        summary.contains("2 moves outside the model kept as programmed"),
        "{summary}"
    );
    let prog = std::fs::read_to_string(&out).unwrap();
    // Table 6.3 Geo F row 30/20 exactly; Geo R row 510/340 is X339.9380 Z509.9275 in the thesis,
    // whose X Ø values carry ±0.2 µm of print rounding (tests/analysis/nc.rs checks all rows).
    assert!(prog.contains("X19.9814 Z29.9988;"), "{prog}");
    assert!(prog.contains("X339.9378 Z509.9275;"), "{prog}");
    // Same program through the machine model (deploy/examples, positional terms): Table 6.3 Pos F row 30/20.
    let model = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("deploy/examples/studer-s36-positional.toml");
    let json: serde_json::Value = serde_json::from_str(&run_ok(
        bin()
            .arg("nc")
            .arg(fx("asadullah_diagonal_uncompensated.nc"))
            .arg("--model")
            .arg(&model)
            .arg("--diameter-x")
            .arg("--json"),
    ))
    .unwrap();
    assert!(
        json["output"]
            .as_str()
            .unwrap()
            .contains("X19.9848 Z29.9993;")
    );
    assert_eq!(json["stats"]["moves_outside_domain"], 2);
}

#[test]
fn circle_reports_g_and_terms() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.csv");
    // A pure X backlash of 4 µm: dr = −2·sgn(vx)·cosθ.
    let mut s = String::from("angle_deg,dr_um,direction\n");
    for (dir_s, sign) in [("ccw", 1.0), ("cw", -1.0)] {
        for i in 0..360 {
            let th = (sign * f64::from(i)).rem_euclid(360.0);
            let vx = -sign * th.to_radians().sin();
            let dr = -2.0 * vx.signum() * th.to_radians().cos();
            s.push_str(&format!("{th},{dr},{dir_s}\n"));
        }
    }
    std::fs::write(&p, s).unwrap();
    let json: serde_json::Value =
        serde_json::from_str(&run_ok(bin().arg("circle").arg(&p).args([
            "--radius-mm",
            "100",
            "--feed-mm-min",
            "1000",
            "--json",
        ])))
        .unwrap();
    assert_eq!(json["terms"][0]["effect"], "backlash_x");
    assert!((json["terms"][0]["params"]["b_um"].as_f64().unwrap() - 4.0).abs() < 0.05);
    assert!(json["iso230_4"]["g_bidirectional_um"].as_f64().unwrap() > 3.0);
}

#[test]
fn fit_axis_writes_a_model_that_check_config_accepts() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs.csv");
    runs::bowed_runs_csv(&runs);
    let model = dir.path().join("m.toml");
    let svg = dir.path().join("fit.svg");
    let text = run_ok(
        bin()
            .args(["fit", "axis"])
            .arg(&runs)
            .args(["--component", "EXX", "--holdout-run", "3", "--out"])
            .arg(&model)
            .arg("--svg")
            .arg(&svg),
    );
    assert!(text.contains("held-out run 3: δ = 9"), "{text}");
    let check = run_ok(bin().arg("check-config").arg(&model));
    assert!(check.contains("EXX"), "{check}");
    assert!(std::fs::read_to_string(&svg).unwrap().contains("EXX fit"));
    // thermal needs a base model: a clear error without one.
    let out = bin()
        .args(["fit", "thermal"])
        .arg(&runs)
        .args(["--signal", "ex_um"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--base-model is required"));
}
