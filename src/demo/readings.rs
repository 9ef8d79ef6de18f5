//! Laser-style readings from a geometry measurement run's recording (sans-IO: takes the parsed
//! [`Recording`]). A reading is the mean error over the last [`READ_WINDOW_S`] of a dwell, i.e. of a
//! still period (all three nominal positions unchanged) lasting at least 80 % of the programmed
//! dwell; the still periods are matched in order against the plan's expected readings, and each
//! must sit on its target with the other axes at the reference point, else the run is rejected
//! (it would mislabel readings). Error = actual − nominal, µm; `deviation_um` as in ISO 230-2.

use std::fmt::Write as _;

use super::error::{Context as _, DemoError};

use super::campaign::{AxisPlan, READ_WINDOW_S, REFERENCE_MM};
use retrocomp_analysis::iso230_2::Reading;
use retrocomp_analysis::table::Direction;
use retrocomp_model::recording::Recording;

const POS: [&str; 3] = ["x_mm", "y_mm", "z_mm"];
pub(crate) const ERR: [&str; 3] = ["ex_um", "ey_um", "ez_um"];
/// Nominal positions closer than this are "on target", mm.
const ON_TARGET_MM: f64 = 1e-3;

fn col<'a>(rec: &'a Recording, name: &str, what: &str) -> Result<&'a [f64], DemoError> {
    rec.col(name)
        .with_context(|| format!("{what}: no column `{name}`"))
}

/// The readings of `plan` in `rec`, per error signal (index 0 = ex_um, 1 = ey_um, 2 = ez_um).
pub(crate) fn readings(
    plan: &AxisPlan,
    rec: &Recording,
    what: &str,
) -> Result<[Vec<Reading>; 3], DemoError> {
    let t = rec.t_s();
    let pos: Vec<&[f64]> = POS
        .iter()
        .map(|n| col(rec, n, what))
        .collect::<Result<_, DemoError>>()?;
    let err: Vec<&[f64]> = ERR
        .iter()
        .map(|n| col(rec, n, what))
        .collect::<Result<_, DemoError>>()?;
    #[allow(
        clippy::float_cmp,
        reason = "still means the recorded position repeats exactly (the simulation writes the same value)"
    )]
    let same = |i: usize, j: usize| pos.iter().all(|p| p[i] == p[j]);
    // Still periods [start, end] (row indices, inclusive).
    let mut stills: Vec<(usize, usize)> = Vec::new();
    let mut start = 0;
    for i in 1..=t.len() {
        if i == t.len() || !same(i, start) {
            if t[i - 1] - t[start] >= 0.8 * plan.dwell_s {
                stills.push((start, i - 1));
            }
            start = i;
        }
    }
    let expected = plan.expected();
    if stills.len() != expected.len() {
        return Err(DemoError::Failed(format!(
            "{what}: found {} dwells of ≥ {:.1} s, the {} program has {} readings",
            stills.len(),
            0.8 * plan.dwell_s,
            plan.axis.upper(),
            expected.len()
        )));
    }
    let k = plan.axis.index();
    let mut out: [Vec<Reading>; 3] = Default::default();
    for (&(a, b), e) in stills.iter().zip(&expected) {
        for (i, p) in pos.iter().enumerate() {
            let want = if i == k { e.target_mm } else { REFERENCE_MM[i] };
            if (p[b] - want).abs() > ON_TARGET_MM {
                return Err(DemoError::Failed(format!(
                    "{what}:{}: dwell at {} = {} mm, expected {want} mm (run {}, {:?})",
                    rec.line_of_row(b),
                    POS[i],
                    p[b],
                    e.run,
                    e.direction
                )));
            }
        }
        let rows = (a..=b).filter(|&i| t[i] >= t[b] - READ_WINDOW_S);
        let n = rows.clone().count() as f64;
        for (j, o) in out.iter_mut().enumerate() {
            o.push(Reading {
                target_mm: e.target_mm,
                run: e.run,
                direction: e.direction,
                deviation_um: rows.clone().map(|i| err[j][i]).sum::<f64>() / n,
            });
        }
    }
    Ok(out)
}

