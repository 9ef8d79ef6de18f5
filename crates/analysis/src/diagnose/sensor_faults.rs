//! Sensor faults (issue 36 point 4): a temperature column that is stuck, reads outside the range a
//! sensor can physically report, jumps, or departs from a redundant neighbour is a finding of its
//! own (`sensor_faults` of docs/diagnose-json.md), found BEFORE the physics search; the faulted
//! column is then left out of that search ([`Context::without`]), so a broken sensor is never
//! "explained" as physics.
//!
//! Columns checked: every column whose name ends in `_C` (°C: `T_<name>_C` and unnamed ones such
//! as `coolant_C`). Windows are row ranges `[first, last]` (inclusive) and the same rows' `t_s`.
//! Each check is one pass over the column (O(rows) a column; the neighbour check compares block
//! means, O(columns² · blocks²)), with no per-cycle use.

use serde::{Deserialize, Serialize};

use super::features::Context;

/// Lowest and highest temperature (°C) a machine-tool sensor can plausibly read: anything outside
/// is the sensor or its wiring (a PT100 open circuit reads ≈ 850 °C, a short ≈ −242 °C).
pub const PLAUSIBLE_C: (f64, f64) = (-40.0, 200.0);

/// Fewest rows of one unchanged reading for a stuck sensor.
pub const MIN_STUCK_ROWS: usize = 30;

/// A stuck run must be this many times longer than the column's 99th-percentile run of equal
/// readings (a sensor read in tenths in a steady room repeats itself: hil-sim's quantised ambient
/// holds one reading 13× its 99th-percentile run in the `regime` family; a stuck one far longer).
pub const STUCK_RUN_RATIO: f64 = 30.0;

/// A step: one row-to-row change this many times the column's robust σ of changes …
pub const STEP_SIGMA: f64 = 30.0;
/// … and this many times its 99th-percentile |change| (a heat step's fastest rows stay below).
pub const STEP_P99_RATIO: f64 = 5.0;

/// Blocks of equal row count for the neighbour comparison.
pub const NEIGHBOUR_BLOCKS: usize = 24;
/// Two columns are redundant neighbours (two sensors reading one spot) when the slope of one on
/// the other (Theil–Sen on the changes of their block means) is within [`REDUNDANT_SLOPE`], the
/// neighbour explains the column's changes ([`FOLLOW_SHARE`]) and the robust σ of what
/// `a + b·x` (or, better by half, `a + b·x + a drift from some block on`) leaves is at most this
/// share of the column's range. Merely correlated sensors are not compared: on FL_THERMAL, sensors
/// at different places depart from each other by up to 40 σ through their own dynamics, and a
/// looser bar (2 %) reported them as faults.
pub const REDUNDANT_SIGMA_SHARE: f64 = 0.006;
/// Slope of one redundant sensor on the other (the same quantity, up to an offset).
pub const REDUNDANT_SLOPE: (f64, f64) = (0.8, 1.25);
/// … and the neighbour explains the column's block-to-block changes: the sum of what it leaves
/// (but the two largest) is at most this share of the sum of the changes.
pub const FOLLOW_SHARE: f64 = 0.25;
/// A block disagrees when its residual exceeds this many σ …
pub const DISAGREE_SIGMA: f64 = 20.0;
/// … and this share of the column's range over the blocks.
pub const DISAGREE_RANGE_SHARE: f64 = 0.05;

/// One sensor fault: the column, its kind, the window and the evidence in words.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct SensorFault {
    /// Always `sensor_fault` (an effect of its own, never physics).
    pub effect: String,
    /// `stuck`, `out_of_range`, `step` or `disagreement`.
    pub kind: String,
    pub column: String,
    /// For `disagreement`: the neighbour it departs from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub neighbour: Option<String>,
    /// First and last row of the window (0-based data rows, inclusive).
    pub rows: [usize; 2],
    /// `t_s` of those rows.
    pub t_s: [f64; 2],
    pub evidence: String,
}

