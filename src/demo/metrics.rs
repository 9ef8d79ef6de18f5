//! Tool-tip error statistics of one demo run, from a hil-sim recording (docs/recording-csv.md columns `t_s`,
//! `ex_um`, `ey_um`, `ez_um`). Sans-IO: takes the CSV text. Error = actual − nominal, µm; "max" is
//! the largest |error|, "volumetric" the largest Euclidean length of (ex, ey, ez) over the run.

use super::error::{Context as _, DemoError};
use serde::{Deserialize, Serialize};

/// RMS and max |error| of one axis, µm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AxisStats {
    pub rms_um: f64,
    pub max_um: f64,
}

/// Statistics of one run (the JSON object of one mode in `retrocomp demo --json`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunStats {
    pub x: AxisStats,
    pub y: AxisStats,
    pub z: AxisStats,
    pub volumetric_max_um: f64,
}

/// The recorded tool-tip error over time (kept for the plots).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorTrace {
    pub t_s: Vec<f64>,
    pub e_um: Vec<[f64; 3]>,
    /// The program's phases found in the recording (`phases`); empty when it has no `z_mm` and
    /// `rpm` columns or no cut.
    pub phases: Vec<Phase>,
}

/// A phase of the demo's program, s from the recording's start.
#[derive(Clone, Debug, PartialEq)]
pub struct Phase {
    pub name: &'static str,
    pub from_s: f64,
    pub to_s: f64,
}

/// The demo program's phases from what the machine did (deploy/demo/sim.toml): **warm-up** from
/// the spindle's start to the cut, **cut** while the tool is below the stock top (z < 0 mm, the
/// spindle on), **cool-down** from the spindle's stop after the cut to the end. No cut: none.
pub(crate) fn phases(t_s: &[f64], z_mm: &[f64], rpm: &[f64]) -> Vec<Phase> {
    let n = t_s.len().min(z_mm.len()).min(rpm.len());
    let cutting = |i: &usize| z_mm[*i] < 0.0 && rpm[*i] > 0.0;
    let (Some(c0), Some(c1)) = ((0..n).find(cutting), (0..n).rev().find(cutting)) else {
        return vec![];
    };
    let phase = |name, a: usize, b: usize| Phase {
        name,
        from_s: t_s[a],
        to_s: t_s[b],
    };
    let mut out = vec![];
    if let Some(w) = (0..c0).find(|i| rpm[*i] > 0.0) {
        out.push(phase("warm-up", w, c0));
    }
    out.push(phase("cut", c0, c1));
    if let Some(c) = (c1..n).find(|i| rpm[*i] <= 0.0) {
        out.push(phase("cool-down", c, n - 1));
    }
    out
}

/// Parse the `t_s` and `e*_um` columns of a recording. `what` names the file in errors.
pub(crate) fn parse_recording(csv_text: &str, what: &str) -> Result<ErrorTrace, DemoError> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_reader(csv_text.as_bytes());
    let headers = rdr
        .headers()
        .with_context(|| format!("{what}: header"))?
        .clone();
    let col = |name: &str| {
        headers
            .iter()
            .position(|h| h == name)
            .with_context(|| format!("{what}: no column `{name}` in the header"))
    };
    let (it, ix, iy, iz) = (col("t_s")?, col("ex_um")?, col("ey_um")?, col("ez_um")?);
    // Only for the phases: a recording without them is still a trace.
    let (iz_mm, irpm) = (col("z_mm").ok(), col("rpm").ok());
    let (mut z_mm, mut rpm) = (vec![], vec![]);
    let mut trace = ErrorTrace::default();
    for (i, rec) in rdr.records().enumerate() {
        // Line 1 is the header.
        let line = i + 2;
        let rec = rec.with_context(|| format!("{what}:{line}"))?;
        let num = |k: usize, name: &str| -> Result<f64, DemoError> {
            let s = rec.get(k).unwrap_or("");
            let v: f64 = s.trim().parse().with_context(|| {
                format!("{what}:{line}: column `{name}`: `{s}` is not a number")
            })?;
            if !v.is_finite() {
                return Err(DemoError::Failed(format!(
                    "{what}:{line}: column `{name}`: {v} is not finite"
                )));
            }
            Ok(v)
        };
        trace.t_s.push(num(it, "t_s")?);
        trace
            .e_um
            .push([num(ix, "ex_um")?, num(iy, "ey_um")?, num(iz, "ez_um")?]);
        if let (Some(a), Some(b)) = (iz_mm, irpm) {
            z_mm.push(num(a, "z_mm")?);
            rpm.push(num(b, "rpm")?);
        }
    }
    trace.phases = phases(&trace.t_s, &z_mm, &rpm);
    if trace.t_s.is_empty() {
        return Err(DemoError::Failed(format!("{what}: no data rows")));
    }
    Ok(trace)
}

