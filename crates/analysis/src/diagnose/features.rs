//! Context features computed from a recording, per sample: axis position (mm), velocity (mm/s),
//! latched direction of travel (+1 / −1, the last approach direction; 0 before the axis first moves),
//! distance travelled since the last reversal (mm), temperatures and their first-order low-pass over
//! any τ (°C), force/strain channels, spindle speed, tool length (mm), time (s) and `run` blocks.
//!
//! Motion features come from the commanded positions (`<a>_mm`, docs/recording-csv.md): direction is latched by
//! the definition shared with the gateway ([`retrocomp_model::approach`], deadband
//! [`DIRECTION_DEADBAND_MM`]), so dwells keep the direction of their approach, as in ISO 230-2
//! step-and-dwell runs; velocity is zero at every standstill row (see `velocity`).

use std::sync::Arc;

use retrocomp_model::approach::ApproachLatch;
use retrocomp_model::recording::{AXES, Recording};

/// Travel back from the extreme (mm) below which the direction latch does not change; also the
/// position change below which two rows are at the same place (standstill).
pub const DIRECTION_DEADBAND_MM: f64 = retrocomp_model::approach::RECORDED_DEADBAND_MM;

/// Velocity and distance since reversal are not held: each is a function of the positions (and
/// times) that only one candidate reads, recomputed on demand by [`AxisFeatures::vel_mm_s`] and
/// [`AxisFeatures::dist_since_rev_mm`] with the same arithmetic (16 MB an axis on a 1M-row
/// recording, issue 12 item 10).
#[derive(Clone, Debug)]
pub struct AxisFeatures {
    /// Shared with the recording (no copy), as every recorded column of [`Context`].
    pub pos_mm: Arc<[f64]>,
    /// The recording's `t_s` (shared), for the velocity.
    t_s: Arc<[f64]>,
    /// Latched direction of the last approach: +1, −1, 0 before the first move (`i8`: exact, an
    /// eighth of an f64 column).
    pub dir: Vec<i8>,
    /// Rows where the latch restarts (each `run` and inferred pass), with 0 and n: the passes are
    /// `bounds[k]..bounds[k + 1]`.
    bounds: Vec<usize>,
    /// Distinct positions (sorted) and each sample's index into them: functions of position alone
    /// (sin/cos of a cyclic candidate) are computed once per distinct position, a large saving on
    /// step-and-dwell recordings.
    pub distinct_mm: Vec<f64>,
    pub distinct_idx: Vec<u32>,
}

impl AxisFeatures {
    /// Velocity of the commanded motion (mm/s), zero at standstill rows (see `velocity`).
    pub fn vel_mm_s(&self) -> Vec<f64> {
        let mut vel = Vec::with_capacity(self.pos_mm.len());
        for w in self.bounds.windows(2) {
            vel.extend(velocity(&self.t_s[w[0]..w[1]], &self.pos_mm[w[0]..w[1]]));
        }
        vel
    }

    /// Distance travelled since the direction last flipped (mm); large before the first reversal.
    pub fn dist_since_rev_mm(&self) -> Vec<f64> {
        let mut dist = Vec::with_capacity(self.pos_mm.len());
        for w in self.bounds.windows(2) {
            latch(&self.pos_mm[w[0]..w[1]], |_, since| dist.push(since));
        }
        dist
    }

    /// The latched direction of row `i` as a number (±1, 0).
    pub fn dir_f64(&self, i: usize) -> f64 {
        f64::from(self.dir[i])
    }

    /// `f(pos)` for every sample, evaluating `f` once per distinct position.
    pub fn map_pos(&self, f: impl Fn(f64) -> f64) -> Vec<f64> {
        let vals: Vec<f64> = self.distinct_mm.iter().map(|&x| f(x)).collect();
        self.distinct_idx
            .iter()
            .map(|&k| vals[k as usize])
            .collect()
    }
}

