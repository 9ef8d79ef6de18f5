//! The measurement campaign of `retrocomp demo`'s fitted pass: what a compensation engineer would
//! run on the machine before installing the box, run here on hil-sim (`hil-sim run`, offline, as
//! fast as the host allows) with the SAME hidden physics as the demo (the sim template of
//! [`super::sim_process`], only the program, the recording interval and the clock differ; no buses).
//!
//! - **Geometry**, one run per axis K (a laser + straightness set-up along K), cold, spindle off:
//!   bidirectional stepped runs (ISO 230-2 style: approach every target from below after a 2 mm
//!   overshoot, then from above), a long dwell at each target so that the heat of the slow move
//!   has decayed (the demo's X screw has τ = 5 s); the other axes sit at the reference point
//!   [`REFERENCE_MM`]. A reading is the mean of the last [`READ_WINDOW_S`] of a dwell (laser
//!   averaging) of all three errors ex, ey, ez → the components EXK, EYK, EZK.
//! - **Context**, one run: cold start, spindle warm-up with X/Y/Z strokes, cutting passes at several
//!   depths and feeds, a cool-down with moves, a second warm-up at another speed. Recorded with
//!   temperatures and the cutting force → thermal and load terms (see [`super::fitted`]).
//!
//! Error = actual − nominal, µm (ISO 230-2); positions mm; forward = approach in +.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use super::error::{Context as _, DemoError};

use retrocomp_analysis::table::Direction;
use retrocomp_model::Axis;

/// Where the axes sit while another axis is measured; every axis' targets include its coordinate,
/// so the Y and Z tables can be zeroed there (see [`super::fitted`]).
pub(crate) const REFERENCE_MM: [f64; 3] = [0.0, 0.0, 0.0];
/// Averaging window at the end of each dwell, s.
pub(crate) const READ_WINDOW_S: f64 = 1.0;
/// Overshoot before each direction's first target, mm (ISO 230-2 approach).
const OVERSHOOT_MM: f64 = 2.0;
/// A hil-sim measurement run is offline and takes well under this; a hung child fails the demo.
const RUN_TIMEOUT: Duration = Duration::from_secs(300);

/// One axis' stepped bidirectional runs.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct AxisPlan {
    pub axis: Axis,
    pub targets_mm: Vec<f64>,
    pub runs: u32,
    pub dwell_s: f64,
    pub feed_mm_min: f64,
}

/// One expected reading of a plan, in program order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Expected {
    pub run: u32,
    pub target_mm: f64,
    pub direction: Direction,
}

fn targets(from: f64, to: f64, step: f64) -> Vec<f64> {
    let n = retrocomp_analysis::numeric::round_usize((to - from) / step);
    (0..=n).map(|i| from + step * i as f64).collect()
}

/// The demo mill's campaign: targets span the part program's range on every axis (X 0–150,
/// Y 0–100, Z −0.5–50) inside the travels; 4 runs each (3 fitted, the 4th held out for δ).
pub(crate) fn demo_plans() -> [AxisPlan; 3] {
    let plan = |axis, targets_mm| AxisPlan {
        axis,
        targets_mm,
        runs: 4,
        dwell_s: 8.0,
        feed_mm_min: 600.0,
    };
    [
        plan(Axis::X, targets(0.0, 200.0, 20.0)),
        plan(Axis::Y, targets(0.0, 150.0, 15.0)),
        plan(Axis::Z, targets(-5.0, 55.0, 5.0)),
    ]
}

fn axis_word(axis: Axis) -> char {
    axis.upper()
}

