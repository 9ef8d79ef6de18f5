//! Shared by the FL_THERMAL tests (`diagnose_fl_thermal`, `diagnose_fl_judge`): the fixture
//! loader, the static 3-sensor simulation the judge compares against, and thin wrappers over
//! `retrocomp diagnose` / `retrocomp eval`.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use retrocomp::diagnose::lsq;

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
    /// `t_s, rpm, T_*` (+ `ez_um` = channel `ch`) over `rows`.
    pub(crate) fn write(&self, path: &Path, rows: std::ops::Range<usize>, ch: Option<&str>) {
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

/// The simulation: static regression of channel `ch` on its 3 best-correlated temperatures over
/// `rows`, as a machine model TOML (reference 0 °C, e0 = intercept).
pub(crate) fn sim_model(d: &Data, ch: &str, rows: std::ops::Range<usize>) -> (String, Vec<String>) {
    let y = &d.col(ch)[rows.clone()];
    let mut ranked: Vec<(f64, &str)> = d
        .temps()
        .into_iter()
        .map(|t| (corr(&d.col(t)[rows.clone()], y).abs(), t))
        .collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    let chosen: Vec<&str> = ranked.iter().take(3).map(|r| r.1).collect();
    let ones = vec![1.0; y.len()];
    let mut cols: Vec<&[f64]> = vec![&ones];
    cols.extend(chosen.iter().map(|t| &d.col(t)[rows.clone()]));
    let fit = lsq::fit(&cols, y);
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
        fit.coef[0],
        fit.coef[1..]
            .iter()
            .map(f64::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    ));
    (toml, chosen.iter().map(|s| s.to_string()).collect())
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

/// Fit sim + diagnose on `fit` rows of channel `ch` into `dir`; returns (sim.toml, model.toml,
/// diagnose's text report).
pub(crate) fn fit_channel(
    d: &Data,
    ch: &str,
    fit: std::ops::Range<usize>,
    dir: &Path,
) -> (PathBuf, PathBuf, String) {
    std::fs::create_dir_all(dir).unwrap();
    let (toml, _) = sim_model(d, ch, fit.clone());
    let sim = dir.join("sim.toml");
    std::fs::write(&sim, toml).unwrap();
    let rec = dir.join("fit.csv");
    d.write(&rec, fit, Some(ch));
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
