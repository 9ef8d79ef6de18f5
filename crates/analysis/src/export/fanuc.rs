//! Fanuc pitch-error compensation in parameter-tape form (`N<param> A<axis> P<value>` lines; pitch
//! data as `N<10000 + point> P<value>`), as in Asad Ullah (2013) Table 7.2.
//!
//! Layout (per axis): 3620 reference-position point number, 3621 most-negative point, 3622
//! most-positive point, 3623 magnification, 3624 point interval (detection units), 1851 backlash
//! (detection units), 1850 grid shift / reference-position shift (detection units). Point n sits at
//! `ref_position + (n − p3620) · interval`. The value stored at point n is the **incremental
//! correction** for the segment from point n−1 to point n, in detection units × magnification, so
//! the pitch table is 0 at the reference point by definition. The points are exactly those the
//! travel needs, by Fanuc's formula: `3621 = 3620 − (negative travel / interval) + 1`,
//! `3622 = 3620 + (positive travel / interval)` (travel = the table's span, rounded outward to the
//! grid). The error *at* the reference point, which the pitch table cannot carry, goes to 1850:
//! `1850 = round(−error(ref) / detection unit)` (a positive value shifts the reference position
//! in +; check the sign convention of the control before loading).
//!
//! Sign: correction = −error (error = actual − nominal). The pitch table carries the mean of the
//! forward and reverse errors; 1851 carries the lost motion L = mean(x̄↓ − x̄↑) (positive when the axis
//! falls short in its direction of travel), so forward = pitch − L/2 and reverse = pitch + L/2.
//!
//! Rounding: incremental integers are formed by rounding the *cumulative* correction at each point
//! (relative to the reference) and differencing, which is the same as carrying each rounding residual
//! into the next point: the cumulative table is never off by more than half a unit, however long.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crate::import_error::{ErrorSink, ImportErrors};
use crate::table::{BidirectionalTable, TableError};

/// Parameter number of the pitch-data block base: point n is parameter `PITCH_BASE + n`.
pub const PITCH_BASE: u32 = 10000;

/// How an axis's table maps onto Fanuc compensation points.
#[derive(Debug, Clone, PartialEq)]
pub struct FanucAxisConfig {
    /// Axis number in the tape (`A1`, `A2`, …).
    pub axis: u8,
    /// Parameter 3620: point number at the reference position.
    pub ref_point: u32,
    /// Machine position of the reference point, mm.
    pub ref_position_mm: f64,
    /// Point spacing, mm (3624 = interval / detection unit).
    pub interval_mm: f64,
    /// Detection unit, µm (1 µm on most mills).
    pub detection_unit_um: f64,
    /// Parameter 3623.
    pub magnification: u32,
    /// Largest |value| per point the control accepts (e.g. 127); exceeding it is an error.
    pub max_abs_value: i64,
}

/// One axis of a pitch table in controller units.
#[derive(Debug, Clone, PartialEq)]
pub struct FanucAxis {
    pub axis: u8,
    pub p3620_ref_point: u32,
    pub p3621_min_point: u32,
    pub p3622_max_point: u32,
    pub p3623_magnification: u32,
    pub p3624_interval_units: i64,
    pub p1851_backlash_units: i64,
    /// Parameter 1850: correction at the reference point (−error there), detection units.
    pub p1850_ref_shift_units: i64,
    /// Incremental values by point number (only the points present in the file).
    pub values: BTreeMap<u32, i64>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FanucError {
    #[error("interval {interval_mm} mm is not a whole number of {unit_um} µm detection units")]
    Interval { interval_mm: f64, unit_um: f64 },
    #[error(
        "table span {lo_mm}..{hi_mm} mm needs point numbers below 0 for reference point {ref_point}"
    )]
    PointRange {
        lo_mm: f64,
        hi_mm: f64,
        ref_point: u32,
    },
    #[error("value {value} at point {point} exceeds ±{max}: raise the magnification (3623)")]
    ValueRange { point: u32, value: i64, max: i64 },
    #[error(
        "axis A{axis}: point {point} is missing between point {from} and the reference point {reference}"
    )]
    Gap {
        axis: u8,
        point: u32,
        from: u32,
        reference: u32,
    },
    #[error("axis A{axis} has no pitch values in points {min}..={max}")]
    NoValues { axis: u8, min: u32, max: u32 },
    #[error(transparent)]
    Table(#[from] TableError),
}

