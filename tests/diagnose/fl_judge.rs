//! The judge, emulated inside the shared FL_THERMAL data (issue 12 item 7, issue 36 point 2;
//! docs/diagnose.md "Judging harness"). retrocomp is judged on the withheld last 40 % of the
//! recording: per channel d1…d5, `retrocomp eval --model deploy/models/fl_thermal/dK/model.toml
//! --path WITHHELD.csv` against a static regression on the 3 best-correlated temperatures fitted on
//! everything shared.
//!
//! Here the shared rows play both parts: for each forward split (fit on the first 50 %, 60 %,
//! 70 %, 80 % of the rows, predict the rest), the simulation and diagnose see only the fit rows,
//! and the found `model.toml` is run over the later rows fed BOTH ways the judge may feed them:
//! (a) `alone`: a file holding only the later rows (it starts mid-run, after the fit rows end), and
//! (b) `history`: a file holding every row, scored on the later rows only.
//! The found model stores where its lags stood at the last fit row (`[lag_state]`), so (a) and (b)
//! agree (asserted, to 10⁻⁴ µm).
//! Held-out RMS = RMS of measured − predicted over the later rows. Asserted on every split and
//! both feeding modes (issue 36 point 2): no channel worse than the static regression, and the
//! median cut ≥ 25 %. What `model.toml` holds per channel is what diagnose's rolling origin over
//! the fit file's spindle-speed regimes chose (`crates/analysis/src/diagnose/regimes.rs`): the named terms, a
//! statistical compensation fit, or the simulation alone; the report's `forward_check[].regimes`
//! says which and is printed with the table.
//! Also printed, not asserted: the structure of the shipped whole-file models
//! (`deploy/models/fl_thermal/d<k>/found_terms.toml`: sensors and τ kept, gains and offset refitted
//! on the fit rows, as in `fl_loo`). Their structure was chosen on every shared row, the
//! later rows included, so that column is optimistic for them.

use std::path::Path;

use crate::fl_support;
use fl_support::*;

const CHANNELS: [&str; 5] = ["d1_um", "d2_um", "d3_um", "d4_um", "d5_um"];
const SPLITS: [f64; 4] = [0.5, 0.6, 0.7, 0.8];

struct Row {
    split: f64,
    ch: &'static str,
    /// What `model.toml` holds (`forward_check[].regimes.written`) and the named terms.
    written: String,
    sim: [f64; 2],
    diag: [f64; 2],
    shape: [f64; 2],
}

fn held_out_rms(meas: &[f64], pred: &[f64]) -> f64 {
    rms(meas.iter().zip(pred).map(|(m, p)| m - p))
}

fn judge_split(d: &Data, split: f64, tmp: &Path) -> Vec<Row> {
    let n = d.n();
    let k = (split * n as f64).round() as usize;
    let alone = tmp.join(format!("alone_{k}.csv"));
    let history = tmp.join(format!("history_{k}.csv"));
    d.write(&alone, k..n, None);
    d.write(&history, 0..n, None);
    let fit: Vec<usize> = (0..k).collect();
    CHANNELS
        .iter()
        .map(|&ch| {
            let dir = tmp.join(format!("{k}_{ch}"));
            let (sim, model, report) = fit_channel(d, ch, &fit, &dir);
            std::fs::write(dir.join("report.txt"), &report).unwrap();
            let written = written_of(&dir, &report);
            let shape = shipped_shape(d, ch, &fit, &dir);
            let meas = &d.col(ch)[k..n];
            let score = |m: &Path| {
                [
                    held_out_rms(meas, &eval(m, &alone)),
                    held_out_rms(meas, &eval(m, &history)[k..]),
                ]
            };
            Row {
                split,
                ch,
                written,
                sim: score(&sim),
                diag: score(&model),
                shape: score(&shape),
            }
        })
        .collect()
}

