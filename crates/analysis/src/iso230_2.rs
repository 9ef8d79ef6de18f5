//! ISO 230-2:2014 ("Determination of accuracy and repeatability of positioning of numerically
//! controlled axes") evaluation of one linear axis.
//!
//! Input: deviations x_ij = P_ij − P_i (actual − target, µm) per target i, run j and approach
//! direction (↑ = `+`, ↓ = `-`). Definitions implemented (2014 edition, same formulas as 2006):
//! - x̄i↑ = mean over runs; x̄i = (x̄i↑ + x̄i↓)/2; Bi = x̄i↑ − x̄i↓; B = max|Bi|; B̄ = mean Bi;
//! - si↑ = sample standard deviation (n − 1); Ri↑ = 4 si↑; Ri = max(2si↑ + 2si↓ + |Bi|, Ri↑, Ri↓);
//! - E↑ = max x̄i↑ − min x̄i↑; E = max(x̄i↑, x̄i↓) − min(x̄i↑, x̄i↓); M = max x̄i − min x̄i;
//! - A↑ = max(x̄i↑ + 2si↑) − min(x̄i↑ − 2si↑); A = max(x̄i↑ + 2si↑, x̄i↓ + 2si↓) − min(… − 2s…).
//!
//! Values that need a standard deviation (s, R, A) are `None` when any target has fewer than two
//! runs in the direction concerned (e.g. mean-only F/R data as in Asad Ullah 2013): they are never
//! invented.

use std::collections::BTreeMap;

use serde::Serialize;

use super::table::{BidirectionalTable, Direction};

/// Edition whose definitions this module implements.
pub const EDITION: &str = "ISO 230-2:2014";

/// One laser reading: deviation (actual − target) at a target, in one run and direction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Reading {
    pub target_mm: f64,
    pub run: u32,
    pub direction: Direction,
    pub deviation_um: f64,
}

/// Per-target statistics.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetStats {
    pub target_mm: f64,
    pub n_up: usize,
    pub n_down: usize,
    /// x̄i↑
    pub mean_up_um: f64,
    /// x̄i↓
    pub mean_down_um: f64,
    /// x̄i
    pub mean_um: f64,
    /// Bi = x̄i↑ − x̄i↓
    #[serde(rename = "B_i_um")]
    pub reversal_um: f64,
    pub s_up_um: Option<f64>,
    pub s_down_um: Option<f64>,
    #[serde(rename = "R_i_up_um")]
    pub r_up_um: Option<f64>,
    #[serde(rename = "R_i_down_um")]
    pub r_down_um: Option<f64>,
    #[serde(rename = "R_i_um")]
    pub r_um: Option<f64>,
}

/// Axis values. JSON keys follow the issue contract (`E_um`, `B_mean_um`, …).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisStats {
    #[serde(rename = "E_um")]
    pub e_um: f64,
    #[serde(rename = "E_up_um")]
    pub e_up_um: f64,
    #[serde(rename = "E_down_um")]
    pub e_down_um: f64,
    #[serde(rename = "M_um")]
    pub m_um: f64,
    #[serde(rename = "B_um")]
    pub b_um: f64,
    #[serde(rename = "B_mean_um")]
    pub b_mean_um: f64,
    #[serde(rename = "R_um")]
    pub r_um: Option<f64>,
    #[serde(rename = "R_up_um")]
    pub r_up_um: Option<f64>,
    #[serde(rename = "R_down_um")]
    pub r_down_um: Option<f64>,
    #[serde(rename = "A_um")]
    pub a_um: Option<f64>,
    #[serde(rename = "A_up_um")]
    pub a_up_um: Option<f64>,
    #[serde(rename = "A_down_um")]
    pub a_down_um: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Iso230_2Report {
    pub standard: &'static str,
    pub targets: Vec<TargetStats>,
    pub axis: AxisStats,
    /// Why s/R/A are missing, when they are.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum Iso230_2Error {
    #[error("no readings")]
    Empty,
    #[error(
        "target {target_mm} mm has no reading in direction `{direction}`: both directions are needed at every target"
    )]
    MissingDirection { target_mm: f64, direction: char },
    #[error("reading {index} is not finite")]
    NonFinite { index: usize },
}