/// Rounded half away from zero, in the parameter's integer type.
#[allow(
    clippy::cast_possible_truncation,
    reason = "saturating: a value past i64 then fails the ±max_abs_value check (pitch values) or is no parameter a control holds anyway"
)]
fn round_half_away(x: f64) -> i64 {
    x.round() as i64
}

/// Converts a table to one Fanuc axis. The points cover the table's span (rounded outward to the
/// grid; a span ending on a grid point needs no point beyond it); between the span and the
/// reference point the end errors are held, so those increments are 0.
pub fn to_fanuc(
    table: &BidirectionalTable,
    cfg: &FanucAxisConfig,
) -> Result<FanucAxis, FanucError> {
    table.validate()?;
    let units_per_interval = cfg.interval_mm * 1000.0 / cfg.detection_unit_um;
    if (units_per_interval - units_per_interval.round()).abs() > 1e-6 || units_per_interval < 1.0 {
        return Err(FanucError::Interval {
            interval_mm: cfg.interval_mm,
            unit_um: cfg.detection_unit_um,
        });
    }
    let lo_mm = table.positions_mm[0];
    let hi_mm = *table.positions_mm.last().expect("validated non-empty");
    // Grid index of the travel ends, rounded outward (a grid-aligned end stays on its point).
    let k_lo = round_half_away(((lo_mm - cfg.ref_position_mm) / cfg.interval_mm + 1e-9).floor());
    let k_hi = round_half_away(((hi_mm - cfg.ref_position_mm) / cfg.interval_mm - 1e-9).ceil());
    // Fanuc's formula: point n covers the segment below it, so the lowest segment (from grid
    // index k_lo) is carried by point ref + k_lo + 1.
    let min_point = i64::from(cfg.ref_point) + k_lo.min(0) + 1;
    let max_point = i64::from(cfg.ref_point) + k_hi.max(0);
    let point_range = || FanucError::PointRange {
        lo_mm,
        hi_mm,
        ref_point: cfg.ref_point,
    };
    // Point numbers are parameters (u32): below 0 or past u32 the table cannot be written.
    let (Ok(p3621_min_point), Ok(p3622_max_point)) =
        (u32::try_from(min_point), u32::try_from(max_point))
    else {
        return Err(point_range());
    };
    let unit = cfg.detection_unit_um * f64::from(cfg.magnification);
    let mean = table.mean_um();
    let correction_units = |n: i64| -> f64 {
        let pos = cfg.ref_position_mm + (n - i64::from(cfg.ref_point)) as f64 * cfg.interval_mm;
        -crate::table::interpolate(&table.positions_mm, &mean, pos) / unit
    };
    let c_ref = correction_units(i64::from(cfg.ref_point));
    let cumulative = |n: i64| round_half_away(correction_units(n) - c_ref);
    let mut values = BTreeMap::new();
    for point in p3621_min_point..=p3622_max_point {
        let n = i64::from(point);
        let v = cumulative(n) - cumulative(n - 1);
        if v.abs() > cfg.max_abs_value {
            return Err(FanucError::ValueRange {
                point,
                value: v,
                max: cfg.max_abs_value,
            });
        }
        values.insert(point, v);
    }
    let lost_motion_um = table
        .reverse_um
        .iter()
        .zip(&table.forward_um)
        .map(|(r, f)| r - f)
        .sum::<f64>()
        / table.len() as f64;
    Ok(FanucAxis {
        axis: cfg.axis,
        p3620_ref_point: cfg.ref_point,
        p3621_min_point,
        p3622_max_point,
        p3623_magnification: cfg.magnification,
        p3624_interval_units: round_half_away(units_per_interval),
        p1851_backlash_units: round_half_away(lost_motion_um / cfg.detection_unit_um),
        p1850_ref_shift_units: round_half_away(c_ref * f64::from(cfg.magnification)),
        values,
    })
}