/// Recorded columns are shared with the [`Recording`] (`Arc`, no copy: on a 1M-row recording each
/// copy was 8 MB, issue 12 item 10); derived features (velocity, direction…) are owned.
#[derive(Clone, Debug)]
pub struct Context {
    pub t_s: Arc<[f64]>,
    pub axes: [Option<AxisFeatures>; 3],
    /// `T_<name>_C` channels.
    pub temps: Vec<(String, Arc<[f64]>)>,
    /// `F_<name>_N` and `strain_<name>_ue` channels.
    pub loads: Vec<(String, Arc<[f64]>)>,
    pub rpm: Option<Arc<[f64]>>,
    pub tool_mm: Option<Arc<[f64]>>,
    /// Block id per sample (the `run` column, else contiguous time blocks; see [`Context::blocks`]).
    pub run: Option<Vec<i64>>,
    /// Columns with no docs/recording-csv.md role (possible decoys).
    pub others: Vec<(String, Arc<[f64]>)>,
    /// (rpm/1000)², the driver [`KRPM2`]: a heat input ∝ n² (bearing friction), kept only when it
    /// is not a linear function of rpm (see [`krpm2_of`]).
    pub krpm2: Option<Arc<[f64]>>,
    /// Squares of the current columns (`<name>_A`, Joule heating ∝ I²), named `<name>_A^2` in
    /// A², each kept only when it is not a linear function of its column ([`square_of`]).
    pub powers: Vec<(String, Arc<[f64]>)>,
}

/// Name of the squared-speed driver: (rpm/1000)², so its column is of the order of the others
/// (rpm² itself is 10⁷ and would swamp a least-squares Gram matrix next to an intercept).
pub const KRPM2: &str = "krpm^2";

/// (rpm/1000)² when it carries information rpm does not ([`square_of`]).
pub fn krpm2_of(rpm: &[f64]) -> Option<Arc<[f64]>> {
    square_of(rpm, 1000.0)
}

/// Suffix of the driver columns also offered through their square: a current (`_A`), whose heat
/// goes as I². `rpm` has its own square ([`KRPM2`]); a power (`_kW`, `_W`) is heat already.
pub const SQUARED_SUFFIXES: [&str; 1] = ["_A"];

/// The column, exponent and divisor a power driver reads: `krpm^2` → (`rpm`, 2, 1000: the column
/// is read in thousands before squaring), `<name>_A^2` → (`<name>_A`, 2, 1). `None` for a column
/// read as it is (exponent 1).
pub fn power_of(name: &str) -> Option<(&str, i32, f64)> {
    if name == KRPM2 {
        return Some(("rpm", 2, 1000.0));
    }
    name.strip_suffix("^2").map(|c| (c, 2, 1.0))
}

