//! Shared by the FL_THERMAL tests (`fl_thermal`, `fl_judge`): the fixture
//! loader, the static 3-sensor simulation the judge compares against, and thin wrappers over
//! `retrocomp diagnose` / `retrocomp eval`.
//! Included by the `analysis` and `diagnose` test binaries, each using part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use retrocomp_analysis::diagnose::lsq;

pub(crate) const DATA: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/data/fl_thermal/fl_thermal_dev.csv"
);

pub(crate) struct Data {
    pub names: Vec<String>,
    pub cols: Vec<Vec<f64>>,
}

impl Data {
    pub(crate) fn load() -> Data {
        let text = std::fs::read_to_string(DATA).expect("fixture present");
        let mut lines = text.lines();
        let names: Vec<String> = lines
            .next()
            .expect("header")
            .split(',')
            .map(str::to_string)
            .collect();
        let mut cols = vec![vec![]; names.len()];
        for l in lines {
            for (c, v) in cols.iter_mut().zip(l.split(',')) {
                c.push(v.parse::<f64>().expect("number"));
            }
        }
        Data { names, cols }
    }
    pub(crate) fn col(&self, name: &str) -> &[f64] {
        let k = self.names.iter().position(|n| n == name).expect(name);
        &self.cols[k]
    }
    pub(crate) fn n(&self) -> usize {
        self.cols[0].len()
    }
    pub(crate) fn temps(&self) -> Vec<&str> {
        self.names
            .iter()
            .filter(|n| n.starts_with("T_"))
            .map(String::as_str)
            .collect()
    }
    /// `t_s, rpm, T_*` (+ `ez_um` = channel `ch`) over `rows` (row indices, in order; a set with
    /// a gap in time, e.g. one spindle block left out, is written as one file).
    pub(crate) fn write(
        &self,
        path: &Path,
        rows: impl IntoIterator<Item = usize>,
        ch: Option<&str>,
    ) {
        let mut names = vec!["t_s", "rpm"];
        names.extend(self.temps());
        let mut out = names.join(",");
        if ch.is_some() {
            out.push_str(",ez_um");
        }
        out.push('\n');
        for i in rows {
            let mut f: Vec<String> = names.iter().map(|n| self.col(n)[i].to_string()).collect();
            if let Some(c) = ch {
                f.push(self.col(c)[i].to_string());
            }
            out.push_str(&f.join(","));
            out.push('\n');
        }
        std::fs::write(path, out).unwrap();
    }
}

pub(crate) fn corr(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt()
}

/// The values of column `name` at `rows`.
pub(crate) fn pick(v: &[f64], rows: &[usize]) -> Vec<f64> {
    rows.iter().map(|&i| v[i]).collect()
}

/// The simulation's fit: channel `ch` regressed on its 3 temperatures best correlated over `rows`
/// (intercept first in `coef`).
pub(crate) fn sim_fit(d: &Data, ch: &str, rows: &[usize]) -> (Vec<String>, Vec<f64>) {
    let y = &pick(d.col(ch), rows);
    let temps: Vec<(&str, Vec<f64>)> = d
        .temps()
        .into_iter()
        .map(|t| (t, pick(d.col(t), rows)))
        .collect();
    let mut ranked: Vec<(f64, &str)> = temps.iter().map(|(t, v)| (corr(v, y).abs(), *t)).collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    let chosen: Vec<&str> = ranked.iter().take(3).map(|r| r.1).collect();
    let ones = vec![1.0; y.len()];
    let mut cols: Vec<&[f64]> = vec![&ones];
    let of = |t: &str| {
        &temps
            .iter()
            .find(|(n, _)| *n == t)
            .expect("a temperature")
            .1[..]
    };
    cols.extend(chosen.iter().map(|t| of(t)));
    let fit = lsq::fit(&cols, y);
    (chosen.iter().map(|s| s.to_string()).collect(), fit.coef)
}