/// Reconstructs the error table of one axis (relative to the reference point, where it is 0) from
/// the points present. Points from the lowest present point − 1 to the highest present point get a
/// row; every point between a row and the reference must be present (else [`FanucError::Gap`]).
pub fn from_fanuc(
    axis: &FanucAxis,
    detection_unit_um: f64,
    ref_position_mm: f64,
) -> Result<BidirectionalTable, FanucError> {
    let (Some((&lo, _)), Some((&hi, _))) =
        (axis.values.first_key_value(), axis.values.last_key_value())
    else {
        return Err(FanucError::NoValues {
            axis: axis.axis,
            min: axis.p3621_min_point,
            max: axis.p3622_max_point,
        });
    };
    let r = axis.p3620_ref_point;
    for n in lo..=hi {
        if !axis.values.contains_key(&n) {
            return Err(FanucError::Gap {
                axis: axis.axis,
                point: n,
                from: if n < r { lo } else { hi },
                reference: r,
            });
        }
    }
    if r + 1 < lo || r > hi {
        return Err(FanucError::Gap {
            axis: axis.axis,
            point: if r < lo { lo - 1 } else { hi + 1 },
            from: lo,
            reference: r,
        });
    }
    let unit = detection_unit_um * f64::from(axis.p3623_magnification);
    let interval_mm = axis.p3624_interval_units as f64 * detection_unit_um / 1000.0;
    // Cumulative correction (units) at point n, relative to the reference point.
    let cum = |n: u32| -> i64 {
        if n >= r {
            (r + 1..=n).map(|k| axis.values[&k]).sum()
        } else {
            -(n + 1..=r).map(|k| axis.values[&k]).sum::<i64>()
        }
    };
    // The lowest present value covers the segment below it, which fixes one more point.
    let first = lo.saturating_sub(1);
    // 1850 carries the correction at the reference point (detection units, no magnification).
    let shift_um = axis.p1850_ref_shift_units as f64 * detection_unit_um;
    let half_l = 0.5 * axis.p1851_backlash_units as f64 * detection_unit_um;
    let mut pos = Vec::new();
    let mut fwd = Vec::new();
    let mut rev = Vec::new();
    for n in first..=hi {
        let e = -(cum(n) as f64) * unit - shift_um;
        pos.push(ref_position_mm + (f64::from(n) - f64::from(r)) * interval_mm);
        fwd.push(e - half_l);
        rev.push(e + half_l);
    }
    Ok(BidirectionalTable::new(pos, fwd, rev)?)
}

/// Sum of all incremental values of an axis (the total correction across the table, units).
pub fn cumulative_sum(axis: &FanucAxis) -> i64 {
    axis.values.values().sum()
}

/// Writes axes in parameter-tape form.
pub fn write_tape(axes: &[FanucAxis]) -> String {
    let mut s = String::from("%\n");
    let row = |s: &mut String, param: u32, f: &dyn Fn(&FanucAxis) -> i64| {
        let _ = write!(s, "N{param}");
        for a in axes {
            let _ = write!(s, " A{} P{}", a.axis, f(a));
        }
        s.push('\n');
    };
    row(&mut s, 1850, &|a| a.p1850_ref_shift_units);
    row(&mut s, 1851, &|a| a.p1851_backlash_units);
    row(&mut s, 3620, &|a| i64::from(a.p3620_ref_point));
    row(&mut s, 3621, &|a| i64::from(a.p3621_min_point));
    row(&mut s, 3622, &|a| i64::from(a.p3622_max_point));
    row(&mut s, 3623, &|a| i64::from(a.p3623_magnification));
    row(&mut s, 3624, &|a| a.p3624_interval_units);
    let mut points: BTreeMap<u32, i64> = BTreeMap::new();
    for a in axes {
        points.extend(a.values.iter().map(|(k, v)| (*k, *v)));
    }
    for (n, v) in points {
        let _ = writeln!(s, "N{} P{}", PITCH_BASE + n, v);
    }
    s.push_str("%\n");
    s
}

