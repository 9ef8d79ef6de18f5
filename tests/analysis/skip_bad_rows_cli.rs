//! `--skip-bad-rows` (issue 12.5, 14.5): `retrocomp diagnose` and `retrocomp fit thermal` keep going
//! past bad rows of a recording and report every skipped line — on stderr, and under
//! `skipped_rows` in the JSON (diagnose: also in `--out`'s report.json). Without the flag the same
//! file is refused with the lines listed.

use std::path::{Path, PathBuf};
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

/// A thermal recording (error = 2 µm/K × temperature rise, plus a ±0.3 µm deterministic wobble)
/// with three bad rows; returns the file and the bad rows' 1-based line numbers.
fn recording_with_bad_rows(dir: &Path) -> (PathBuf, Vec<u64>) {
    let mut s = String::from("t_s,x_mm,T_a_C,ex_um,sim_ex_um\n");
    let mut bad = vec![];
    for i in 0..400 {
        let t = 10.0 * f64::from(i);
        let temp = 20.0 + 5.0 * (1.0 - (-t / 1500.0).exp());
        let e = 2.0 * (temp - 20.0) + 0.3 * (f64::from(i) * 0.7).sin();
        let x = 50.0 * f64::from(i % 5);
        // Line numbers: the header is line 1, row i is line i + 2 (bad rows are extra lines).
        let line = s.lines().count() as u64 + 1;
        match i {
            57 => {
                s.push_str(&format!("{t},{x},oops,{e},0\n"));
                bad.push(line);
                continue;
            }
            123 => {
                s.push_str(&format!("{t},{x},NaN,{e},0\n"));
                bad.push(line);
                continue;
            }
            301 => {
                s.push_str(&format!("{t},{x},{temp}\n"));
                bad.push(line);
                continue;
            }
            _ => {}
        }
        s.push_str(&format!("{t},{x},{temp},{e},0\n"));
    }
    let p = dir.join("rec.csv");
    std::fs::write(&p, s).unwrap();
    (p, bad)
}

fn lines_of(j: &serde_json::Value) -> Vec<u64> {
    j["skipped_rows"]
        .as_array()
        .unwrap_or_else(|| panic!("no skipped_rows: {j}"))
        .iter()
        .map(|r| r["line"].as_u64().unwrap())
        .collect()
}

fn stderr_lists(stderr: &str, rec: &Path, bad: &[u64]) {
    for l in bad {
        assert!(
            stderr.contains(&format!("{}: skipped line {l}", rec.display())),
            "line {l} not listed: {stderr}"
        );
    }
}

#[test]
fn diagnose_lists_every_skipped_line_in_the_json_and_report_json() {
    let tmp = tempfile::tempdir().unwrap();
    let (rec, bad) = recording_with_bad_rows(tmp.path());
    assert_eq!(bad.len(), 3);
    let refused = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(&rec)
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(err.contains(&format!("line {}", bad[0])), "{err}");

    let out = tmp.path().join("out");
    let o = bin()
        .args(["diagnose", "--json", "--skip-bad-rows", "--recording"])
        .arg(&rec)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    stderr_lists(&err, &rec, &bad);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(lines_of(&j), bad);
    let rows = j["skipped_rows"].as_array().unwrap();
    assert_eq!(rows[0]["column"], "T_a_C");
    assert!(rows[0]["reason"].as_str().unwrap().contains("oops"));
    assert!(rows[2]["column"].is_null(), "a short row has no column");
    // The contract's keys are all still there, and report.json says the same.
    for k in [
        "verdict",
        "rms_before_um",
        "mismatch",
        "findings",
        "alternatives",
    ] {
        assert!(j.get(k).is_some(), "missing {k}");
    }
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(lines_of(&written), bad);

    // Without --skip-bad-rows on a clean file there is no extra key.
    let clean = tmp.path().join("clean.csv");
    let text = std::fs::read_to_string(&rec).unwrap();
    let kept: Vec<&str> = text
        .lines()
        .enumerate()
        .filter(|(k, _)| !bad.contains(&(*k as u64 + 1)))
        .map(|(_, l)| l)
        .collect();
    std::fs::write(&clean, kept.join("\n") + "\n").unwrap();
    let o = bin()
        .args(["diagnose", "--json", "--recording"])
        .arg(&clean)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(j.get("skipped_rows").is_none());
}

#[test]
fn fit_thermal_skips_and_reports_every_bad_line() {
    let tmp = tempfile::tempdir().unwrap();
    let (rec, bad) = recording_with_bad_rows(tmp.path());
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/demo/mill-base.toml");
    let fit = |extra: &[&str]| {
        bin()
            .args(["fit", "thermal"])
            .arg(&rec)
            .args(["--signal", "ex_um", "--base-model"])
            .arg(&base)
            .args(extra)
            .output()
            .unwrap()
    };
    let refused = fit(&["--json"]);
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains(&format!("line {}", bad[1])),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    let o = fit(&["--json", "--skip-bad-rows"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    stderr_lists(&err, &rec, &bad);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(lines_of(&j), bad);
    // The fit on the kept rows finds the 2 µm/K of the data.
    let term = &j["fit"]["model"]["terms"][0];
    assert_eq!(term["signal"], "T_a_C", "{j}");
    assert!((term["coef"].as_f64().unwrap() - 2.0).abs() < 0.05, "{j}");
    // Text mode says how many were skipped.
    let o = fit(&["--skip-bad-rows"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("skipped 3 bad row(s)"), "{text}");
}