impl AxisPlan {
    /// The measurement program (machine coordinates, absolute, mm, G4 P in seconds).
    pub(crate) fn gcode(&self) -> String {
        let k = axis_word(self.axis);
        let (first, last) = (
            self.targets_mm[0],
            self.targets_mm[self.targets_mm.len() - 1],
        );
        let mut g = format!("G90 G21\nG1 F{}\n", self.feed_mm_min);
        for _ in 0..self.runs {
            let _ = writeln!(g, "G1 {k}{}", first - OVERSHOOT_MM);
            for t in &self.targets_mm {
                let _ = writeln!(g, "G1 {k}{t}\nG4 P{}", self.dwell_s);
            }
            let _ = writeln!(g, "G1 {k}{}", last + OVERSHOOT_MM);
            for t in self.targets_mm.iter().rev() {
                let _ = writeln!(g, "G1 {k}{t}\nG4 P{}", self.dwell_s);
            }
        }
        g.push_str("M30\n");
        g
    }

    /// The readings the program produces, in order (runs numbered from 1).
    pub(crate) fn expected(&self) -> Vec<Expected> {
        let mut v = Vec::new();
        for run in 1..=self.runs {
            for &target_mm in &self.targets_mm {
                v.push(Expected {
                    run,
                    target_mm,
                    direction: Direction::Forward,
                });
            }
            for &target_mm in self.targets_mm.iter().rev() {
                v.push(Expected {
                    run,
                    target_mm,
                    direction: Direction::Reverse,
                });
            }
        }
        v
    }
}

/// The context program: warm-up, cuts, cool-down, second warm-up. The stock top is z = 0 (the
/// demo's `[hidden.cutting]`); the force is kc · depth · feed per tooth, so depths and feeds vary.
pub(crate) fn context_gcode() -> String {
    let mut g = String::from("G90 G21\nG4 P3                (cold)\nS4000 M3\nG1 F3600\n");
    for _ in 0..3 {
        g.push_str("G1 X150\nG1 Y100 Z40\nG1 X0\nG1 Y0 Z0\n");
    }
    for _ in 0..3 {
        g.push_str("G1 X150\nG1 X0\n");
    }
    // Cutting passes along X and Y at three depths and feeds.
    for (depth, feed) in [(0.5, 900.0), (1.0, 1200.0), (0.3, 1800.0)] {
        let _ = writeln!(
            g,
            "G0 X10 Y20 Z2\nG1 F300 Z-{depth}\nG1 F{feed} X140\nG1 Y80\nG1 X10\nG1 Y20\nG0 Z5"
        );
    }
    g.push_str("M5\nG1 F1800\n");
    for _ in 0..4 {
        g.push_str("G1 X150 Y100 Z50\nG1 X0 Y0 Z0\nG4 P4\n");
    }
    g.push_str("S2500 M3\nG1 F2400\n");
    for _ in 0..4 {
        g.push_str("G1 X150 Y50\nG1 X0 Z30\nG1 Y100\nG1 Y0 Z0\n");
    }
    g.push_str("G0 X20 Y20 Z2\nG1 F300 Z-0.8\nG1 F1500 X130\nG1 Y70\nG1 X20\nG0 Z5\nM5\n");
    g.push_str("G1 F1200 X100 Y60 Z20\nG1 X0 Y0 Z0\nG4 P8\nM30\n");
    g
}

/// The demo's hidden machine (the filled sim template) with another program: offline clock, no
/// buses, `every_s` recording interval.
pub(crate) fn measurement_config(
    sim_toml: &str,
    gcode: &str,
    every_s: f64,
    what: &str,
) -> Result<String, DemoError> {
    let mut t: toml::Table =
        toml::from_str(sim_toml).context("the demo's sim template does not parse")?;
    t.remove("io");
    let clock = t
        .entry("clock")
        .or_insert_with(|| toml::Value::Table(Default::default()));
    let clock = clock.as_table_mut().context("[clock] is not a table")?;
    clock.insert("realtime".into(), false.into());
    clock.insert("max_duration_s".into(), 5000.0.into());
    let program = t
        .get_mut("program")
        .and_then(toml::Value::as_table_mut)
        .context("the sim template has no [program]")?;
    program.insert("gcode".into(), gcode.into());
    program.insert(
        "start_mm".into(),
        toml::Value::Array(REFERENCE_MM.iter().map(|v| (*v).into()).collect()),
    );
    let mut record = toml::Table::new();
    record.insert("every_s".into(), every_s.into());
    t.insert("record".into(), toml::Value::Table(record));
    Ok(format!(
        "# retrocomp demo measurement run `{what}`: the demo's machine, another program.\n{}",
        toml::to_string(&t)?
    ))
}