/// RMS and max per axis, and the volumetric max, over every sample with `t_s >= from_s`.
pub(crate) fn stats(trace: &ErrorTrace, from_s: f64) -> Result<RunStats, DemoError> {
    let mut sq = [0.0; 3];
    let mut max = [0.0f64; 3];
    let mut vol = 0.0f64;
    let mut n = 0usize;
    for (t, e) in trace.t_s.iter().zip(&trace.e_um) {
        if *t < from_s {
            continue;
        }
        n += 1;
        for k in 0..3 {
            sq[k] += e[k] * e[k];
            max[k] = max[k].max(e[k].abs());
        }
        vol = vol.max((e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt());
    }
    if n == 0 {
        return Err(DemoError::Failed(format!(
            "no samples at or after t = {from_s} s"
        )));
    }
    let axis = |k: usize| AxisStats {
        rms_um: (sq[k] / n as f64).sqrt(),
        max_um: max[k],
    };
    Ok(RunStats {
        x: axis(0),
        y: axis(1),
        z: axis(2),
        volumetric_max_um: vol,
    })
}

/// The four runs, in the order and with the keys of the `--json` line (the first three keys are
/// the outside contract; `fitted` was added after them, same shape).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DemoStats {
    pub uncompensated: RunStats,
    pub geometric: RunStats,
    pub full: RunStats,
    /// With the model fitted from the simulator's own measurement runs.
    pub fitted: RunStats,
    /// How each compensated run's gateway kept up (an addition after the contract's keys).
    #[serde(default)]
    pub gateway: GatewayRuns,
}

/// Did the gateway compensate the whole run? From its [`retrocomp_gateway::run::RunSummary`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GatewayRun {
    /// Time compensation was enabled but not applied on some axis (stale inputs, model fault), s.
    pub not_compensating_s: f64,
    /// Separate episodes of that (each a `compensation.<axis>` fault in the gateway's log).
    pub not_compensating_episodes: u64,
    /// Time compensated without the load terms because the force was stale, s, and episodes
    /// (each a `compensation.<axis>.partial` fault).
    #[serde(default)]
    pub partial_s: f64,
    #[serde(default)]
    pub partial_episodes: u64,
    /// Cycles that started more than one period late, and the worst lateness, ms.
    pub late_cycles: u64,
    pub max_late_ms: f64,
}

/// [`GatewayRun`] of the three compensated runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GatewayRuns {
    pub geometric: GatewayRun,
    pub full: GatewayRun,
    pub fitted: GatewayRun,
}

impl DemoStats {
    /// Fall of the max volumetric error, full (truth) model vs uncompensated, percent.
    pub fn volumetric_reduction_pct(&self) -> f64 {
        Self::fall_pct(&self.full, &self.uncompensated)
    }

    /// Fall of the max volumetric error, fitted model vs uncompensated, percent.
    pub fn fitted_volumetric_reduction_pct(&self) -> f64 {
        Self::fall_pct(&self.fitted, &self.uncompensated)
    }