/// (v/`per`)² when it carries information v does not: its part not explained by a + b·v holds
/// more than 1 % of its variance (an on/off spindle at one speed, a current switched between 0
/// and one level, give v² ∝ v exactly, so the square could not be told from the column).
pub fn square_of(v: &[f64], per: f64) -> Option<Arc<[f64]>> {
    let q: Vec<f64> = v.iter().map(|x| (x / per).powi(2)).collect();
    let n = v.len() as f64;
    if n < 3.0 {
        return None;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    let (mv, mq) = (mean(v), mean(&q));
    let (mut svv, mut sqq, mut svq) = (0.0, 0.0, 0.0);
    for (x, y) in v.iter().zip(&q) {
        let (a, b) = (x / per - mv / per, y - mq);
        svv += a * a;
        sqq += b * b;
        svq += a * b;
    }
    let unexplained = if svv > 0.0 {
        sqq - svq * svq / svv
    } else {
        sqq
    };
    (sqq > 0.0 && unexplained > 0.01 * sqq).then(|| q.into())
}

pub fn axis_index(a: char) -> usize {
    AXES.iter()
        .position(|&b| b == a)
        .expect("axis is x, y or z")
}

impl Context {
    pub fn from_recording(rec: &Recording) -> Self {
        let t_s = rec
            .col_shared("t_s")
            .expect("t_s is validated at construction");
        let run = rec.col("run");
        let axes = AXES.map(|a| {
            rec.col_shared(&format!("{a}_mm"))
                .map(|p| axis_features(Arc::clone(&t_s), p, run))
        });
        let grab = |names: Vec<String>| -> Vec<(String, Arc<[f64]>)> {
            names
                .into_iter()
                .map(|n| {
                    let c = rec.col_shared(&n).expect("listed");
                    (n, c)
                })
                .collect()
        };
        Context {
            temps: grab(rec.temperature_channels()),
            loads: grab(rec.load_channels()),
            rpm: rec.col_shared("rpm"),
            tool_mm: rec.col_shared("tool_mm"),
            run: rec
                .col("run")
                .map(|r| r.iter().map(|&v| run_id(v)).collect()),
            others: grab(rec.other_channels()),
            krpm2: rec.col("rpm").and_then(krpm2_of),
            powers: rec
                .other_channels()
                .into_iter()
                .filter(|n| SQUARED_SUFFIXES.iter().any(|s| n.ends_with(s)))
                .filter_map(|n| {
                    let sq = square_of(rec.col(&n).expect("listed"), 1.0)?;
                    Some((format!("{n}^2"), sq))
                })
                .collect(),
            axes,
            t_s,
        }
    }

    pub fn n(&self) -> usize {
        self.t_s.len()
    }

    pub fn axis(&self, a: char) -> Option<&AxisFeatures> {
        self.axes[axis_index(a)].as_ref()
    }

    /// A temperature channel, or any other driver column (`rpm`, columns with no docs/recording-csv.md role):
    /// thermal candidates read their driver through this.
    pub fn temp(&self, name: &str) -> Option<&[f64]> {
        self.temps
            .iter()
            .chain(&self.others)
            .find(|(n, _)| n == name)
            .map(|(_, v)| &**v)
            .or_else(|| self.rpm.as_deref().filter(|_| name == "rpm"))
            .or_else(|| self.krpm2.as_deref().filter(|_| name == KRPM2))
            .or_else(|| {
                self.powers
                    .iter()
                    .find(|(n, _)| n == name)
                    .map(|(_, v)| &**v)
            })
    }

    /// The resolution of column `name` (its unit): the smallest non-zero step between
    /// consecutive rows, e.g. 0.1 °C for a sensor read in tenths. `None` for a constant column.
    pub fn resolution(&self, name: &str) -> Option<f64> {
        let q = self
            .temp(name)?
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .filter(|d| *d > 0.0)
            .fold(f64::INFINITY, f64::min);
        q.is_finite().then_some(q)
    }

    /// Heat-source drivers other than temperatures: `rpm` and every column with no docs/recording-csv.md
    /// role (spindle load, power, coolant, ambient… or a decoy), name and values.
    pub fn drivers(&self) -> Vec<(&str, &[f64])> {
        self.rpm
            .iter()
            .map(|v| ("rpm", &**v))
            .chain(self.krpm2.iter().map(|v| (KRPM2, &**v)))
            .chain(self.others.iter().map(|(n, v)| (n.as_str(), &**v)))
            .chain(self.powers.iter().map(|(n, v)| (n.as_str(), &**v)))
            .collect()
    }

    pub fn load(&self, name: &str) -> Option<&[f64]> {
        self.loads
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| &**v)
    }

    /// Validation blocks: the distinct `run` ids when there are at least three, else `k` contiguous
    /// time blocks of equal sample count. Returns a block index per sample and the block count.
    pub fn blocks(&self, k: usize) -> (Vec<usize>, usize) {
        if let Some(run) = &self.run {
            let mut ids: Vec<i64> = run.clone();
            ids.sort_unstable();
            ids.dedup();
            // Leave-one-run-out needs ≥ 3 runs: with two (e.g. a forward and a reverse laser run)
            // every direction-dependent term would be fitted on one direction only.
            if ids.len() >= 3 {
                let idx = run
                    .iter()
                    .map(|r| ids.binary_search(r).expect("present"))
                    .collect();
                return (idx, ids.len());
            }
        }
        let n = self.n();
        let k = k.clamp(1, n.max(1));
        ((0..n).map(|i| i * k / n.max(1)).collect(), k)
    }
}