fn fault(kind: &str, column: &str, rows: [usize; 2], t: &[f64], evidence: String) -> SensorFault {
    SensorFault {
        effect: "sensor_fault".into(),
        kind: kind.into(),
        column: column.into(),
        neighbour: None,
        rows,
        t_s: [t[rows[0]], t[rows[1]]],
        evidence,
    }
}

/// The `_C` columns of the context (name, values).
fn checked(ctx: &Context) -> Vec<(&str, &[f64])> {
    ctx.temps
        .iter()
        .chain(&ctx.others)
        .filter(|(n, _)| n.ends_with("_C"))
        .map(|(n, v)| (n.as_str(), &**v))
        .collect()
}

/// Every sensor fault of the recording, by column then row.
pub fn scan(ctx: &Context) -> Vec<SensorFault> {
    let cols = checked(ctx);
    let mut out = vec![];
    for (name, v) in &cols {
        let range = out_of_range(name, v, &ctx.t_s);
        let stuck = stuck(name, v, &ctx.t_s);
        let busy: Vec<[usize; 2]> = range.iter().chain(&stuck).map(|f| f.rows).collect();
        out.extend(range);
        out.extend(stuck);
        out.extend(steps(name, v, &ctx.t_s, &busy));
    }
    out.extend(disagreements(&cols, &ctx.t_s, &out));
    out
}

/// Windows of rows outside [`PLAUSIBLE_C`] (at most 5 listed a column; the evidence counts all).
fn out_of_range(name: &str, v: &[f64], t: &[f64]) -> Vec<SensorFault> {
    let (lo, hi) = PLAUSIBLE_C;
    let mut wins: Vec<[usize; 2]> = vec![];
    for (i, x) in v.iter().enumerate() {
        if (lo..=hi).contains(x) {
            continue;
        }
        match wins.last_mut() {
            Some(w) if w[1] + 1 == i => w[1] = i,
            _ => wins.push([i, i]),
        }
    }
    let total = wins.len();
    wins.into_iter()
        .take(5)
        .map(|w| {
            let seen = v[w[0]..=w[1]]
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            let cause = if seen.1 > 800.0 {
                " (≈ 850 °C: a PT100 open circuit)"
            } else if seen.0 < -200.0 {
                " (a short circuit)"
            } else {
                ""
            };
            let more = if total > 5 {
                format!("; {total} such windows in all")
            } else {
                String::new()
            };
            fault(
                "out_of_range",
                name,
                w,
                t,
                format!(
                    "reads {:.1}..{:.1} °C over {} rows, outside the {lo:.0}..{hi:.0} °C a sensor can plausibly read{cause}{more}",
                    seen.0,
                    seen.1,
                    w[1] - w[0] + 1
                ),
            )
        })
        .collect()
}

/// The `q`-quantile of `v` (reorders it).
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = crate::numeric::rank(v.len(), q);
    *v.select_nth_unstable_by(k, f64::total_cmp).1
}

/// Runs of one unchanged reading far longer than the column's usual repeats.
#[allow(
    clippy::float_cmp,
    reason = "a stuck sensor repeats the identical reading: bit-equality is the test"
)]
fn stuck(name: &str, v: &[f64], t: &[f64]) -> Vec<SensorFault> {
    let mut runs: Vec<[usize; 2]> = vec![];
    for i in 0..v.len() {
        match runs.last_mut() {
            Some(r) if v[r[1]] == v[i] => r[1] = i,
            _ => runs.push([i, i]),
        }
    }
    // A column that hardly changes is not "stuck" in a window: it is flat (and offers no term).
    if runs.len() < 10 {
        return vec![];
    }
    let mut lens: Vec<f64> = runs.iter().map(|r| (r[1] - r[0] + 1) as f64).collect();
    let p99 = quantile(&mut lens, 0.99);
    runs.into_iter()
        .filter(|r| {
            let len = r[1] - r[0] + 1;
            len >= MIN_STUCK_ROWS && len as f64 >= STUCK_RUN_RATIO * p99
        })
        .map(|r| {
            fault(
                "stuck",
                name,
                r,
                t,
                format!(
                    "reads {:.3} °C unchanged for {} rows ({:.0} s), {:.0}× its 99th-percentile run of equal readings ({p99:.0} rows)",
                    v[r[0]],
                    r[1] - r[0] + 1,
                    t[r[1]] - t[r[0]],
                    (r[1] - r[0] + 1) as f64 / p99
                ),
            )
        })
        .collect()
}