/// Two targets closer than this are the same target (laser software prints rounded positions).
const TARGET_TOLERANCE_MM: f64 = 1e-6;

/// Deviations at one target: (target_mm, ↑ values, ↓ values).
type TargetGroup = (f64, Vec<f64>, Vec<f64>);

/// Groups readings by target (sorted ascending) and direction.
fn group(readings: &[Reading]) -> Result<Vec<TargetGroup>, Iso230_2Error> {
    if readings.is_empty() {
        return Err(Iso230_2Error::Empty);
    }
    let mut sorted: Vec<&Reading> = Vec::with_capacity(readings.len());
    for (i, r) in readings.iter().enumerate() {
        if !(r.target_mm.is_finite() && r.deviation_um.is_finite()) {
            return Err(Iso230_2Error::NonFinite { index: i });
        }
        sorted.push(r);
    }
    sorted.sort_by(|a, b| a.target_mm.total_cmp(&b.target_mm).then(a.run.cmp(&b.run)));
    let mut groups: Vec<TargetGroup> = Vec::new();
    for r in sorted {
        let new_group = match groups.last() {
            Some((t, _, _)) => (r.target_mm - *t).abs() > TARGET_TOLERANCE_MM,
            None => true,
        };
        if new_group {
            groups.push((r.target_mm, Vec::new(), Vec::new()));
        }
        let g = groups.last_mut().expect("pushed above");
        match r.direction {
            Direction::Forward => g.1.push(r.deviation_um),
            Direction::Reverse => g.2.push(r.deviation_um),
        }
    }
    for (t, up, down) in &groups {
        if up.is_empty() {
            return Err(Iso230_2Error::MissingDirection {
                target_mm: *t,
                direction: '+',
            });
        }
        if down.is_empty() {
            return Err(Iso230_2Error::MissingDirection {
                target_mm: *t,
                direction: '-',
            });
        }
    }
    Ok(groups)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Sample standard deviation (n − 1); `None` for fewer than two values.
fn sample_sd(v: &[f64]) -> Option<f64> {
    if v.len() < 2 {
        return None;
    }
    let m = mean(v);
    Some((v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt())
}

fn max_of(it: impl Iterator<Item = f64>) -> f64 {
    it.fold(f64::NEG_INFINITY, f64::max)
}
fn min_of(it: impl Iterator<Item = f64>) -> f64 {
    it.fold(f64::INFINITY, f64::min)
}
/// Max over per-target optional values: `None` if any is `None`.
fn max_opt(it: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let mut m = f64::NEG_INFINITY;
    for v in it {
        m = m.max(v?);
    }
    Some(m)
}

/// Evaluates one axis from individual readings.
pub fn evaluate(readings: &[Reading]) -> Result<Iso230_2Report, Iso230_2Error> {
    let groups = group(readings)?;
    let targets: Vec<TargetStats> = groups
        .iter()
        .map(|(t, up, down)| {
            let (mu, md) = (mean(up), mean(down));
            let (su, sd) = (sample_sd(up), sample_sd(down));
            let b = mu - md;
            let (ru, rd) = (su.map(|s| 4.0 * s), sd.map(|s| 4.0 * s));
            let r = match (su, sd) {
                (Some(su), Some(sd)) => {
                    Some((2.0 * su + 2.0 * sd + b.abs()).max(4.0 * su).max(4.0 * sd))
                }
                _ => None,
            };
            TargetStats {
                target_mm: *t,
                n_up: up.len(),
                n_down: down.len(),
                mean_up_um: mu,
                mean_down_um: md,
                mean_um: 0.5 * (mu + md),
                reversal_um: b,
                s_up_um: su,
                s_down_um: sd,
                r_up_um: ru,
                r_down_um: rd,
                r_um: r,
            }
        })
        .collect();
    let axis = axis_stats(&targets);
    let note = if axis.r_um.is_none() {
        Some("s, R and A need at least two runs per direction at every target; they are not defined for this data".to_string())
    } else {
        None
    };
    Ok(Iso230_2Report {
        standard: EDITION,
        targets,
        axis,
        note,
    })
}

fn axis_stats(t: &[TargetStats]) -> AxisStats {
    let up = || t.iter().map(|s| s.mean_up_um);
    let down = || t.iter().map(|s| s.mean_down_um);
    let e_up = max_of(up()) - min_of(up());
    let e_down = max_of(down()) - min_of(down());
    let e = max_of(up().chain(down())) - min_of(up().chain(down()));
    let m = max_of(t.iter().map(|s| s.mean_um)) - min_of(t.iter().map(|s| s.mean_um));
    let b = max_of(t.iter().map(|s| s.reversal_um.abs()));
    let b_mean = t.iter().map(|s| s.reversal_um).sum::<f64>() / t.len() as f64;
    let r_up = max_opt(t.iter().map(|s| s.r_up_um));
    let r_down = max_opt(t.iter().map(|s| s.r_down_um));
    let r = max_opt(t.iter().map(|s| s.r_um));
    // A needs every s; collect the ±2s band edges per direction.
    let band =
        |mean: fn(&TargetStats) -> f64, s: fn(&TargetStats) -> Option<f64>| -> Option<(f64, f64)> {
            let mut hi = f64::NEG_INFINITY;
            let mut lo = f64::INFINITY;
            for ts in t {
                let sv = s(ts)?;
                hi = hi.max(mean(ts) + 2.0 * sv);
                lo = lo.min(mean(ts) - 2.0 * sv);
            }
            Some((hi, lo))
        };
    let bu = band(|s| s.mean_up_um, |s| s.s_up_um);
    let bd = band(|s| s.mean_down_um, |s| s.s_down_um);
    let a_up = bu.map(|(h, l)| h - l);
    let a_down = bd.map(|(h, l)| h - l);
    let a = match (bu, bd) {
        (Some((hu, lu)), Some((hd, ld))) => Some(hu.max(hd) - lu.min(ld)),
        _ => None,
    };
    AxisStats {
        e_um: e,
        e_up_um: e_up,
        e_down_um: e_down,
        m_um: m,
        b_um: b,
        b_mean_um: b_mean,
        r_um: r,
        r_up_um: r_up,
        r_down_um: r_down,
        a_um: a,
        a_up_um: a_up,
        a_down_um: a_down,
    }
}

/// Evaluates mean-only bidirectional data (one value per target and direction, taken as x̄i↑, x̄i↓):
/// E, M and B are defined; s, R and A are `None`.
pub fn evaluate_table(table: &BidirectionalTable) -> Result<Iso230_2Report, Iso230_2Error> {
    evaluate(&table_readings(table))
}

/// The readings of a mean-only table (run 1 in each direction).
pub fn table_readings(table: &BidirectionalTable) -> Vec<Reading> {
    let mut v = Vec::with_capacity(2 * table.len());
    for i in 0..table.len() {
        v.push(Reading {
            target_mm: table.positions_mm[i],
            run: 1,
            direction: Direction::Forward,
            deviation_um: table.forward_um[i],
        });
        v.push(Reading {
            target_mm: table.positions_mm[i],
            run: 1,
            direction: Direction::Reverse,
            deviation_um: table.reverse_um[i],
        });
    }
    v
}

/// The per-target means as a bidirectional table (several runs averaged).
pub fn mean_table(report: &Iso230_2Report) -> BidirectionalTable {
    BidirectionalTable {
        positions_mm: report.targets.iter().map(|t| t.target_mm).collect(),
        forward_um: report.targets.iter().map(|t| t.mean_up_um).collect(),
        reverse_um: report.targets.iter().map(|t| t.mean_down_um).collect(),
    }
}

/// Text form of the report.
pub fn to_text(report: &Iso230_2Report) -> String {
    use std::fmt::Write;
    let f = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), |x| format!("{x:.2}"));
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{} positioning evaluation ({} targets)",
        report.standard,
        report.targets.len()
    );
    let _ = writeln!(
        s,
        "{:>10} {:>4} {:>4} {:>9} {:>9} {:>9} {:>8} {:>7} {:>7} {:>7}",
        "target_mm", "n↑", "n↓", "x̄↑_um", "x̄↓_um", "x̄_um", "B_i_um", "s↑_um", "s↓_um", "R_i_um"
    );
    for t in &report.targets {
        let _ = writeln!(
            s,
            "{:>10.3} {:>4} {:>4} {:>9.2} {:>9.2} {:>9.2} {:>8.2} {:>7} {:>7} {:>7}",
            t.target_mm,
            t.n_up,
            t.n_down,
            t.mean_up_um,
            t.mean_down_um,
            t.mean_um,
            t.reversal_um,
            f(t.s_up_um),
            f(t.s_down_um),
            f(t.r_um)
        );
    }
    let a = &report.axis;
    let _ = writeln!(
        s,
        "E↑ = {:.2} µm   E↓ = {:.2} µm   E = {:.2} µm   M = {:.2} µm",
        a.e_up_um, a.e_down_um, a.e_um, a.m_um
    );
    let _ = writeln!(s, "B = {:.2} µm   B̄ = {:.2} µm", a.b_um, a.b_mean_um);
    let _ = writeln!(
        s,
        "R↑ = {} µm   R↓ = {} µm   R = {} µm",
        f(a.r_up_um),
        f(a.r_down_um),
        f(a.r_um)
    );
    let _ = writeln!(
        s,
        "A↑ = {} µm   A↓ = {} µm   A = {} µm",
        f(a.a_up_um),
        f(a.a_down_um),
        f(a.a_um)
    );
    if let Some(n) = &report.note {
        let _ = writeln!(s, "note: {n}");
    }
    s
}