/// Reads a parameter tape. Pitch points are assigned to the axis whose 3621..=3622 range holds
/// them; a point in no axis's range, an unknown parameter or a malformed word is a located error.
pub fn read_tape(file: &str, text: &str) -> Result<Vec<FanucAxis>, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut params: BTreeMap<(u32, u8), (i64, u64)> = BTreeMap::new();
    let mut pitch: Vec<(u32, i64, u64)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        read_tape_line(&mut sink, i as u64 + 1, raw, &mut params, &mut pitch);
    }
    let axis_ids: std::collections::BTreeSet<u8> = params.keys().map(|(_, a)| *a).collect();
    // An empty tape (or one of comments only) is refused: it would import as "no axes" and export
    // as a tape of empty parameter rows that no reader accepts (fuzz target `controller_tables`).
    if axis_ids.is_empty() && sink.is_empty() {
        sink.push(
            0,
            None,
            "no axis parameters found (expected N1851 and N3620–N3624 with `A<axis> P<value>` pairs)",
        );
    }
    let mut axes = Vec::new();
    for a in axis_ids {
        if let Some(axis) = tape_axis(&mut sink, &params, a) {
            axes.push(axis);
        }
    }
    for (n, v, line) in pitch {
        match axes
            .iter_mut()
            .find(|a| (a.p3621_min_point..=a.p3622_max_point).contains(&n))
        {
            Some(a) => {
                if a.values.insert(n, v).is_some() {
                    sink.push(
                        line,
                        Some(&format!("N{}", PITCH_BASE + n)),
                        "pitch point given twice",
                    );
                }
            }
            None => sink.push(
                line,
                Some(&format!("N{}", PITCH_BASE + n)),
                "pitch point lies in no axis's 3621..3622 range",
            ),
        }
    }
    sink.finish(axes)
}

/// One tape line into `params` ((parameter, axis) → (value, line)) or `pitch` (point, value,
/// line); a line that is neither goes to `sink` with what was expected.
fn read_tape_line(
    sink: &mut ErrorSink,
    line_no: u64,
    raw: &str,
    params: &mut BTreeMap<(u32, u8), (i64, u64)>,
    pitch: &mut Vec<(u32, i64, u64)>,
) {
    let line = raw.split(['(', '#']).next().unwrap_or("").trim();
    if line.is_empty() || line == "%" {
        return;
    }
    let mut words = line.split_whitespace();
    let n_word = words.next().unwrap_or("");
    let Some(param) = n_word.strip_prefix('N').and_then(|v| v.parse::<u32>().ok()) else {
        sink.push(line_no, Some(n_word), "expected `N<parameter number>`");
        return;
    };
    let rest: Vec<&str> = words.collect();
    if param >= PITCH_BASE {
        match rest.as_slice() {
            [p] if p.starts_with('P') => match p[1..].parse::<i64>() {
                Ok(v) => pitch.push((param - PITCH_BASE, v, line_no)),
                Err(_) => sink.push(line_no, Some(p), "expected `P<integer>`"),
            },
            _ => sink.push(
                line_no,
                Some(n_word),
                "pitch data needs exactly one `P<integer>` word",
            ),
        }
        return;
    }
    if ![1850, 1851, 3620, 3621, 3622, 3623, 3624].contains(&param) {
        sink.push(
            line_no,
            Some(n_word),
            "unsupported parameter (expected 1850, 1851, 3620–3624 or pitch data ≥ 10000)",
        );
        return;
    }
    if rest.is_empty() || !rest.len().is_multiple_of(2) {
        sink.push(line_no, Some(n_word), "expected `A<axis> P<value>` pairs");
        return;
    }
    for pair in rest.chunks(2) {
        let a = pair[0].strip_prefix('A').and_then(|v| v.parse::<u8>().ok());
        let p = pair[1]
            .strip_prefix('P')
            .and_then(|v| v.parse::<i64>().ok());
        match (a, p) {
            (Some(a), Some(p)) => {
                params.insert((param, a), (p, line_no));
            }
            _ => sink.push(
                line_no,
                Some(&format!("{} {}", pair[0], pair[1])),
                "expected `A<axis> P<integer>`",
            ),
        }
    }
}