/// Most position cells [`Context::position_cells`] makes.
pub const MAX_POSITION_CELLS: usize = 32;

impl Context {
    /// Cells of the axis' position, pooled over direction: one per distinct target when the axis
    /// was read at ≤ [`MAX_POSITION_CELLS`] targets each seen at least twice on average (stepped
    /// laser runs), else [`MAX_POSITION_CELLS`] equal-width bins over its travel. Returns the cell
    /// per sample and the cell count; `None` without the axis.
    pub fn position_cells(&self, axis: char) -> Option<(Vec<usize>, usize)> {
        let f = self.axis(axis)?;
        let n = f.pos_mm.len();
        let distinct = f.distinct_mm.len();
        if distinct <= MAX_POSITION_CELLS && 2 * distinct <= n {
            return Some((
                f.distinct_idx.iter().map(|&k| k as usize).collect(),
                distinct,
            ));
        }
        let lo = f.distinct_mm[0];
        let hi = *f.distinct_mm.last().expect("n ≥ 1");
        if hi - lo <= 1e-9 {
            return Some((vec![0; n], 1));
        }
        let k = MAX_POSITION_CELLS;
        let cell = |x: f64| crate::numeric::bin(x, lo, hi, k);
        Some((f.pos_mm.iter().map(|&x| cell(x)).collect(), k))
    }

    /// Validation folds for the signal of `axis`. As [`Context::blocks`], except when there are
    /// fewer than three runs and some contiguous time block holds only one approach direction of
    /// the axis although the recording has both (a forward then a reverse laser run): then a
    /// direction-dependent term could only ever be validated on the direction it was not fitted
    /// on. The folds are then interleaved position cells (cell c → fold c mod k), so every fold
    /// holds both directions at its positions and every position zone keeps data in training.
    pub fn blocks_for(&self, axis: char, k: usize) -> (Vec<usize>, usize) {
        let (block, nb) = self.blocks(k);
        let runs = self.run.as_ref().map_or(1, |r| {
            let mut ids = r.clone();
            ids.sort_unstable();
            ids.dedup();
            ids.len()
        });
        let (Some(f), Some((cell, n_cells))) = (self.axis(axis), self.position_cells(axis)) else {
            return (block, nb);
        };
        if runs >= 3 || n_cells < 2 * k {
            return (block, nb);
        }
        let has = |b: usize, d: i8| (0..f.dir.len()).any(|i| block[i] == b && f.dir[i] == d);
        let both = f.dir.contains(&1) && f.dir.contains(&-1);
        if !both || (0..nb).all(|b| has(b, 1) && has(b, -1)) {
            return (block, nb);
        }
        (cell.iter().map(|c| c % k).collect(), k)
    }
}

/// A `run` column's value as its block id: run ids are small whole numbers in the CSV.
#[allow(
    clippy::cast_possible_truncation,
    reason = "saturating: a run id beyond ±9·10¹⁸ is still one id, the same for each of its rows"
)]
fn run_id(v: f64) -> i64 {
    v.round() as i64
}