/// The simulation of [`sim_fit`] as a machine model TOML (reference 0 °C, e0 = intercept).
pub(crate) fn sim_model(d: &Data, ch: &str, rows: &[usize]) -> (String, Vec<String>) {
    let (chosen, coef) = sim_fit(d, ch, rows);
    let sensor = |t: &str| {
        t.trim_start_matches("T_")
            .trim_end_matches("_C")
            .to_string()
    };
    let mut toml = String::from(
        "schema = 1\n[machine]\nname = \"fl-static-sim\"\nchain = \"X F Y Z\"\ntool_axis = \"-z\"\n\
         [axes.x]\n[axes.y]\n[axes.z]\n[[tools]]\nname = \"tool\"\noffset_mm = [0.0, 0.0, 0.0]\n",
    );
    for t in &chosen {
        toml.push_str(&format!(
            "[[sensors]]\nname = \"{}\"\nreference_C = 0.0\n",
            sensor(t)
        ));
    }
    toml.push_str(&format!(
        "[[thermal]]\nname = \"static_sim\"\ntarget = \"EZZ\"\nkind = \"polynomial_dt\"\nsensors = [{}]\ne0_um = {}\nb_um_per_K = [{}]\n",
        chosen
            .iter()
            .map(|t| format!("\"{}\"", sensor(t)))
            .collect::<Vec<_>>()
            .join(", "),
        coef[0],
        coef[1..]
            .iter()
            .map(f64::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    ));
    (toml, chosen)
}

/// One term of a found model's structure: what it reads (`T_<n>_C`, `rpm` or `krpm^2`) and its
/// lag (`None`: read as is, a `thermal_drift`).
#[derive(Clone, Debug)]
pub(crate) struct Shape {
    pub sensor: String,
    pub tau_s: Option<f64>,
}

/// The structure of a `found_terms.toml` (thermal drift / lag terms only).
pub(crate) fn shapes_of(found_terms: &Path) -> Vec<Shape> {
    let text = std::fs::read_to_string(found_terms).unwrap();
    let v: toml::Value = toml::from_str(&text).unwrap();
    v.get("term")
        .and_then(toml::Value::as_array)
        .map(|a| {
            a.iter()
                .map(|t| {
                    let p = &t["params"];
                    let tau_s = match t["effect"].as_str() {
                        Some("thermal_lag") => Some(p["tau_s"].as_float().unwrap()),
                        Some("thermal_drift") => None,
                        e => panic!("{}: unexpected effect {e:?}", found_terms.display()),
                    };
                    Shape {
                        sensor: p["sensor"].as_str().unwrap().to_string(),
                        tau_s,
                    }
                })
                .collect()
        })
        .unwrap_or_default()
}

/// The shapes' gains refitted on `rows` on top of the simulation fitted there (as diagnose with
/// `--fit-offset` writes them: the simulation first, the terms and an offset on its residual), as a
/// machine model TOML (the simulation's with the terms added). Lags are computed over `rows` as
/// one file (started at steady state on the first row), as diagnose sees a fit file.
pub(crate) fn refit_shapes(d: &Data, ch: &str, rows: &[usize], shapes: &[Shape]) -> String {
    let (chosen, coef) = sim_fit(d, ch, rows);
    let (mut toml, _) = sim_model(d, ch, rows);
    let y = pick(d.col(ch), rows);
    let r: Vec<f64> = (0..rows.len())
        .map(|i| {
            let s: f64 = chosen
                .iter()
                .zip(&coef[1..])
                .map(|(t, c)| c * d.col(t)[rows[i]])
                .sum();
            y[i] - coef[0] - s
        })
        .collect();
    let t = pick(d.col("t_s"), rows);
    // krpm^2 is fitted per krpm² (so the Gram matrix stays well scaled) and written per rpm².
    let input = |s: &Shape| -> (Vec<f64>, f64) {
        match s.sensor.as_str() {
            "krpm^2" => (
                pick(d.col("rpm"), rows)
                    .iter()
                    .map(|v| (v / 1e3).powi(2))
                    .collect(),
                1e-6,
            ),
            name => (pick(d.col(name), rows), 1.0),
        }
    };
    let mut cols = vec![vec![1.0; rows.len()]];
    for s in shapes {
        let (u, _) = input(s);
        cols.push(match s.tau_s {
            Some(tau) => retrocomp_model::lag::series(&t, &u, tau, u[0]),
            None => u,
        });
    }
    let refs: Vec<&[f64]> = cols.iter().map(Vec::as_slice).collect();
    let fit = lsq::fit(&refs, &r);
    for (j, s) in shapes.iter().enumerate() {
        let (_, unit) = input(s);
        let column = match s.sensor.as_str() {
            "krpm^2" => "column = \"rpm\"\nexponent = 2\n".to_string(),
            name => format!("column = \"{name}\"\n"),
        };
        let tau = s.tau_s.map_or(String::new(), |t| format!("tau_s = {t}\n"));
        toml.push_str(&format!(
            "[[sensors]]\nname = \"shape{j}\"\nreference_C = 0.0\n{tau}{column}\
             [[thermal]]\nname = \"shape{j}\"\ntarget = \"EZZ\"\nkind = \"polynomial_dt\"\n\
             sensors = [\"shape{j}\"]\ne0_um = {}\nb_um_per_K = [{}]\n",
            if j == 0 { fit.coef[0] } else { 0.0 },
            fit.coef[j + 1] * unit
        ));
    }
    // Where the lags stand at the last fit row (as `diagnose --out` writes it): `eval` continues
    // from there over rows that follow.
    let lagged: Vec<String> = shapes
        .iter()
        .enumerate()
        .filter(|(_, s)| s.tau_s.is_some())
        .map(|(j, s)| {
            let last = *cols[j + 1].last().expect("fit rows");
            format!("shape{j} = {}", last / input(s).1)
        })
        .collect();
    if !lagged.is_empty() {
        toml.push_str(&format!(
            "[lag_state]\nt_s = {}\nlagged = {{ {} }}\n",
            t.last().expect("fit rows"),
            lagged.join(", ")
        ));
    }
    if shapes.is_empty() {
        toml = toml.replacen(
            &format!("e0_um = {}\n", coef[0]),
            &format!("e0_um = {}\n", coef[0] + fit.coef[0]),
            1,
        );
    }
    toml
}

/// The shipped whole-file model's structure for channel `ch` (`deploy/models/fl_thermal/d<k>/
/// found_terms.toml`: sensors and τ kept) with gains and offset refitted on `rows`, written as
/// `dir/shape.toml`; returns its path.
pub(crate) fn shipped_shape(d: &Data, ch: &str, rows: &[usize], dir: &Path) -> PathBuf {
    let shapes = shapes_of(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("deploy/models/fl_thermal")
            .join(ch.trim_end_matches("_um"))
            .join("found_terms.toml"),
    );
    let shape = dir.join("shape.toml");
    std::fs::write(&shape, refit_shapes(d, ch, rows, &shapes)).unwrap();
    shape
}

pub(crate) fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

/// `retrocomp eval` over `path`: the model's ez_um per row.
pub(crate) fn eval(model: &Path, path: &Path) -> Vec<f64> {
    let out = bin()
        .args(["eval", "--model"])
        .arg(model)
        .arg("--path")
        .arg(path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "eval {}: {}",
        model.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let k = head
        .iter()
        .position(|h| *h == "ez_um")
        .expect("ez_um column");
    lines
        .map(|l| l.split(',').nth(k).unwrap().parse().unwrap())
        .collect()
}

pub(crate) fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (s / n as f64).sqrt()
}

/// `dir/sim.toml` (the static simulation of `fit` rows of `ch`) and `dir/fit.csv` (those rows,
/// `ez_um` = the channel).
fn sim_and_fit_file(d: &Data, ch: &str, fit: &[usize], dir: &Path) -> (PathBuf, PathBuf) {
    std::fs::create_dir_all(dir).unwrap();
    let (toml, _) = sim_model(d, ch, fit);
    let sim = dir.join("sim.toml");
    std::fs::write(&sim, toml).unwrap();
    let rec = dir.join("fit.csv");
    d.write(&rec, fit.iter().copied(), Some(ch));
    (sim, rec)
}

/// Fit sim + diagnose on `fit` rows of channel `ch` into `dir`; returns (sim.toml, model.toml,
/// diagnose's text report).
pub(crate) fn fit_channel(
    d: &Data,
    ch: &str,
    fit: &[usize],
    dir: &Path,
) -> (PathBuf, PathBuf, String) {
    let (sim, rec) = sim_and_fit_file(d, ch, fit, dir);
    // --fit-offset: the simulation's intercept was fitted on this same data without the found
    // terms, so the joint refit's constant offset belongs to the model.
    let out = bin()
        .args(["diagnose", "--fit-offset", "--recording"])
        .arg(&rec)
        .arg("--model")
        .arg(&sim)
        .arg("--out")
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "diagnose {ch}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::remove_file(&rec).unwrap();
    (
        sim,
        dir.join("model.toml"),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

/// The compensation fit of `docs/diagnose.md` ("Compensation model") on `fit` rows of channel
/// `ch`, written to `dir`: the static simulation (`sim.toml`) and `retrocomp fit thermal
/// --residual` on it (`compensation.toml`, with its JSON report `compensation.json`).
pub(crate) fn fit_compensation(
    d: &Data,
    ch: &str,
    fit: &[usize],
    dir: &Path,
) -> (PathBuf, PathBuf) {
    let (sim, rec) = sim_and_fit_file(d, ch, fit, dir);
    let comp = dir.join("compensation.toml");
    let out = bin()
        .args(["fit", "thermal"])
        .arg(&rec)
        .args(compensation_args())
        .arg("--base-model")
        .arg(&sim)
        .arg("--out")
        .arg(&comp)
        .arg("--json")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "fit thermal {ch}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::write(dir.join("compensation.json"), &out.stdout).unwrap();
    std::fs::remove_file(&rec).unwrap();
    (sim, comp)
}

/// The settings the compensation fit runs with: [`COMPENSATION_ARGS`], or for the variants tabled
/// in docs/diagnose.md ("The settings were chosen on these six splits") the whitespace-separated
/// arguments of `FL_COMPENSATION_ARGS` (e.g. `FL_COMPENSATION_ARGS='--signal ez_um --residual
/// --refit-all --criterion bic --max-terms 6 --lags-s 0,300,1200,4800 --drivers rpm^2'`). A
/// variant may fail the assertions; its table is printed first.
fn compensation_args() -> Vec<String> {
    match std::env::var("FL_COMPENSATION_ARGS") {
        Ok(v) => v.split_whitespace().map(str::to_string).collect(),
        Err(_) => COMPENSATION_ARGS.iter().map(|a| a.to_string()).collect(),
    }
}

/// The compensation fit's settings (docs/diagnose.md, "Compensation model"; README).
pub(crate) const COMPENSATION_ARGS: [&str; 12] = [
    "--signal",
    "ez_um",
    "--residual",
    "--refit-all",
    "--criterion",
    "average",
    "--max-terms",
    "6",
    "--lags-s",
    "0,300,1200,4800",
    "--drivers",
    "rpm^2",
];