/// Single-row jumps far beyond the column's row-to-row changes, outside the `busy` windows
/// (out-of-range and stuck windows jump at their edges already).
fn steps(name: &str, v: &[f64], t: &[f64], busy: &[[usize; 2]]) -> Vec<SensorFault> {
    if v.len() < 20 {
        return vec![];
    }
    let d: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
    let mut abs: Vec<f64> = d.iter().map(|x| x.abs()).collect();
    let p99 = quantile(&mut abs, 0.99);
    let med = quantile(&mut abs, 0.5);
    let sigma = (1.4826 * med).max(
        d.iter()
            .map(|x| x.abs())
            .filter(|x| *x > 0.0)
            .fold(f64::INFINITY, f64::min),
    );
    if !sigma.is_finite() {
        return vec![];
    }
    let near = |i: usize| busy.iter().any(|w| i + 1 >= w[0] && i <= w[1] + 1);
    d.iter()
        .enumerate()
        .filter(|&(i, x)| {
            x.abs() > STEP_SIGMA * sigma && x.abs() > STEP_P99_RATIO * p99 && !near(i + 1)
        })
        .take(5)
        .map(|(i, x)| {
            fault(
                "step",
                name,
                [i, i + 1],
                t,
                format!(
                    "jumps by {x:+.2} K from one row to the next: {:.0}× its robust σ of row-to-row changes, {:.0}× their 99th percentile",
                    x.abs() / sigma,
                    x.abs() / p99.max(f64::MIN_POSITIVE)
                ),
            )
        })
        .collect()
}

/// Theil–Sen fit y ≈ a + b·x: (a, b).
#[allow(
    clippy::float_cmp,
    reason = "equal abscissae give no slope (a division by zero); any difference gives one"
)]
fn theil_sen(x: &[f64], y: &[f64]) -> Option<(f64, f64)> {
    let mut slopes = vec![];
    for i in 0..x.len() {
        for j in i + 1..x.len() {
            if x[j] != x[i] {
                slopes.push((y[j] - y[i]) / (x[j] - x[i]));
            }
        }
    }
    if slopes.is_empty() {
        return None;
    }
    let b = quantile(&mut slopes, 0.5);
    let mut a: Vec<f64> = x.iter().zip(y).map(|(x, y)| y - b * x).collect();
    Some((quantile(&mut a, 0.5), b))
}

fn diffs(v: &[f64]) -> Vec<f64> {
    v.windows(2).map(|w| w[1] - w[0]).collect()
}