/// Axis features; the direction latch restarts at every change of `run` (a new run is a new
/// approach: its first samples take the direction of its own first move, like the first samples of
/// the recording), so a reverse laser run that starts where the forward run ended is read as reverse.
/// A readings-only recording (see [`pass_starts`]) restarts it at each inferred pass as well.
#[allow(
    clippy::float_cmp,
    reason = "a run id changes or it does not: ids are exact small integers"
)]
fn axis_features(t_s: Arc<[f64]>, pos: Arc<[f64]>, run: Option<&[f64]>) -> AxisFeatures {
    let n = pos.len();
    let mut starts = vec![0];
    if let Some(r) = run {
        starts.extend((1..n).filter(|&i| r[i] != r[i - 1]));
    }
    starts.push(n);
    let mut bounds = vec![0];
    for w in starts.windows(2) {
        bounds.extend(pass_starts(&pos[w[0]..w[1]]).into_iter().map(|k| w[0] + k));
        bounds.push(w[1]);
    }
    bounds.dedup();
    bounds.shrink_to_fit();
    let mut dir = Vec::with_capacity(n);
    for w in bounds.windows(2) {
        dir.extend(latched_dir(&pos[w[0]..w[1]]));
    }
    let mut distinct_mm = pos.to_vec();
    distinct_mm.sort_by(f64::total_cmp);
    distinct_mm.dedup();
    // A handful of distinct positions would otherwise keep the capacity of n rows (8 MB per axis
    // on a 1M-row recording).
    distinct_mm.shrink_to_fit();
    let distinct_idx = pos
        .iter()
        .map(|x| {
            distinct_mm
                .binary_search_by(|d| d.total_cmp(x))
                .ok()
                .and_then(|k| u32::try_from(k).ok())
                .expect("present, and a recording has fewer than 2³² rows")
        })
        .collect();
    AxisFeatures {
        pos_mm: pos,
        t_s,
        dir,
        bounds,
        distinct_mm,
        distinct_idx,
    }
}

/// Pass boundaries of a readings-only bidirectional run (only the readings at the targets are
/// recorded, the same number `m` at every visit, as a laser table F then R with no overshoot row:
/// Asad Ullah's Table 6.2 has m = 1): when every dwell (rows at one position) holds exactly `m`
/// rows except at turnarounds, which hold exactly `2m`, the second half of a turnaround dwell is
/// the first visit of the next pass (approached from the other side after an overshoot the
/// recording does not list). Returns the first row of each such second half; empty for any other
/// recording (a sampled trajectory dwells over varying numbers of rows, and a dwell keeps the
/// direction of its approach, as the latch says).
fn pass_starts(pos: &[f64]) -> Vec<usize> {
    let n = pos.len();
    // Dwells: (first row, row count).
    let mut dwells: Vec<(usize, usize)> = vec![];
    for i in 0..n {
        match dwells.last_mut() {
            Some((s, c)) if (pos[i] - pos[*s]).abs() <= DIRECTION_DEADBAND_MM => *c += 1,
            _ => dwells.push((i, 1)),
        }
    }
    if dwells.len() < 3 {
        return vec![];
    }
    let m = dwells[0].1;
    let mut out = vec![];
    for k in 0..dwells.len() {
        let (s, c) = dwells[k];
        let turnaround = k > 0
            && k + 1 < dwells.len()
            && (pos[s] - pos[dwells[k - 1].0]).signum() != (pos[dwells[k + 1].0] - pos[s]).signum();
        match (turnaround, c) {
            (true, c) if c == 2 * m => out.push(s + m),
            (false, c) if c == m => {}
            _ => return vec![],
        }
    }
    out
}

/// Velocity of one run's commanded motion at each row: a row whose position equals that of a
/// neighbouring row (within the deadband) is at standstill and has v = 0 (a step-and-dwell reading
/// never gets a velocity from the step between two standstill readings); a moving row has the
/// central difference (one-sided at the run's ends).
fn velocity(t_s: &[f64], pos: &[f64]) -> Vec<f64> {
    let n = pos.len();
    let mut vel = vec![0.0; n];
    let same = |a: usize, b: usize| (pos[a] - pos[b]).abs() <= DIRECTION_DEADBAND_MM;
    for (i, v) in vel.iter_mut().enumerate() {
        let lo = i.saturating_sub(1);
        let hi = (i + 1).min(n - 1);
        let still = (lo < i && same(lo, i)) || (hi > i && same(i, hi));
        let dt = t_s[hi] - t_s[lo];
        if !still && hi > lo && dt > 0.0 {
            *v = (pos[hi] - pos[lo]) / dt;
        }
    }
    vel
}

