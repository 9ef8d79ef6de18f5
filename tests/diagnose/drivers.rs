//! A heat source seen only through `rpm` (no temperature sensor near it) on a thermal-only
//! recording (no axis column): diagnose names `thermal_lag` driven by `rpm` with its τ, writes a
//! model.toml holding a lag state reading the `rpm` column, and `retrocomp eval` runs that model
//! forward over a NEW recording without axis columns, predicting its error.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

/// Deterministic noise in [-0.5, 0.5).
fn noise(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
}

const TAU_S: f64 = 1800.0;
const GAIN_UM_PER_RPM: f64 = 0.002;

/// t_s, rpm (steps), an unrelated temperature, ez_um = gain·lag(rpm) + noise, sim_ez_um = 0.
fn recording(levels: &[f64], seed: u64, with_error: bool) -> (String, Vec<f64>) {
    let dt = 15.0;
    let per = 960; // 4 h per level
    let mut s = seed;
    let mut lag = 0.0;
    let mut out = String::from("t_s,rpm,T_room_C");
    if with_error {
        out.push_str(",ez_um,sim_ez_um");
    }
    out.push('\n');
    let mut truth = vec![];
    for (k, &rpm) in levels.iter().enumerate() {
        for i in 0..per {
            let t = (k * per + i) as f64 * dt;
            let e = GAIN_UM_PER_RPM * lag;
            truth.push(e);
            let room = 20.0 + 0.3 * (t / 20000.0).sin() + 0.02 * noise(&mut s);
            out.push_str(&format!("{t},{rpm},{room:.4}"));
            if with_error {
                out.push_str(&format!(",{:.4},0", e + 0.2 * noise(&mut s)));
            }
            out.push('\n');
            lag += (1.0 - (-dt / TAU_S).exp()) * (rpm - lag);
        }
    }
    (out, truth)
}

#[test]
fn rpm_heat_source_is_found_written_and_predicts_a_new_recording() {
    let dir = tempfile::tempdir().unwrap();
    let (fit, _) = recording(&[0.0, 1000.0, 0.0, 2000.0, 0.0], 7, true);
    let fit_path = dir.path().join("fit.csv");
    std::fs::write(&fit_path, fit).unwrap();
    let out_dir = dir.path().join("out");
    let out = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(&fit_path)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["verdict"], "found", "{j:#}");
    let f = &j["findings"][0];
    assert_eq!(f["effect"], "thermal_lag", "{j:#}");
    assert_eq!(f["params"]["sensor"], "rpm", "{j:#}");
    let tau = f["params"]["tau_s"].as_f64().unwrap();
    let gain = f["params"]["um_per_K"].as_f64().unwrap();
    assert!((tau / TAU_S - 1.0).abs() < 0.15, "tau {tau}");
    assert!((gain / GAIN_UM_PER_RPM - 1.0).abs() < 0.1, "gain {gain}");
    let toml = std::fs::read_to_string(out_dir.join("model.toml")).unwrap();
    assert!(toml.contains("column = \"rpm\""), "{toml}");

    // Tomorrow's recording: other speeds, no axis and no error columns; it starts cold, as the
    // model's lag state assumes (steady state at the first row).
    let (next, truth) = recording(&[0.0, 1500.0, 0.0, 3000.0], 11, false);
    let next_path = dir.path().join("next.csv");
    std::fs::write(&next_path, next).unwrap();
    let ev = bin()
        .args(["eval", "--model"])
        .arg(out_dir.join("model.toml"))
        .arg("--path")
        .arg(&next_path)
        .output()
        .unwrap();
    assert!(
        ev.status.success(),
        "{}",
        String::from_utf8_lossy(&ev.stderr)
    );
    let text = String::from_utf8(ev.stdout).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let k = head.iter().position(|h| *h == "ez_um").unwrap();
    let pred: Vec<f64> = lines
        .map(|l| l.split(',').nth(k).unwrap().parse().unwrap())
        .collect();
    assert_eq!(pred.len(), truth.len());
    let err = (pred
        .iter()
        .zip(&truth)
        .map(|(p, t)| (p - t).powi(2))
        .sum::<f64>()
        / truth.len() as f64)
        .sqrt();
    let size = (truth.iter().map(|t| t * t).sum::<f64>() / truth.len() as f64).sqrt();
    assert!(err < 0.1 * size, "forward error {err} µm RMS of {size} µm");
}