/// Count of runs per direction found in the readings (for reporting).
pub fn runs_per_direction(readings: &[Reading]) -> BTreeMap<char, usize> {
    let mut m: BTreeMap<char, std::collections::BTreeSet<u32>> = BTreeMap::new();
    for r in readings {
        m.entry(r.direction.symbol()).or_default().insert(r.run);
    }
    m.into_iter().map(|(k, v)| (k, v.len())).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(t: f64, run: u32, d: Direction, x: f64) -> Reading {
        Reading {
            target_mm: t,
            run,
            direction: d,
            deviation_um: x,
        }
    }

    #[test]
    fn hand_computed_two_targets_two_runs() {
        use Direction::*;
        // Target 0: ↑ {1, 3} ↓ {-1, -1}; target 100: ↑ {4, 4} ↓ {2, 0}.
        let rs = [
            r(0.0, 1, Forward, 1.0),
            r(0.0, 2, Forward, 3.0),
            r(0.0, 1, Reverse, -1.0),
            r(0.0, 2, Reverse, -1.0),
            r(100.0, 1, Forward, 4.0),
            r(100.0, 2, Forward, 4.0),
            r(100.0, 1, Reverse, 2.0),
            r(100.0, 2, Reverse, 0.0),
        ];
        let rep = evaluate(&rs).unwrap();
        let t0 = &rep.targets[0];
        assert_eq!(
            (t0.mean_up_um, t0.mean_down_um, t0.reversal_um),
            (2.0, -1.0, 3.0)
        );
        let s2 = 2f64.sqrt();
        assert!((t0.s_up_um.unwrap() - s2).abs() < 1e-12);
        assert_eq!(t0.s_down_um, Some(0.0));
        // R_0 = max(2√2 + 0 + 3, 4√2, 0)
        assert!((t0.r_um.unwrap() - (2.0 * s2 + 3.0)).abs() < 1e-12);
        let a = &rep.axis;
        assert_eq!(a.e_up_um, 2.0); // 4 − 2
        assert_eq!(a.e_down_um, 2.0); // 1 − (−1)
        assert_eq!(a.e_um, 5.0); // 4 − (−1)
        assert_eq!(a.m_um, 2.5 - 0.5);
        assert_eq!(a.b_um, 3.0);
        assert_eq!(a.b_mean_um, 3.0); // B_100 = 4 − 1
        // A↑ = max(2+2√2, 4) − min(2−2√2, 4) = 4√2.
        assert!((a.a_up_um.unwrap() - 4.0 * s2).abs() < 1e-12);
        // ↓ bands: target 0: −1 ± 0, target 100: 1 ± 2√2. A = (2+2√2) − (1−2√2) = 1 + 4√2.
        assert!((a.a_um.unwrap() - (1.0 + 4.0 * s2)).abs() < 1e-12);
    }

    #[test]
    fn missing_direction_is_an_error_naming_the_target() {
        let rs = [r(5.0, 1, Direction::Forward, 1.0)];
        assert_eq!(
            evaluate(&rs),
            Err(Iso230_2Error::MissingDirection {
                target_mm: 5.0,
                direction: '-'
            })
        );
    }
}