/// Latched direction (the shared definition of [`retrocomp_model::approach`]) and distance since
/// reversal of each row of one run, in row order, to `row(dir, since_mm)`: the features keep the
/// direction, a reversal candidate's columns the distance (each without the other's column).
fn latch(pos: &[f64], mut row: impl FnMut(i8, f64)) {
    let mut l = ApproachLatch::new(DIRECTION_DEADBAND_MM);
    let mut since = 1e9; // no reversal seen yet: "far from any reversal"
    for i in 0..pos.len() {
        let was = l.dir();
        if let Some(ext) = l.update(pos[i]) {
            if was != 0 {
                since = (pos[i] - ext).abs();
            } else if i > 0 {
                since += (pos[i] - pos[i - 1]).abs();
            }
        } else if i > 0 {
            since += (pos[i] - pos[i - 1]).abs();
        }
        row(l.dir(), since);
    }
}

/// The latched direction of each row of one run. The first move's direction also applies to the
/// samples before it (they were approached from somewhere; the best guess is the same side), so
/// the latch never has to invent a zero level.
fn latched_dir(pos: &[f64]) -> Vec<i8> {
    let mut dir = Vec::with_capacity(pos.len());
    latch(pos, |d, _| dir.push(d));
    if let Some(first) = dir.iter().position(|&v| v != 0) {
        let d0 = dir[first];
        dir[..first].iter_mut().for_each(|v| *v = d0);
    }
    dir
}