/// Column `y` against neighbour `x` (block means): the slope `b` of y on x and the rate `c` of any
/// steady drift between them, fitted (Theil–Sen) on the block-to-block CHANGES, so that a drift or
/// a window of wrong readings does not bend the fit; then `e = y − b·x` per block, which is a
/// constant plus noise while the two agree. Returns the robust σ of `e` (from the changes), the
/// range of `y` over the blocks, `e`'s median and the blocks whose `e` departs from it — `None`
/// when the two are not redundant neighbours (σ above [`REDUNDANT_SIGMA_SHARE`] of the range).
fn compare(x: &[f64], y: &[f64]) -> Comparison {
    let (dx, dy) = (diffs(x), diffs(y));
    // The slope of the changes: pairs of blocks on the same side of a drift's start see the
    // same drift rate, which their slope cancels.
    let (_, b) = theil_sen(&dx, &dy)?;
    if !(REDUNDANT_SLOPE.0..=REDUNDANT_SLOPE.1).contains(&b) {
        return None;
    }
    let mut de: Vec<f64> = dx
        .iter()
        .zip(&dy)
        .map(|(dx, dy)| (dy - b * dx).abs())
        .collect();
    // The neighbour explains the column's changes: what it leaves, but for the two largest
    // (the edges of a window of wrong readings), is a small share of them.
    de.sort_by(f64::total_cmp);
    let left: f64 = de[..de.len().saturating_sub(2)].iter().sum();
    let own: f64 = dy.iter().map(|d| d.abs()).sum();
    if left > FOLLOW_SHARE * own {
        return None;
    }
    // y − b·x is a constant while the two agree; a drift of one of them adds a hinge (flat,
    // then a ramp from block k0). Refitted jointly (the changes' slope is bent by the drift's
    // start): σ is the robust spread of what the better form leaves.
    let (k0, rate, b, sigma) = hinge(x, y, b);

    let e: Vec<f64> = x.iter().zip(y).map(|(x, y)| y - b * x).collect();
    let mid = quantile(&mut e.clone(), 0.5);
    let mid = if rate == 0.0 {
        mid
    } else {
        // The constant of the hinge form: e's median over the blocks before the ramp.
        quantile(&mut e[..k0.max(1)].to_vec(), 0.5)
    };
    let (lo, hi) = y
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    let range = hi - lo;
    if range <= 0.0 || sigma > REDUNDANT_SIGMA_SHARE * range {
        return None;
    }
    let bar = (DISAGREE_SIGMA * sigma).max(DISAGREE_RANGE_SHARE * range);
    let drift = |k: usize| rate * k.saturating_sub(k0) as f64;
    let bad = (0..e.len())
        .filter(|&k| (e[k] - mid - drift(k)).abs() > bar || drift(k).abs() > bar)
        .collect();
    Some((sigma, range, mid, bad))
}

/// The better of `y ≈ a + b·x` (b the changes' slope `b0`, rate 0, k0 = len) and `y ≈ a + b·x +
/// rate·max(0, k − k0)` (least squares, every k0) by the robust spread (1.4826 × median
/// |residual|) of what each leaves: (k0, rate per block, b, σ).
fn hinge(x: &[f64], y: &[f64], b0: f64) -> (usize, f64, f64, f64) {
    let n = y.len();
    let spread = |res: Vec<f64>| {
        let mut a: Vec<f64> = res.iter().map(|r| r.abs()).collect();
        1.4826 * quantile(&mut a, 0.5)
    };
    let e0: Vec<f64> = x.iter().zip(y).map(|(x, y)| y - b0 * x).collect();
    let m0 = quantile(&mut e0.clone(), 0.5);
    let mut best = (n, 0.0, b0, spread(e0.iter().map(|v| v - m0).collect()));
    for k0 in 1..n.saturating_sub(3) {
        let h: Vec<f64> = (0..n).map(|k| k.saturating_sub(k0) as f64).collect();
        let Some(c) = lsq3(x, &h, y) else {
            continue;
        };
        let res: Vec<f64> = (0..n)
            .map(|k| y[k] - c[0] - c[1] * x[k] - c[2] * h[k])
            .collect();
        let s = spread(res);
        if s < 0.5 * best.3 {
            best = (k0, c[2], c[1], s);
        }
    }
    best
}

/// Least squares of `y` on [1, u, v]: the coefficients, `None` when not finite.
fn lsq3(u: &[f64], v: &[f64], y: &[f64]) -> Option<[f64; 3]> {
    let one = vec![1.0; y.len()];
    let c = super::lsq::coef(&[&one, u, v], y);
    c.iter().all(|v| v.is_finite()).then(|| [c[0], c[1], c[2]])
}

