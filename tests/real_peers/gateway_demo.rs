//! `retrocomp demo --json` end to end: the real retrocomp binary spawns the real hil-sim binary
//! (hidden geometry from deploy/demo/mill-geometric.toml, accelerated thermal warm-up, cutting
//! force) and runs the gateway against it over a socketcand hub and Modbus TCP on 127.0.0.1, four
//! times. With the truth model (geometry + thermal) the max volumetric error must fall ≥ 80 %; with
//! the model fitted from hil-sim's own measurement runs it must be present, finite and better than
//! no compensation (its figure is printed, not promised: docs/demo.md states the measured one).

use std::process::Command;

use crate::hil_sim;
use hil_sim::hil_sim_next_to_retrocomp;

#[test]
fn demo_json_full_model_cuts_volumetric_error_by_80_percent() {
    let _turn = crate::turn::take(file!());
    let hil_sim = hil_sim_next_to_retrocomp();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let t0 = std::time::Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["demo", "--json", "--out"])
        .arg(&out_dir)
        .env("HIL_SIM_BIN", &hil_sim)
        .output()
        .unwrap();
    let wall_s = t0.elapsed().as_secs_f64();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo failed\n{stdout}\n{stderr}");
    let last = stdout.lines().last().expect("no output");
    let v: serde_json::Value = serde_json::from_str(last)
        .unwrap_or_else(|e| panic!("last line is not JSON ({e}): {last}"));
    let num = |mode: &str, path: &[&str]| -> f64 {
        let mut x = &v[mode];
        for p in path {
            x = &x[p];
        }
        x.as_f64()
            .unwrap_or_else(|| panic!("{mode}.{path:?} missing: {last}"))
    };
    for mode in ["uncompensated", "geometric", "full", "fitted"] {
        for ax in ["x", "y", "z"] {
            let (rms, max) = (num(mode, &[ax, "rms_um"]), num(mode, &[ax, "max_um"]));
            assert!(
                rms.is_finite() && max.is_finite() && rms >= 0.0 && rms <= max,
                "{mode}.{ax}: rms {rms} max {max}"
            );
        }
    }
    let (unc, geo, full, fitted) = (
        num("uncompensated", &["volumetric_max_um"]),
        num("geometric", &["volumetric_max_um"]),
        num("full", &["volumetric_max_um"]),
        num("fitted", &["volumetric_max_um"]),
    );
    let fall_pct = 100.0 * (1.0 - full / unc);
    let fitted_pct = 100.0 * (1.0 - fitted / unc);
    eprintln!(
        "volumetric max: {unc:.2} → geometric {geo:.2} → full {full:.2} µm ({fall_pct:.1} %), \
         fitted {fitted:.2} µm ({fitted_pct:.1} %), {wall_s:.1} s wall"
    );
    assert!(
        fitted.is_finite() && fitted < unc,
        "fitted {fitted} vs uncompensated {unc}"
    );
    for ax in ["x", "y", "z"] {
        let (f, u) = (
            num("fitted", &[ax, "rms_um"]),
            num("uncompensated", &[ax, "rms_um"]),
        );
        assert!(f < u, "fitted {ax} rms {f} not below uncompensated {u}");
    }
    // The fit found the dominant hidden physics from the measurement runs alone: the spindle's
    // thermal growth on Z (hidden: −6 µm/K, deploy/demo/sim.toml) …
    let fitted_toml = std::fs::read_to_string(out_dir.join("models/mill-fitted.toml")).unwrap();
    let model = retrocomp_model::MachineModel::from_toml_str(&fitted_toml, "mill-fitted.toml")
        .unwrap_or_else(|e| panic!("{e}\n{fitted_toml}"));
    let growth = model.spec().thermal.iter().find_map(|t| match &t.kind {
        retrocomp_model::ThermalKind::PolynomialDt {
            sensors, b_per_k, ..
        } if t.target.iso_name() == "EZZ" => sensors
            .iter()
            .position(|s| s == "spindle")
            .map(|k| b_per_k[k]),
        _ => None,
    });
    assert!(
        growth.is_some_and(|b| (b + 6.0).abs() < 0.3),
        "EZZ growth {growth:?}\n{fitted_toml}"
    );
    // … and the measurement campaign left its laser-style readings for `retrocomp fit axis`.
    let exx = std::fs::read_to_string(out_dir.join("campaign/readings_EXX.csv")).unwrap();
    assert!(exx.contains("target_mm,run,direction,deviation_um") && exx.lines().count() > 80);
    // The hidden errors are tens of µm; a demo that moved nothing would pass the ratio trivially.
    assert!(unc > 20.0, "uncompensated volumetric max only {unc} µm");
    assert!(
        fall_pct >= 80.0,
        "full model: max volumetric error falls only {fall_pct:.1} %"
    );
    // Geometric-only removes the Y errors (pure geometry in this machine) but not the thermal Z growth.
    assert!(
        num("geometric", &["y", "max_um"]) < 0.3 * num("uncompensated", &["y", "max_um"]),
        "{last}"
    );
    assert!(
        num("geometric", &["z", "max_um"]) > 0.5 * num("uncompensated", &["z", "max_um"]),
        "{last}"
    );
    // The files the demo promises.
    for mode in ["uncompensated", "geometric", "full", "fitted"] {
        let rec = out_dir.join(mode).join("recording.csv");
        let text = std::fs::read_to_string(&rec).unwrap();
        assert!(
            text.starts_with("t_s,") && text.lines().count() > 1000,
            "{}",
            rec.display()
        );
    }
    for svg in [
        "error_x.svg",
        "error_y.svg",
        "error_z.svg",
        "volumetric.svg",
    ] {
        let text = std::fs::read_to_string(out_dir.join(svg)).unwrap();
        assert!(
            text.contains("<polyline") && text.contains("uncompensated") && text.contains("fitted"),
            "{svg}: no curves or legend"
        );
        // The second panel (full and fitted on their own scale) and the phases found in the
        // recording (src/demo/plot_tests.rs checks their geometry).
        for label in ["(full, fitted)", "warm-up", "cut", "cool-down"] {
            assert!(text.contains(label), "{svg}: no `{label}`");
        }
    }
}

