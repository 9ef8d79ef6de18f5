//! `retrocomp diagnose` end to end: the docs/diagnose-json.md JSON keys, `--out` files (SVG plots whose text
//! renders, found-terms TOML, and `model.toml`, which `check-config` accepts and `eval` evaluates to
//! the found term — with and without `--model`), `--model` as the simulation, and a bad recording
//! refused with its line.

use std::process::Command;

use crate::pixels;

use retrocomp_model::recording::Recording;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

/// A small step-and-dwell recording with a 6 µm backlash on X and white-ish noise.
fn backlash_recording(dir: &std::path::Path) -> std::path::PathBuf {
    backlash_recording_with(dir, &[])
}

/// [`backlash_recording`] with `spikes` (row, µm) added to the error: servo-lag outliers.
fn backlash_recording_with(dir: &std::path::Path, spikes: &[(usize, f64)]) -> std::path::PathBuf {
    let n = 800;
    let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let x: Vec<f64> = (0..n)
        .map(|i| {
            let k = (i / 8) % 20;
            20.0 * if k < 10 { k as f64 } else { (20 - k) as f64 }
        })
        .collect();
    let mut dir_latch = 1.0;
    let mut ex = vec![];
    for i in 0..n {
        if i > 0 && (x[i] - x[i - 1]).abs() > 0.0 {
            dir_latch = (x[i] - x[i - 1]).signum();
        }
        // Deterministic pseudo-noise (no RNG needed): ±0.4 µm.
        let noise = 0.4 * ((i as f64 * 12.9898).sin() * 43758.5453).fract();
        ex.push(3.0 * dir_latch + noise);
    }
    for (i, v) in spikes {
        ex[*i] += v;
    }
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t),
        ("x_mm".into(), x),
        ("ex_um".into(), ex),
        ("sim_ex_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let p = dir.join("rec.csv");
    rec.write_csv(std::fs::File::create(&p).unwrap()).unwrap();
    p
}

/// `diagnose --json --recording REC --out OUT`: its JSON.
fn diagnose_json_out(rec: &std::path::Path, out: &std::path::Path) -> serde_json::Value {
    let o = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(rec)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // stderr is a pipe here: no progress line, no colour (src/cli/term.rs).
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !err.contains('\x1b') && !err.contains("diagnose: reading") && !err.contains('\r'),
        "{err}"
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn json_output_follows_the_contract_and_out_dir_has_plots_and_terms() {
    let tmp = tempfile::tempdir().unwrap();
    let rec = backlash_recording(tmp.path());
    let out = tmp.path().join("out");
    let j = diagnose_json_out(&rec, &out);
    for k in [
        "verdict",
        "rms_before_um",
        "mismatch",
        "findings",
        "alternatives",
    ] {
        assert!(j.get(k).is_some(), "missing key {k}");
    }
    assert_eq!(j["verdict"], "found");
    let f = &j["findings"][0];
    assert_eq!(f["effect"], "backlash");
    assert_eq!(f["axis"], "x");
    assert_eq!(f["signal"], "ex_um");
    let b = f["params"]["b_um"].as_f64().unwrap();
    assert!((b - 6.0).abs() < 0.3, "b_um {b}");
    let ci = f["ci95"]["b_um"].as_array().unwrap();
    assert!(ci[0].as_f64().unwrap() < b && b < ci[1].as_f64().unwrap());
    for k in ["delta_bic", "p_value"] {
        assert!(f["evidence"][k].is_number());
    }
    for k in [
        "rms_after_um",
        "heldout_rms_before_um",
        "heldout_rms_after_um",
        "explanation",
        "equation",
    ] {
        assert!(f.get(k).is_some(), "finding lacks {k}");
    }
    let svg = std::fs::read_to_string(out.join("residual_ex_um_vs_x_mm.svg")).unwrap();
    assert!(
        svg.contains("<text") && svg.contains("residual"),
        "plot text must render"
    );
    assert!(svg.contains("<circle"), "plot has points");
    assert_figures_clear(&out);
    let toml_text = std::fs::read_to_string(out.join("found_terms.toml")).unwrap();
    let v: toml::Value = toml::from_str(&toml_text).unwrap();
    assert_eq!(v["term"][0]["effect"].as_str(), Some("backlash"));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report, j);
}