/// Columns that depart from a redundant neighbour over ≥ 2 blocks. Of a disagreeing pair the
/// faulty one is the one that no other redundant neighbour backs (the other agrees with a third
/// column); when neither can be told, both are listed as each other's neighbour. Columns already
/// faulted (out of range, stuck) are not compared.
fn disagreements(cols: &[(&str, &[f64])], t: &[f64], known: &[SensorFault]) -> Vec<SensorFault> {
    let n = t.len();
    if n < 4 * NEIGHBOUR_BLOCKS {
        return vec![];
    }
    let cols: Vec<&(&str, &[f64])> = cols
        .iter()
        .filter(|(c, _)| !known.iter().any(|f| f.column == *c))
        .collect();
    let means: Vec<Vec<f64>> = cols
        .iter()
        .map(|(_, v)| {
            (0..NEIGHBOUR_BLOCKS)
                .map(|k| {
                    let b = &v[k * n / NEIGHBOUR_BLOCKS..(k + 1) * n / NEIGHBOUR_BLOCKS];
                    b.iter().sum::<f64>() / b.len() as f64
                })
                .collect()
        })
        .collect();
    // cmp[i][j]: column i fitted on column j.
    let m = cols.len();
    let mut cmp: Vec<Vec<Comparison>> = vec![vec![None; m]; m];
    for i in 0..m {
        for j in 0..m {
            if i != j {
                cmp[i][j] = compare(&means[j], &means[i]);
            }
        }
    }
    let agrees = |i: usize, j: usize| {
        cmp[i][j].as_ref().is_some_and(|c| c.3.is_empty())
            && cmp[j][i].as_ref().is_some_and(|c| c.3.is_empty())
    };
    let mut out = vec![];
    let flagged = |i: usize, j: usize| cmp[i][j].as_ref().filter(|c| c.3.len() >= 2);
    for i in 0..m {
        for j in i + 1..m {
            if flagged(i, j).is_none() && flagged(j, i).is_none() {
                continue;
            }
            let backed = |k: usize| (0..m).any(|o| o != i && o != j && agrees(k, o));
            // The one a third column does not back is named; with no third column to tell,
            // both are, each with the other as its neighbour.
            let named: &[(usize, usize)] = match (backed(i), backed(j)) {
                (false, true) => &[(i, j)],
                (true, false) => &[(j, i)],
                _ => &[(i, j), (j, i)],
            };
            for &(k, o) in named {
                let told = backed(o) && !backed(k);
                out.push(disagreement(&cols, &means, (k, o), &cmp, t, told));
            }
        }
    }
    out
}

type Comparison = Option<(f64, f64, f64, Vec<usize>)>;

/// The fault of column `k` departing from neighbour `o` (its comparison, else the neighbour's
/// against it); `told`: a third column backs the neighbour.
fn disagreement(
    cols: &[&(&str, &[f64])],
    means: &[Vec<f64>],
    (k, o): (usize, usize),
    cmp: &[Vec<Comparison>],
    t: &[f64],
    told: bool,
) -> SensorFault {
    let n = t.len();
    let (y, x, c) = match &cmp[k][o] {
        Some(c) if c.3.len() >= 2 => (k, o, c),
        _ => (o, k, cmp[o][k].as_ref().expect("flagged")),
    };
    let (sigma, range, mid, bad) = c;
    let (first, last) = (bad[0], bad[bad.len() - 1]);
    let rows = [
        first * n / NEIGHBOUR_BLOCKS,
        ((last + 1) * n / NEIGHBOUR_BLOCKS).min(n) - 1,
    ];
    let b = theil_sen(&diffs(&means[x]), &diffs(&means[y]))
        .expect("fitted")
        .1;
    let worst = bad
        .iter()
        .map(|&q| means[y][q] - b * means[x][q] - mid)
        .fold(0.0_f64, |w, e| if e.abs() > w.abs() { e } else { w });
    let which = if told {
        format!("{} agrees with a third column", cols[o].0)
    } else {
        "no third column tells which of the two is wrong".to_string()
    };
    let mut f = fault(
        "disagreement",
        cols[k].0,
        rows,
        t,
        format!(
            "{} departs from {} by up to {worst:+.2} K in {} of {NEIGHBOUR_BLOCKS} blocks (σ {sigma:.3} K elsewhere, range {range:.2} K); {which}",
            cols[y].0,
            cols[x].0,
            bad.len()
        ),
    );
    f.neighbour = Some(cols[o].0.to_string());
    f
}

impl Context {
    /// The context without the named columns (faulted sensors): the physics search never reads
    /// them.
    pub fn without(mut self, columns: &[&str]) -> Self {
        self.temps.retain(|(n, _)| !columns.contains(&n.as_str()));
        self.others.retain(|(n, _)| !columns.contains(&n.as_str()));
        self
    }
}