/// What the channel's `model.toml` holds, from diagnose's report: `named: <findings>`,
/// `statistical` or `simulation`.
fn written_of(dir: &Path, report: &str) -> String {
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    // Every channel of a thermal test is judged on later regimes, and the report says in words
    // when the named physics loses to the statistical fit (issue 36 point 1).
    let regimes = &json["forward_check"][0]["regimes"];
    let written = regimes["written"]
        .as_str()
        .unwrap_or_else(|| panic!("no forward_check[0].regimes in {}", dir.display()))
        .to_string();
    let (named_um, stat_um) = (
        regimes["rms_named_um"].as_f64().unwrap(),
        regimes["rms_statistical_um"].as_f64().unwrap(),
    );
    assert_eq!(
        stat_um < named_um,
        report.contains("the named physics does NOT beat a purely statistical compensation fit"),
        "{}: {report}",
        dir.display()
    );
    let named: Vec<String> = json["findings"]
        .as_array()
        .map(|a| {
            a.iter()
                .map(|f| {
                    let p = &f["params"];
                    format!(
                        "{}({}{})",
                        f["effect"].as_str().unwrap_or("?"),
                        p["sensor"].as_str().unwrap_or("?"),
                        p["tau_s"]
                            .as_f64()
                            .map_or(String::new(), |t| format!(", {t:.0} s"))
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    format!("{written}; named: {}", named.join(" + "))
}

#[test]
fn fl_thermal_judge_emulated_on_forward_splits_no_channel_worse() {
    let d = Data::load();
    let tmp = tempfile::tempdir().unwrap();
    // FL_JUDGE_DIR=DIR keeps every split's sim.toml, model.toml and report for inspection.
    let root = std::env::var_os("FL_JUDGE_DIR")
        .map_or_else(|| tmp.path().to_path_buf(), std::path::PathBuf::from);
    let rows: Vec<Row> = SPLITS
        .iter()
        .flat_map(|&s| judge_split(&d, s, &root))
        .collect();
    let mut table = String::from(
        "split ch   | static µm | alone µm  cut % | history µm  cut % | shipped shape alone, history cut % | model.toml holds\n",
    );
    let cut = |a: f64, b: f64| 100.0 * (1.0 - a / b);
    for r in &rows {
        table.push_str(&format!(
            "{:>4.0} % {} | {:9.2} | {:8.2} {:6.1} | {:10.2} {:6.1} | {:6.2} {:6.1}, {:6.2} {:6.1} | {}\n",
            100.0 * r.split,
            r.ch.trim_end_matches("_um"),
            r.sim[0],
            r.diag[0],
            cut(r.diag[0], r.sim[0]),
            r.diag[1],
            cut(r.diag[1], r.sim[1]),
            r.shape[0],
            cut(r.shape[0], r.sim[0]),
            r.shape[1],
            cut(r.shape[1], r.sim[1]),
            r.written,
        ));
    }
    let mut medians = vec![];
    for (mode, m) in [("alone", 0), ("history", 1)] {
        for &s in &SPLITS {
            let mut cuts: Vec<f64> = rows
                .iter()
                .filter(|r| r.split == s)
                .map(|r| 1.0 - r.diag[m] / r.sim[m])
                .collect();
            cuts.sort_by(f64::total_cmp);
            medians.push((mode, s, cuts[2]));
            let mut shape_cuts: Vec<f64> = rows
                .iter()
                .filter(|r| r.split == s)
                .map(|r| 1.0 - r.shape[m] / r.sim[m])
                .collect();
            shape_cuts.sort_by(f64::total_cmp);
            table.push_str(&format!(
                "median cut, {mode}, fit on {:.0} %: {:.1} % (shipped shape {:.1} %)\n",
                100.0 * s,
                100.0 * cuts[2],
                100.0 * shape_cuts[2]
            ));
        }
    }
    eprintln!("{table}");
    // The static regression does not depend on history; both modes must agree on it.
    for r in &rows {
        assert!(
            (r.sim[0] - r.sim[1]).abs() <= 1e-6 * r.sim[0].max(1.0),
            "static simulation differs between feeding modes\n{table}"
        );
    }
    // `diagnose --out` stores where the lags stood at the last fit row (`[lag_state]`), so the
    // found model run over the later rows alone continues the recording as if fed from its start.
    for r in &rows {
        assert!(
            (r.diag[0] - r.diag[1]).abs() <= 1e-4,
            "{} fit on {:.0} %: alone {:.6} µm, history {:.6} µm: the stored lag state did not \
             carry over\n{table}",
            r.ch,
            100.0 * r.split,
            r.diag[0],
            r.diag[1]
        );
    }
    for r in &rows {
        for (mode, m) in [("alone", 0), ("history", 1)] {
            assert!(
                r.diag[m] <= r.sim[m],
                "{} fit on {:.0} % fed {mode}: {:.2} µm > static {:.2} µm\n{table}",
                r.ch,
                100.0 * r.split,
                r.diag[m],
                r.sim[m]
            );
        }
    }
    for (mode, s, c) in medians {
        assert!(
            c >= 0.25,
            "fit on {:.0} % fed {mode}: median cut {c:.3} < 0.25\n{table}",
            100.0 * s
        );
    }
}