#[test]
fn model_option_evaluates_the_machine_model_as_simulation() {
    let tmp = tempfile::tempdir().unwrap();
    // The recording's error is a pure EXX scale of 50 ppm; the model states exactly that, so the
    // residual is zero and nothing is found; without the model, scale_error is found.
    let n = 400;
    let x: Vec<f64> = (0..n).map(|i| ((i * 7) % 300) as f64).collect();
    let ex: Vec<f64> = x.iter().map(|v| 0.05 * v).collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), (0..n).map(|i| i as f64).collect()),
        ("x_mm".into(), x),
        ("z_mm".into(), vec![0.0; n]),
        ("ex_um".into(), ex),
        ("sim_ex_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let rp = tmp.path().join("r.csv");
    rec.write_csv(std::fs::File::create(&rp).unwrap()).unwrap();
    let model = tmp.path().join("m.toml");
    std::fs::write(
        &model,
        "schema = 1\n[machine]\nname = \"t\"\nchain = \"Z X\"\ntool_axis = \"+x\"\n\
         [axes.z]\ntravel_mm = [0.0, 10.0]\n[axes.x]\ntravel_mm = [0.0, 300.0]\n\
         [[tools]]\nname = \"t\"\noffset_mm = [0.0, 0.0, 0.0]\n\
         [[components]]\nname = \"EXX\"\npositions_mm = [0, 300]\nforward_mm = [0.0, 0.015]\n",
    )
    .unwrap();
    let with = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(&rp)
        .arg("--model")
        .arg(&model)
        .output()
        .unwrap();
    assert!(
        with.status.success(),
        "{}",
        String::from_utf8_lossy(&with.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&with.stdout).unwrap();
    assert!(j["rms_before_um"].as_f64().unwrap() < 0.01, "{j}");
    assert_eq!(j["verdict"], "none");
    let without = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(&rp)
        .output()
        .unwrap();
    let j: serde_json::Value = serde_json::from_slice(&without.stdout).unwrap();
    assert_eq!(j["findings"][0]["effect"], "scale_error");
    assert!((j["findings"][0]["params"]["ppm"].as_f64().unwrap() - 50.0).abs() < 1e-6);
}

#[test]
fn bad_rows_are_refused_with_their_line_numbers() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("bad.csv");
    std::fs::write(
        &p,
        "t_s,x_mm,ex_um,sim_ex_um\n0,0,1,0\n1,1,oops,0\n-0.5,2,1,0\n",
    )
    .unwrap();
    let o = bin()
        .args(["diagnose", "--recording"])
        .arg(&p)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("line 3, column `ex_um`: `oops` is not a number"),
        "{e}"
    );
    assert!(
        e.contains("line 4, column `t_s`: time goes backwards"),
        "{e}"
    );
}

/// `retrocomp eval` of `model` along (x, dir_x) points (extra columns given as `extra`): ex_um.
fn eval_ex(
    model: &std::path::Path,
    pts: &[(f64, i8)],
    extra: &str,
    dir: &std::path::Path,
) -> Vec<f64> {
    let path = dir.join("path.csv");
    let mut text = format!(
        "x_mm,dir_x{}\n",
        if extra.is_empty() {
            String::new()
        } else {
            format!(",{extra}")
        }
    );
    for (x, d) in pts {
        let zeros = extra
            .split(',')
            .filter(|c| !c.is_empty())
            .map(|_| ",0")
            .collect::<String>();
        text.push_str(&format!("{x},{d}{zeros}\n"));
    }
    std::fs::write(&path, text).unwrap();
    let o = bin()
        .args(["eval", "--model"])
        .arg(model)
        .arg("--path")
        .arg(&path)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8(o.stdout).unwrap();
    let mut lines = out.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let k = head.iter().position(|h| *h == "ex_um").unwrap();
    lines
        .map(|l| l.split(',').nth(k).unwrap().parse().unwrap())
        .collect()
}