#[test]
fn demo_without_hil_sim_says_how_to_build_it() {
    let _turn = crate::turn::take(file!());
    // A copy of retrocomp alone in a folder, with HIL_SIM_BIN unset: a clear error, no hang.
    // A hard link in the target dir (same file system) instead of a 100 MB copy of a debug binary.
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let exe = dir.path().join("retrocomp");
    if std::fs::hard_link(env!("CARGO_BIN_EXE_retrocomp"), &exe).is_err() {
        std::fs::copy(env!("CARGO_BIN_EXE_retrocomp"), &exe).unwrap();
    }
    let out = Command::new(&exe)
        .args(["demo", "--out"])
        .arg(dir.path().join("o"))
        .env_remove("HIL_SIM_BIN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("cargo build --release --workspace"), "{err}");
}

#[test]
fn demo_serve_refuses_an_address_it_cannot_listen_on_before_the_runs() {
    let _turn = crate::turn::take(file!());
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    // A port held here, and a host name (the gateway's `status_listen` takes IP:PORT only).
    for (serve, why) in [
        (
            addr.as_str(),
            format!("--serve {addr}: cannot listen there"),
        ),
        (
            "localhost:8080",
            "--serve localhost:8080: expected IP:PORT".into(),
        ),
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
            .args(["demo", "--seconds", "0", "--serve", serve, "--out"])
            .arg(dir.path().join("o"))
            .stdin(std::process::Stdio::null())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{err}");
        assert!(err.contains(&why), "{err}");
        // Refused before the first run: nothing was written.
        assert!(!dir.path().join("o").exists(), "{err}");
    }
}