/// Readings as the long ISO 230-2 CSV of `retrocomp iso230-2` / `retrocomp fit axis`.
pub(crate) fn readings_csv(readings: &[Reading], comment: &str) -> String {
    let mut s = format!("# {comment}\ntarget_mm,run,direction,deviation_um\n");
    for r in readings {
        let d = if r.direction == Direction::Forward {
            '+'
        } else {
            '-'
        };
        let _ = writeln!(s, "{},{},{d},{:.4}", r.target_mm, r.run, r.deviation_um);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_model::Axis;
    use retrocomp_model::error::Chain;

    fn plan() -> AxisPlan {
        AxisPlan {
            axis: Axis::X,
            targets_mm: vec![0.0, 10.0],
            runs: 1,
            dwell_s: 2.0,
            feed_mm_min: 600.0,
        }
    }

    /// A synthetic recording of `plan()`: moves of 1 s, dwells of 2 s, ex = 1 µm/mm × x + 5 on
    /// reverse approaches, the first dwell sample an outlier that the 1 s window must not see.
    fn rec(x_at: &[f64]) -> Recording {
        let mut cols: [Vec<f64>; 8] = Default::default();
        let mut t = 0.0;
        let mut push = |x: f64, rev: bool, n: usize, outlier: bool| {
            for i in 0..n {
                let ex =
                    x + if rev { 5.0 } else { 0.0 } + if outlier && i == 0 { 99.0 } else { 0.0 };
                for (c, v) in cols.iter_mut().zip([t, x, 0.0, 0.0, ex, 0.5, -0.5, 20.0]) {
                    c.push(v);
                }
                t += 0.1;
            }
        };
        push(-2.0, false, 10, false);
        push(x_at[0], false, 21, true);
        push(x_at[1], false, 21, true);
        push(12.0, false, 10, false);
        push(x_at[2], true, 21, true);
        push(x_at[3], true, 21, true);
        let names = [
            "t_s", "x_mm", "y_mm", "z_mm", "ex_um", "ey_um", "ez_um", "T_a_C",
        ];
        Recording::from_columns(names.iter().map(|n| n.to_string()).zip(cols).collect()).unwrap()
    }

    #[test]
    fn one_reading_per_dwell_averaged_over_the_window() {
        let r = readings(&plan(), &rec(&[0.0, 10.0, 10.0, 0.0]), "g.csv").unwrap();
        let ex: Vec<(f64, Direction, f64)> = r[0]
            .iter()
            .map(|r| (r.target_mm, r.direction, r.deviation_um))
            .collect();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert_eq!(ex.len(), 4);
        for ((t, d, v), (wt, wd, wv)) in ex.iter().zip([
            (0.0, Direction::Forward, 0.0),
            (10.0, Direction::Forward, 10.0),
            (10.0, Direction::Reverse, 15.0),
            (0.0, Direction::Reverse, 5.0),
        ]) {
            assert!(*t == wt && *d == wd && close(*v, wv), "{ex:?}");
        }
        assert!(r[1].iter().all(|r| close(r.deviation_um, 0.5)));
        let csv = readings_csv(&r[0], "EXX");
        assert!(csv.contains("\n10,1,-,15.0000\n"), "{csv}");
    }

    #[test]
    fn a_dwell_off_target_or_a_missing_dwell_is_an_error() {
        let e = readings(&plan(), &rec(&[0.0, 10.0, 9.0, 0.0]), "g.csv").unwrap_err();
        let msg = Chain(&e).to_string();
        assert!(
            msg.contains("g.csv:") && msg.contains("expected 10 mm"),
            "{msg}"
        );
        let mut p = plan();
        p.runs = 2;
        let e = readings(&p, &rec(&[0.0, 10.0, 10.0, 0.0]), "g.csv").unwrap_err();
        let msg = Chain(&e).to_string();
        assert!(
            msg.contains("found 4 dwells") && msg.contains("8 readings"),
            "{msg}"
        );
    }
}