/// Axis `a` from its parameters, with no pitch values yet; `None` when a required parameter is
/// missing (each missing one reported, in parameter order).
fn tape_axis(
    sink: &mut ErrorSink,
    params: &BTreeMap<(u32, u8), (i64, u64)>,
    a: u8,
) -> Option<FanucAxis> {
    let mut get = |p: u32| -> Option<i64> {
        let v = params.get(&(p, a)).map(|v| v.0);
        if v.is_none() {
            sink.push(
                0,
                Some(&format!("N{p} A{a}")),
                "parameter missing for this axis",
            );
        }
        v
    };
    let (Some(b), Some(r), Some(lo), Some(hi), Some(m), Some(iv)) = (
        get(1851),
        get(3620),
        get(3621),
        get(3622),
        get(3623),
        get(3624),
    ) else {
        return None;
    };
    // Point numbers and the magnification are unsigned: a negative one is an error on the tape,
    // not a number to wrap.
    let mut unsigned = |p: u32, v: i64| {
        let u = u32::try_from(v).ok();
        if u.is_none() {
            sink.push(
                0,
                Some(&format!("N{p} A{a}")),
                "must be a whole number from 0 to 4294967295",
            );
        }
        u
    };
    let (Some(r), Some(lo), Some(hi), Some(m)) = (
        unsigned(3620, r),
        unsigned(3621, lo),
        unsigned(3622, hi),
        unsigned(3623, m),
    ) else {
        return None;
    };
    Some(FanucAxis {
        axis: a,
        p3620_ref_point: r,
        p3621_min_point: lo,
        p3622_max_point: hi,
        p3623_magnification: m,
        p3624_interval_units: iv,
        p1851_backlash_units: b,
        // Optional: a tape without it has no reference-point shift.
        p1850_ref_shift_units: params.get(&(1850, a)).map_or(0, |v| v.0),
        values: BTreeMap::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tape_without_axis_parameters_is_refused() {
        for text in ["", "%\n%\n", "(comment only)\n"] {
            let e = read_tape("t.tape", text).unwrap_err().to_string();
            assert!(e.contains("no axis parameters found"), "{text:?}: {e}");
        }
    }

    #[test]
    fn rounding_carries_the_residual() {
        // A steady 0.4 µm/interval error ramp: per-interval rounding would emit all zeros.
        let pos: Vec<f64> = (0..=10).map(|i| 20.0 * f64::from(i)).collect();
        let err: Vec<f64> = (0..=10).map(|i| -0.4 * f64::from(i)).collect();
        let t = BidirectionalTable::unidirectional(pos, err).unwrap();
        let cfg = FanucAxisConfig {
            axis: 1,
            ref_point: 10,
            ref_position_mm: 0.0,
            interval_mm: 20.0,
            detection_unit_um: 1.0,
            magnification: 1,
            max_abs_value: 127,
        };
        let ax = to_fanuc(&t, &cfg).unwrap();
        assert_eq!(cumulative_sum(&ax), 4); // round(0.4 × 10)
        assert!(ax.values.values().any(|v| *v == 1));
    }
}
