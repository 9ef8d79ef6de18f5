//! Issue 37, point 6 end to end with the real binaries: `hil-sim artefacts --lead-wave` gives its
//! hidden machine (deploy/examples/old-mill-3axis.toml) a 5 mm lead wave on X, Y, Z (1.5 / 1.2 /
//! 1.0 µm at 30° / 140° / −110°, hil_sim::artefacts::LEAD_WAVES), probes plates 0.45 lead off whole
//! leads and writes laser runs every 1.25 mm; `retrocomp identify --lead-mm 5` and
//! `retrocomp fit axis --lead-mm 5` must each find every wave within 0.2 µm and 20°, and write it
//! into the model as a table every ≤ lead/4 that `check-config` loads.

use crate::hil_sim;

use crate::identify_support as cli;

use std::path::Path;
use std::process::Command;

use cli::{check_config, csvs, ok, retrocomp};

/// The hidden waves `--lead-wave` adds: (component, amplitude µm, phase °).
const TRUTH: [(&str, f64, f64); 3] = [
    ("EXX", 1.5, 30.0),
    ("EYY", 1.2, 140.0),
    ("EZZ", 1.0, -110.0),
];

fn phase_off(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// Amplitude and phase of a JSON lead wave against the truth; panics with `what` when off.
fn check(w: &serde_json::Value, amp: f64, phase: f64, what: &str) {
    let a = w["amplitude_um"].as_f64().unwrap();
    let p = w["phase_deg"].as_f64().unwrap();
    eprintln!("{what}: {a:.3} µm at {p:.1}° (truth {amp} µm at {phase}°)");
    assert!(
        (a - amp).abs() <= 0.2 && phase_off(p, phase) <= 20.0,
        "{what}: {a:.3} µm at {p:.1}°, truth {amp} µm at {phase}°"
    );
}

/// The model's component `name` is a table whose steps are all ≤ lead/4.
fn assert_fine_table(model_toml: &str, name: &str) {
    let doc: toml::Table = model_toml.parse().unwrap();
    let c = doc["components"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"].as_str() == Some(name))
        .unwrap_or_else(|| panic!("{name} in the model"));
    let q: Vec<f64> = c["positions_mm"]
        .as_array()
        .unwrap_or_else(|| panic!("{name} is a table"))
        .iter()
        .map(|v| v.as_float().unwrap())
        .collect();
    assert!(
        q.windows(2).all(|w| w[1] - w[0] <= 5.0 / 4.0),
        "{name}: steps above lead/4"
    );
}

#[test]
fn identify_and_fit_find_the_hidden_lead_wave() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let art = dir.path().join("art");
    let o = Command::new(hil_sim::hil_sim_next_to_retrocomp())
        .args(["artefacts", "--seed", "4", "--lead-wave", "--truth"])
        .arg(root.join("deploy/examples/old-mill-3axis.toml"))
        .arg("--out")
        .arg(&art)
        .output()
        .unwrap();
    ok(&o, "hil-sim artefacts --lead-wave");

    let model = dir.path().join("identified.toml");
    let mut cmd = retrocomp();
    cmd.args([
        "identify",
        "--chain",
        "X F Y Z",
        "--lead-mm",
        "5",
        "--hole-plate",
    ])
    .args(csvs(&art.join("plates")))
    .arg("--out")
    .arg(&model);
    let text = ok(&cmd.output().unwrap(), "retrocomp identify --lead-mm 5");
    assert!(
        text.lines()
            .filter(|l| l.starts_with("lead wave: E"))
            .count()
            == 3,
        "one lead wave line per positioning component:\n{text}"
    );
    let json: serde_json::Value = serde_json::from_str(&ok(
        &cmd.arg("--json").output().unwrap(),
        "retrocomp identify --lead-mm 5 --json",
    ))
    .unwrap();
    let toml = std::fs::read_to_string(&model).unwrap();
    for (name, amp, phase) in TRUTH {
        let w = json["lead_waves"]
            .as_array()
            .unwrap()
            .iter()
            .find(|w| w["name"] == name)
            .unwrap_or_else(|| panic!("{name} in lead_waves"));
        assert_eq!(w["identified"], true, "{name}");
        check(w, amp, phase, &format!("identify {name}"));
        assert_fine_table(&toml, name);
    }
    check_config(&model);

    for (axis, (name, amp, phase)) in ["x", "y", "z"].into_iter().zip(TRUTH) {
        let out = ok(
            &retrocomp()
                .args([
                    "fit",
                    "axis",
                    "--component",
                    name,
                    "--lead-mm",
                    "5",
                    "--json",
                ])
                .arg(art.join("laser").join(format!("{axis}.csv")))
                .output()
                .unwrap(),
            "retrocomp fit axis --lead-mm 5",
        );
        let j: serde_json::Value = serde_json::from_str(&out).unwrap();
        check(&j["fit"]["lead"], amp, phase, &format!("fit {name}"));
        assert_fine_table(j["model_toml"].as_str().unwrap(), name);
    }
    // A piecewise quadratic cannot carry the wave: refused, with the reason.
    let o = retrocomp()
        .args([
            "fit",
            "axis",
            "--component",
            "EXX",
            "--lead-mm",
            "5",
            "--form",
            "piecewise",
        ])
        .arg(art.join("laser/x.csv"))
        .output()
        .unwrap();
    assert!(
        !o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--form table"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}
