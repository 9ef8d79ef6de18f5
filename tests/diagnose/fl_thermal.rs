//! Real data, forward in time: FL_THERMAL (CAIVIAC, MIT licence; `tests/data/fl_thermal/`), a
//! machine tool run for 46 h with the spindle stepped through speeds, 16 temperatures and 5
//! displacement channels d1…d5 (µm, sign as recorded) every 15 s. The fixture is the first 60 %
//! (0–27.8 h: 1250, 0, 2500, 0, 3750, 0, 5000 rpm).
//!
//! Protocol (issue 12, item 7), per channel: the simulation is a static regression on the 3
//! temperatures best correlated with the channel, fitted on the first half (0–13.9 h: only 1250
//! and 2500 rpm), written as a machine model (`polynomial_dt` on EZZ); `retrocomp diagnose
//! --model SIM.toml --fit-offset --out DIR` sees only the first half (`ez_um` = the channel); `retrocomp eval
//! --model DIR/model.toml` runs the found model forward over the second half (3750 and 5000 rpm,
//! never seen), against `retrocomp eval --model SIM.toml`. Held-out RMS = RMS of measured −
//! predicted over the second half. Targets: no channel worse than the simulation, median cut ≥ 10 %
//! (asserted: ≥ 30 %, measured 35.1 %).
//!
//! `FL_THERMAL_MODELS_DIR=DIR cargo test --test diagnose fl_thermal::` also fits every channel on
//! the WHOLE fixture and writes DIR/d<k>/{sim.toml, model.toml} (the deployable models); without
//! it they are written to a temporary directory and must equal the shipped ones byte for byte.

use std::path::PathBuf;

use crate::fl_support;
use fl_support::*;

#[test]
fn fl_thermal_found_model_predicts_the_unseen_second_half() {
    let d = Data::load();
    let n = d.n();
    let h = n / 2;
    let tmp = tempfile::tempdir().unwrap();
    let next = tmp.path().join("next.csv");
    d.write(&next, h..n, None);
    let mut cuts = vec![];
    let mut table = String::new();
    for ch in ["d1_um", "d2_um", "d3_um", "d4_um", "d5_um"] {
        let dir = tmp.path().join(ch);
        let (sim, model, report) = fit_channel(&d, ch, &(0..h).collect::<Vec<_>>(), &dir);
        let meas = &d.col(ch)[h..n];
        let p_sim = eval(&sim, &next);
        let p_diag = eval(&model, &next);
        let r_sim = rms(meas.iter().zip(&p_sim).map(|(m, p)| m - p));
        let r_diag = rms(meas.iter().zip(&p_diag).map(|(m, p)| m - p));
        let cut = 1.0 - r_diag / r_sim;
        let physics: Vec<&str> = report
            .lines()
            .filter(|l| l.contains("sensor =") || l.contains("tau_s =") || l.contains("um_per_K ="))
            .collect();
        table.push_str(&format!(
            "{ch}: simulation {r_sim:.2} µm, diagnose {r_diag:.2} µm, cut {:.1} % | {}\n",
            100.0 * cut,
            physics.join(" ;").replace("  ", " ")
        ));
        cuts.push(cut);
    }
    eprintln!("{table}");
    for (ch, c) in ["d1", "d2", "d3", "d4", "d5"].iter().zip(&cuts) {
        assert!(
            *c >= 0.0,
            "{ch}: the found model is worse than the simulation on the unseen half\n{table}"
        );
    }
    let mut sorted = cuts.clone();
    sorted.sort_by(f64::total_cmp);
    // Issue target 10 %; with the krpm^2 driver the split gives 35.1 % (docs/diagnose.md).
    assert!(
        sorted[2] >= 0.30,
        "median held-out cut {:.3} < 0.30\n{table}",
        sorted[2]
    );
}

/// The deployable models: fitted on the whole fixture, each must load and run forward over the
/// whole fixture without axis columns and not be worse there than the simulation alone.
#[test]
fn fl_thermal_models_fitted_on_everything_run_forward() {
    let d = Data::load();
    let n = d.n();
    let tmp = tempfile::tempdir().unwrap();
    let root = std::env::var_os("FL_THERMAL_MODELS_DIR")
        .map_or_else(|| tmp.path().to_path_buf(), PathBuf::from);
    let all = tmp.path().join("all.csv");
    d.write(&all, 0..n, None);
    let centred = |v: Vec<f64>| rms(v.into_iter());
    for ch in ["d1_um", "d2_um", "d3_um", "d4_um", "d5_um"] {
        let dir = root.join(ch.trim_end_matches("_um"));
        let (sim, model, report) = fit_channel(&d, ch, &(0..n).collect::<Vec<_>>(), &dir);
        std::fs::write(dir.join("report.txt"), &report).unwrap();
        // The shipped models are what this code writes, bit for bit: a change of any number in
        // them is a change of the code, made on purpose and regenerated with this test.
        let shipped = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("deploy/models/fl_thermal")
            .join(dir.file_name().unwrap());
        for file in ["sim.toml", "model.toml", "found_terms.toml", "report.json"] {
            let read =
                |p: PathBuf| std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{p:?}: {e}"));
            assert!(
                read(dir.join(file)) == read(shipped.join(file)),
                "{ch}: {file} differs from {:?}; if the change is meant, regenerate them: \
                 FL_THERMAL_MODELS_DIR=deploy/models/fl_thermal cargo test --release --test diagnose \
                 -- fl_thermal::fl_thermal_models_fitted",
                shipped.join(file)
            );
        }
        // The forward check on real data (the report's `forward_check`): every channel's model,
        // its gains refitted on the first 60 % of the file, predicts the last 40 % better than
        // the offset alone (measured 2026-11-26: d1 4.75 → 2.33 … d3 8.58 → 7.26 µm).
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap())
                .unwrap();
        let fc = &json["forward_check"][0];
        let (offset_um, found_um) = (fc["rms_sim_um"].as_f64(), fc["rms_model_um"].as_f64());
        assert!(
            matches!((offset_um, found_um), (Some(o), Some(f)) if f < o),
            "{ch}: forward check {fc}"
        );
        // Terms the exchange step replaced are reported (issue 12 point 3): on this file d1 and
        // d5 each lose a first-step term to an exchange, which must be listed under `dropped`.
        if ch == "d1_um" || ch == "d5_um" {
            let json: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap())
                    .unwrap();
            let exchanged: Vec<&serde_json::Value> = json["dropped"]
                .as_array()
                .map(|a| a.iter().filter(|d| d["reason"] == "exchanged").collect())
                .unwrap_or_default();
            assert!(
                !exchanged.is_empty()
                    && exchanged
                        .iter()
                        .all(|d| { d["replaced_by"].as_array().is_some_and(|b| !b.is_empty()) }),
                "{ch}: no exchanged term under `dropped`:\n{report}"
            );
            assert!(report.contains("exchanged by"), "{ch}: {report}");
        }
        let meas = d.col(ch);
        let r_sim = centred(
            meas.iter()
                .zip(eval(&sim, &all))
                .map(|(m, p)| m - p)
                .collect(),
        );
        let r_diag = centred(
            meas.iter()
                .zip(eval(&model, &all))
                .map(|(m, p)| m - p)
                .collect(),
        );
        eprintln!(
            "{ch} (fitted on all): simulation {r_sim:.2} µm, with the found terms {r_diag:.2} µm"
        );
        assert!(
            r_diag <= r_sim * 1.001,
            "{ch}: {r_diag} > {r_sim} on the data it was fitted on"
        );
    }
}