    fn fall_pct(with: &RunStats, without: &RunStats) -> f64 {
        100.0 * (1.0 - with.volumetric_max_um / without.volumetric_max_um)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_model::error::Chain;

    const CSV: &str =
        "t_s,x_mm,ex_um,ey_um,ez_um\n0.0,0,100,100,100\n1.0,0,3,-4,0\n2.0,0,0,0,-12\n";

    #[test]
    fn rms_max_and_volumetric_from_columns_by_name() {
        let tr = parse_recording(CSV, "r.csv").unwrap();
        let s = stats(&tr, 0.5).unwrap();
        assert_eq!(s.x.max_um, 3.0);
        assert_eq!(s.y.max_um, 4.0);
        assert_eq!(s.z.max_um, 12.0);
        assert!((s.x.rms_um - (9.0f64 / 2.0).sqrt()).abs() < 1e-12);
        assert!((s.z.rms_um - (144.0f64 / 2.0).sqrt()).abs() < 1e-12);
        // max of |(3,−4,0)| = 5 and |(0,0,−12)| = 12.
        assert_eq!(s.volumetric_max_um, 12.0);
        // The first sample counts from t = 0.
        assert_eq!(stats(&tr, 0.0).unwrap().x.max_um, 100.0);
    }

    #[test]
    fn phases_follow_the_spindle_and_the_tool_below_the_stock_top() {
        // Idle, spindle on (warm-up), below z = 0 (cut), retract, spindle off (cool-down).
        let csv = "t_s,z_mm,rpm,ex_um,ey_um,ez_um\n0,5,0,0,0,0\n1,5,4000,0,0,0\n2,5,4000,0,0,0\n\
                   3,-0.5,4000,0,0,0\n4,-0.5,4000,0,0,0\n5,30,4000,0,0,0\n6,30,0,0,0,0\n7,5,0,0,0,0\n";
        let tr = parse_recording(csv, "r.csv").unwrap();
        let got: Vec<(&str, f64, f64)> = tr
            .phases
            .iter()
            .map(|p| (p.name, p.from_s, p.to_s))
            .collect();
        assert_eq!(
            got,
            vec![
                ("warm-up", 1.0, 3.0),
                ("cut", 3.0, 4.0),
                ("cool-down", 6.0, 7.0)
            ]
        );
        // No cut (or no such columns): no phases.
        assert!(phases(&[0.0, 1.0], &[5.0, 5.0], &[4000.0, 0.0]).is_empty());
        assert!(parse_recording(CSV, "r.csv").unwrap().phases.is_empty());
    }

    #[test]
    fn bad_cell_names_file_line_and_column() {
        let bad = "t_s,ex_um,ey_um,ez_um\n0,1,2,3\n0.1,1,oops,3\n";
        let e = Chain(&parse_recording(bad, "r.csv").unwrap_err()).to_string();
        assert!(
            e.contains("r.csv:3") && e.contains("ey_um") && e.contains("oops"),
            "{e}"
        );
        let missing = Chain(&parse_recording("t_s,ex_um\n0,1\n", "r.csv").unwrap_err()).to_string();
        assert!(missing.contains("ey_um"), "{missing}");
        assert!(stats(&parse_recording(CSV, "r").unwrap(), 9.0).is_err());
    }

    #[test]
    fn json_keys_are_the_outside_contract() {
        let d = DemoStats::default();
        let v = serde_json::to_value(d).unwrap();
        for mode in ["uncompensated", "geometric", "full", "fitted"] {
            for ax in ["x", "y", "z"] {
                assert!(v[mode][ax]["rms_um"].is_number() && v[mode][ax]["max_um"].is_number());
            }
            assert!(v[mode]["volumetric_max_um"].is_number());
        }
        // The contract's three keys come first, in order; `fitted` is an addition after them.
        let line = serde_json::to_string(&d).unwrap();
        let at: Vec<usize> = ["uncompensated", "geometric", "full", "fitted"]
            .iter()
            .map(|k| line.find(&format!("\"{k}\":")).unwrap())
            .collect();
        assert!(at.windows(2).all(|w| w[0] < w[1]), "{line}");
        // Then `gateway` (how each compensated run kept up), also an addition, last.
        let gw = line.find("\"gateway\":").unwrap();
        assert!(gw > at[3], "{line}");
        for mode in ["geometric", "full", "fitted"] {
            assert!(
                v["gateway"][mode]["not_compensating_s"].is_number(),
                "{line}"
            );
            assert!(
                v["gateway"][mode]["not_compensating_episodes"].is_u64(),
                "{line}"
            );
        }
        assert_eq!(v.as_object().unwrap().len(), 5);
    }
}