/// Runs `hil-sim run --config CONFIG --out DIR` and returns DIR/recording.csv.
pub(crate) async fn run_measurement(
    hil_sim: &Path,
    config: &Path,
    out: &Path,
) -> Result<PathBuf, DemoError> {
    let child = tokio::process::Command::new(hil_sim)
        .arg("run")
        .arg("--config")
        .arg(config)
        .arg("--out")
        .arg(out)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .with_context(|| format!("starting {}", hil_sim.display()))?;
    let done = tokio::time::timeout(RUN_TIMEOUT, child.wait_with_output())
        .await
        .with_context(|| {
            format!(
                "hil-sim run {} did not finish within {} s",
                config.display(),
                RUN_TIMEOUT.as_secs()
            )
        })??;
    if !done.status.success() {
        return Err(DemoError::Failed(format!(
            "hil-sim run --config {} failed ({}):\n{}",
            config.display(),
            done.status,
            String::from_utf8_lossy(&done.stderr)
        )));
    }
    Ok(out.join("recording.csv"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_include_the_reference_and_stay_inside_the_travel() {
        // Travels of deploy/demo/mill-base.toml; the overshoot must stay inside too.
        let travel = [(-5.0, 205.0), (-5.0, 155.0), (-10.0, 60.0)];
        for (p, (lo, hi)) in demo_plans().iter().zip(travel) {
            let i = p.axis.index();
            assert!(p.targets_mm.contains(&REFERENCE_MM[i]), "{:?}", p.axis);
            assert!(p.targets_mm[0] - OVERSHOOT_MM >= lo);
            assert!(p.targets_mm.last().unwrap() + OVERSHOOT_MM <= hi);
        }
    }

    #[test]
    fn program_and_expected_readings_agree() {
        let p = AxisPlan {
            axis: Axis::Y,
            targets_mm: vec![0.0, 10.0, 20.0],
            runs: 2,
            dwell_s: 3.0,
            feed_mm_min: 600.0,
        };
        let g = p.gcode();
        assert_eq!(g.matches("G4 P3").count(), 12, "{g}");
        assert!(
            g.contains("G1 Y-2\nG1 Y0\n") && g.contains("G1 Y22\nG1 Y20\n"),
            "{g}"
        );
        let e = p.expected();
        assert_eq!(e.len(), 12);
        assert_eq!((e[2].target_mm, e[2].direction), (20.0, Direction::Forward));
        assert_eq!((e[3].target_mm, e[3].direction), (20.0, Direction::Reverse));
        assert_eq!((e[6].run, e[6].target_mm), (2, 0.0));
    }

    #[test]
    fn measurement_config_keeps_the_physics_and_drops_the_buses() {
        let sim = super::super::sim_process::sim_config(
            7,
            Path::new("/m/truth.toml"),
            1234,
            10.0,
            Path::new("/o/pty"),
        );
        let text = measurement_config(&sim, "G1 X1\nM30\n", 0.1, "t").unwrap();
        let t: toml::Table = toml::from_str(&text).unwrap();
        assert!(t.get("io").is_none());
        assert_eq!(t["clock"]["realtime"].as_bool(), Some(false));
        assert_eq!(t["program"]["gcode"].as_str(), Some("G1 X1\nM30\n"));
        assert_eq!(t["record"]["every_s"].as_float(), Some(0.1));
        assert_eq!(t["seed"].as_integer(), Some(7));
        // The hidden machine is the demo's, unchanged.
        let orig: toml::Table = toml::from_str(&sim).unwrap();
        for key in ["truth", "hidden", "servo", "plc"] {
            assert_eq!(t[key], orig[key], "[{key}]");
        }
    }
}