/// First-order low-pass of `u` with time constant `tau_s`, exact for a signal held between samples
/// (`y += (1 − e^{−Δt/τ})(u − y)`), started at the first value (the machine was at rest before).
pub fn lowpass(t_s: &[f64], u: &[f64], tau_s: f64) -> Vec<f64> {
    retrocomp_model::lag::series(t_s, u, tau_s, u.first().copied().unwrap_or(0.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn direction_latches_through_dwells_and_counts_distance_since_reversal() {
        let t: Vec<f64> = (0..7).map(f64::from).collect();
        let x = [0.0, 1.0, 1.0, 2.0, 1.5, 1.5, 1.0];
        let f = axis_features(Arc::from(&t[..]), Arc::from(&x[..]), None);
        assert_eq!(f.dir, vec![1, 1, 1, 1, -1, -1, -1]);
        assert_eq!(&f.dist_since_rev_mm()[4..], &[0.5, 0.5, 1.0]);
        // Rows 1, 2 and 4, 5 are dwells: no velocity from the steps into or out of them; row 3
        // (the turnaround, moving in and out) has the central difference.
        assert_eq!(f.vel_mm_s(), vec![1.0, 0.0, 0.0, 0.25, 0.0, 0.0, -0.5]);
    }

    #[test]
    fn a_readings_only_table_without_run_labels_reverses_at_the_repeated_turnaround_reading() {
        // F then R, one reading per target, no overshoot row: the second reading at 30 mm is the
        // first of the reverse pass.
        let x = [0.0, 10.0, 20.0, 30.0, 30.0, 20.0, 10.0, 0.0];
        let t: Vec<f64> = (0..x.len()).map(|i| 10.0 * i as f64).collect();
        let f = axis_features(Arc::from(&t[..]), Arc::from(&x[..]), None);
        assert_eq!(f.dir, vec![1, 1, 1, 1, -1, -1, -1, -1]);
        // A sampled trajectory dwelling at its turnaround keeps the approach direction there.
        let x = [0.0, 10.0, 20.0, 30.0, 30.0, 30.0, 20.0, 10.0];
        let f = axis_features(Arc::from(&t[..]), Arc::from(&x[..]), None);
        assert_eq!(f.dir, vec![1, 1, 1, 1, 1, 1, -1, -1]);
        // Two readings per visit, four at the turnaround: split two and two.
        let x = [0.0, 0.0, 10.0, 10.0, 20.0, 20.0, 20.0, 20.0, 10.0, 10.0];
        let t: Vec<f64> = (0..x.len()).map(|i| 10.0 * i as f64).collect();
        let f = axis_features(Arc::from(&t[..]), Arc::from(&x[..]), None);
        assert_eq!(&f.dir[4..8], &[1, 1, -1, -1]);
        assert!(f.vel_mm_s().iter().all(|v| *v == 0.0), "{:?}", f.vel_mm_s());
    }

    #[test]
    fn a_forward_then_reverse_run_is_validated_on_folds_holding_both_directions() {
        // One reading per target, 0..170 mm forward (run 0) then back (run 1), as Table 6.2.
        let x: Vec<f64> = (0..18)
            .chain((0..18).rev())
            .map(|k| 10.0 * f64::from(k))
            .collect();
        let n = x.len();
        let rec = Recording::from_columns(vec![
            ("t_s".into(), (0..n).map(|i| 10.0 * i as f64).collect()),
            ("x_mm".into(), x),
            ("ex_um".into(), vec![0.0; n]),
            (
                "run".into(),
                (0..n).map(|i| f64::from(u8::from(i >= 18))).collect(),
            ),
        ])
        .unwrap();
        let ctx = Context::from_recording(&rec);
        let dir = &ctx.axis('x').unwrap().dir;
        // Contiguous time blocks would put each direction in different folds.
        let (time_blocks, _) = ctx.blocks(5);
        assert!((0..n).filter(|&i| time_blocks[i] == 0).all(|i| dir[i] == 1));
        let (cells, k) = ctx.position_cells('x').unwrap();
        assert_eq!(k, 18, "one cell per target");
        assert_eq!(cells[0], cells[n - 1]);
        let (fold, nf) = ctx.blocks_for('x', 5);
        assert_eq!(nf, 5);
        for b in 0..nf {
            let d: Vec<i8> = (0..n).filter(|&i| fold[i] == b).map(|i| dir[i]).collect();
            assert!(d.contains(&1) && d.contains(&-1), "fold {b}: {d:?}");
        }
        // With ≥ 3 runs the runs stay the folds.
        let rec3 = Recording::from_columns(vec![
            ("t_s".into(), (0..n).map(|i| i as f64).collect()),
            ("x_mm".into(), rec.col("x_mm").unwrap().to_vec()),
            ("ex_um".into(), vec![0.0; n]),
            ("run".into(), (0..n).map(|i| (i / 12) as f64).collect()),
        ])
        .unwrap();
        assert_eq!(Context::from_recording(&rec3).blocks_for('x', 5).1, 3);
    }

    #[test]
    fn resolution_is_the_smallest_step_of_a_reading() {
        let n = 50;
        let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
        // Read in tenths: steps of 0.1 and 0.2 °C, and rows with no change.
        let tq: Vec<f64> = (0..n)
            .map(|i| 20.0 + 0.1 * (i / 3 + i / 10) as f64)
            .collect();
        let rec = Recording::from_columns(vec![
            ("t_s".into(), t),
            ("T_a_C".into(), tq),
            ("T_b_C".into(), vec![21.0; n]),
            ("ez_um".into(), vec![0.0; n]),
        ])
        .unwrap();
        let ctx = Context::from_recording(&rec);
        let q = ctx.resolution("T_a_C").unwrap();
        assert!((q - 0.1).abs() < 1e-9, "{q}");
        assert_eq!(
            ctx.resolution("T_b_C"),
            None,
            "a constant reading has no step"
        );
        assert_eq!(ctx.resolution("T_none_C"), None);
    }

    #[test]
    fn lowpass_step_response_reaches_63_percent_at_tau() {
        let t: Vec<f64> = (0..=1000).map(f64::from).collect();
        let u: Vec<f64> = t
            .iter()
            .map(|&ti| if ti > 0.0 { 1.0 } else { 0.0 })
            .collect();
        let y = lowpass(&t, &u, 100.0);
        // The reading 1 at t = 1 s is held over the interval it ends (the gateway's rule,
        // `models::lag`), so the step acts from t = 0: 1 − 1/e at t = τ = 100 s.
        assert!(
            (y[100] - (1.0 - (-1.0f64).exp())).abs() < 1e-9,
            "{}",
            y[100]
        );
    }
}