fn check_config(model: &std::path::Path) {
    let o = bin().arg("check-config").arg(model).output().unwrap();
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn out_model_toml_loads_and_evaluates_to_the_found_backlash() {
    let tmp = tempfile::tempdir().unwrap();
    let rec = backlash_recording(tmp.path());
    let out = tmp.path().join("out");
    let o = bin()
        .args(["diagnose", "--recording"])
        .arg(&rec)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(
        text.contains("added: backlash on x (ex_um) → EXX table"),
        "{text}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let b = report["findings"][0]["params"]["b_um"].as_f64().unwrap();
    let model = out.join("model.toml");
    let toml_text = std::fs::read_to_string(&model).unwrap();
    assert!(
        toml_text.contains("# Base: no --model given"),
        "{toml_text}"
    );
    check_config(&model);
    // The recording has only x: the default chain is "X F Y" (y a placeholder, given as 0).
    let ex = eval_ex(
        &model,
        &[(0.0, 1), (90.0, 1), (90.0, -1), (180.0, -1)],
        "y_mm",
        tmp.path(),
    );
    assert_eq!(ex.len(), 4, "one value per query point: {ex:?}");
    for (v, want) in ex.iter().zip([b / 2.0, b / 2.0, -b / 2.0, -b / 2.0]) {
        assert!((v - want).abs() < 1e-6, "{ex:?} vs b/2 = {}", b / 2.0);
    }
}

#[test]
fn with_model_the_out_model_is_the_input_model_plus_the_found_term() {
    let tmp = tempfile::tempdir().unwrap();
    // Truth: EXX = 50 ppm scale (in the input model) + a 6 µm backlash (not in it). Step-and-dwell.
    let n = 800;
    let x: Vec<f64> = (0..n)
        .map(|i| {
            let k = (i / 8) % 20;
            30.0 * if k < 10 { k as f64 } else { (20 - k) as f64 }
        })
        .collect();
    let mut dir = 1.0;
    let mut ex = vec![];
    for i in 0..n {
        if i > 0 && x[i] != x[i - 1] {
            dir = (x[i] - x[i - 1]).signum();
        }
        let noise = 0.3 * ((i as f64 * 12.9898).sin() * 43758.5453).fract();
        ex.push(0.05 * x[i] + 3.0 * dir + noise);
    }
    let rec = Recording::from_columns(vec![
        ("t_s".into(), (0..n).map(|i| i as f64).collect()),
        ("x_mm".into(), x),
        ("z_mm".into(), vec![0.0; n]),
        ("ex_um".into(), ex),
    ])
    .unwrap();
    let rp = tmp.path().join("r.csv");
    rec.write_csv(std::fs::File::create(&rp).unwrap()).unwrap();
    let base = tmp.path().join("m.toml");
    std::fs::write(
        &base,
        "schema = 1\n[machine]\nname = \"lathe\"\nchain = \"Z X\"\ntool_axis = \"+x\"\n\
         [axes.z]\ntravel_mm = [0.0, 10.0]\n[axes.x]\ntravel_mm = [0.0, 300.0]\n\
         [[tools]]\nname = \"t\"\noffset_mm = [0.0, 0.0, 0.0]\n\
         [[components]]\nname = \"EXX\"\npositions_mm = [0, 300]\nforward_mm = [0.0, 0.015]\n\
         [[components]]\nname = \"EZZ\"\npositions_mm = [0, 10]\nforward_um = [0.0, 1.0]\n",
    )
    .unwrap();
    let out = tmp.path().join("out");
    let o = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(&rp)
        .arg("--model")
        .arg(&base)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(j["findings"][0]["effect"], "backlash", "{j}");
    let b = j["findings"][0]["params"]["b_um"].as_f64().unwrap();
    assert!((b - 6.0).abs() < 0.3, "{b}");
    let model = out.join("model.toml");
    let text = std::fs::read_to_string(&model).unwrap();
    assert!(text.contains("# Base: the input model `lathe`"), "{text}");
    check_config(&model);
    let m = retrocomp_model::MachineModel::from_toml_str(&text, "model.toml").unwrap();
    assert_eq!(
        m.spec().chain_string(),
        "F Z X",
        "the input chain \"Z X\" (no F = frame first)"
    );
    assert!(m.term_names().iter().any(|t| t == "EZZ"), "base terms kept");
    // EXX now = 50 ppm·x ± b/2 by approach direction, on the base's own table span.
    let pts = [(0.0, 1), (150.0, 1), (150.0, -1), (300.0, -1)];
    let ex = eval_ex(&model, &pts, "z_mm", tmp.path());
    assert_eq!(ex.len(), pts.len(), "one value per query point: {ex:?}");
    for ((x, d), v) in pts.iter().zip(&ex) {
        let want = 0.05 * x + f64::from(*d) * b / 2.0;
        assert!((v - want).abs() < 1e-6, "x {x} dir {d}: {v} vs {want}");
    }
}

/// Every SVG of `--out`: no data point under the legend, in its geometry and on its rendering.
fn assert_figures_clear(out: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut svgs: Vec<_> = std::fs::read_dir(out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "svg"))
        .collect();
    svgs.sort();
    assert!(!svgs.is_empty(), "--out wrote figures");
    for p in &svgs {
        pixels::assert_legend_clear_in_pixels(p, &p.display().to_string());
    }
    svgs
}

/// Three servo-lag spikes of −300 µm among ±3 µm: the residual's scale follows the residual (the
/// spikes are marked at the edge and counted), and the residual after the findings gets a figure
/// on its own scale.
#[test]
fn out_figures_keep_the_residual_scale_under_servo_lag_spikes() {
    let tmp = tempfile::tempdir().unwrap();
    let spikes: Vec<(usize, f64)> = [101, 413, 725].map(|i| (i, -300.0)).to_vec();
    let rec = backlash_recording_with(tmp.path(), &spikes);
    let out = tmp.path().join("out");
    let j = diagnose_json_out(&rec, &out);
    let svgs = assert_figures_clear(&out);
    assert_eq!(
        j["findings"][0]["effect"], "backlash",
        "found despite the spikes"
    );
    let before = std::fs::read_to_string(out.join("residual_ex_um_vs_t_s.svg")).unwrap();
    assert!(
        before.contains("point(s) beyond the scale"),
        "the spikes are counted at the edge, not stretching the scale"
    );
    assert!(before.contains("x position / mm") || before.contains("time / s"));
    // The y tick labels stay within µm of the residual: no tick near −300.
    for tick in [">-300.0<", ">-250.0<", ">-200.0<", ">-100.0<"] {
        assert!(!before.contains(tick), "scale set by the spikes: {tick}");
    }
    let after = out.join("residual_after_ex_um_vs_t_s.svg");
    assert!(
        svgs.contains(&after),
        "the residual after the findings on its own scale"
    );
    let a = std::fs::read_to_string(&after).unwrap();
    assert!(
        a.contains("after backlash: rms"),
        "per-finding rms beside it"
    );
}
