//! Import of laser positioning runs into ISO 230-2 [`Reading`]s.
//!
//! Two CSV layouts are accepted (detected from the header; `#` lines are comments):
//! - **long**: columns `target_mm`, `run` (integer), `direction` (`+` or `-`), `deviation_um`
//!   (actual − target), in any order, one reading per row;
//! - **wide** (laser software export, two columns per run: one per direction): `target_mm`, then
//!   `run<k>_fwd_um`, `run<k>_rev_um` for k = 1, 2, … (deviation = actual − target).
//!
//! Every bad cell is reported with file, line and column; nothing is imported when any row is bad.
//! Linear drift per cycle can be removed ([`remove_linear_drift`], after Spaan Ch3).

use std::collections::BTreeMap;

use super::import_error::{ErrorSink, ImportErrors};
use super::iso230_2::Reading;
use super::table::Direction;

/// Parses either layout from CSV text. `file` is used in error messages only.
pub fn parse_readings(file: &str, text: &str) -> Result<Vec<Reading>, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let Some((mut rdr, headers, header_line)) = open_csv(&mut sink, text) else {
        return sink.finish(Vec::new());
    };
    let names: Vec<&str> = headers.iter().collect();
    if names.contains(&"direction") {
        parse_long(sink, &mut rdr, &names, header_line)
    } else if names
        .iter()
        .any(|n| n.starts_with("run") && n.ends_with("_fwd_um"))
    {
        parse_wide(sink, &mut rdr, &names, header_line)
    } else {
        sink.push(
            header_line,
            None,
            format!(
                "unknown layout: expected columns `target_mm,run,direction,deviation_um` or `target_mm,run1_fwd_um,run1_rev_um,…`; found `{}`",
                names.join(",")
            ),
        );
        sink.finish(Vec::new())
    }
}

/// Readings seen so far: (target in nm, run, direction) → line.
type Seen = std::collections::HashMap<(i64, u32, char), u64>;

/// A second reading for the same target, run and direction is an error (it would silently weigh
/// that run twice in the means).
fn check_duplicate(sink: &mut ErrorSink, seen: &mut Seen, r: &Reading, line: u64) {
    #[allow(
        clippy::cast_possible_truncation,
        reason = "a key only: targets are finite and far inside ±9·10⁹ mm, so nm fit an i64 exactly"
    )]
    let key = (
        (r.target_mm * 1e6).round() as i64,
        r.run,
        r.direction.symbol(),
    );
    if let Some(first) = seen.insert(key, line) {
        sink.push(
            line,
            None,
            format!(
                "second reading for target {} mm, run {}, direction `{}` (first on line {first})",
                r.target_mm, r.run, key.2
            ),
        );
    }
}

/// Opens the CSV text every importer here reads: header first, `#` lines are comments, cells trimmed.
/// Returns the reader, the header and the header's line; `None` (error in `sink`) if the header is
/// unreadable.
fn open_csv<'a>(
    sink: &mut ErrorSink,
    text: &'a str,
) -> Option<(csv::Reader<&'a [u8]>, csv::StringRecord, u64)> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .flexible(true)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    match rdr.headers() {
        Ok(h) => {
            let h = h.clone();
            let line = rdr.position().line();
            Some((rdr, h, line))
        }
        Err(e) => {
            sink.push(1, None, format!("cannot read the header: {e}"));
            None
        }
    }
}

/// Calls `row(sink, line, record)` for every data row with exactly `width` fields; an unreadable
/// row or one of another width is reported in `sink` (with its line) and skipped, never dropped
/// silently.
fn for_each_row(
    sink: &mut ErrorSink,
    rdr: &mut csv::Reader<&[u8]>,
    width: usize,
    mut row: impl FnMut(&mut ErrorSink, u64, &csv::StringRecord),
) {
    for rec in rdr.records() {
        let rec = match rec {
            Ok(r) => r,
            Err(e) => {
                let line = e.position().map_or(0, |p| p.line());
                sink.push(line, None, format!("unreadable row: {e}"));
                continue;
            }
        };
        let line = rec.position().map_or(0, |p| p.line());
        if rec.len() != width {
            sink.push(
                line,
                None,
                format!("expected {width} fields, found {}", rec.len()),
            );
            continue;
        }
        row(sink, line, &rec);
    }
}

/// Finishes an import: a file with a header but no data row (and no other error) is an error too.
fn finish_rows<T>(
    mut sink: ErrorSink,
    header_line: u64,
    no_rows: bool,
    value: T,
) -> Result<T, ImportErrors> {
    if no_rows && sink.is_empty() {
        sink.push(header_line, None, "no data rows");
    }
    sink.finish(value)
}

fn column(sink: &mut ErrorSink, names: &[&str], name: &str, line: u64) -> Option<usize> {
    let i = names.iter().position(|n| *n == name);
    if i.is_none() {
        sink.push(
            line,
            Some(name),
            "required column is missing from the header",
        );
    }
    i
}

fn parse_long(
    mut sink: ErrorSink,
    rdr: &mut csv::Reader<&[u8]>,
    names: &[&str],
    header_line: u64,
) -> Result<Vec<Reading>, ImportErrors> {
    let ct = column(&mut sink, names, "target_mm", header_line);
    let cr = column(&mut sink, names, "run", header_line);
    let cd = column(&mut sink, names, "direction", header_line);
    let cx = column(&mut sink, names, "deviation_um", header_line);
    let (Some(ct), Some(cr), Some(cd), Some(cx)) = (ct, cr, cd, cx) else {
        return sink.finish(Vec::new());
    };
    let mut out = Vec::new();
    let mut seen = Seen::new();
    for_each_row(&mut sink, rdr, names.len(), |sink, line, rec| {
        let t = sink.parse_f64(line, "target_mm", &rec[ct]);
        let run = match rec[cr].parse::<u32>() {
            Ok(v) => Some(v),
            Err(_) => {
                sink.push(
                    line,
                    Some("run"),
                    format!("expected a non-negative integer, found `{}`", &rec[cr]),
                );
                None
            }
        };
        let dir = match &rec[cd] {
            "+" => Some(Direction::Forward),
            "-" => Some(Direction::Reverse),
            other => {
                sink.push(
                    line,
                    Some("direction"),
                    format!("expected `+` or `-`, found `{other}`"),
                );
                None
            }
        };
        let x = sink.parse_f64(line, "deviation_um", &rec[cx]);
        if let (Some(target_mm), Some(run), Some(direction), Some(deviation_um)) = (t, run, dir, x)
        {
            let r = Reading {
                target_mm,
                run,
                direction,
                deviation_um,
            };
            check_duplicate(sink, &mut seen, &r, line);
            out.push(r);
        }
    });
    finish_rows(sink, header_line, out.is_empty(), out)
}

fn parse_wide(
    mut sink: ErrorSink,
    rdr: &mut csv::Reader<&[u8]>,
    names: &[&str],
    header_line: u64,
) -> Result<Vec<Reading>, ImportErrors> {
    let Some(ct) = column(&mut sink, names, "target_mm", header_line) else {
        return sink.finish(Vec::new());
    };
    // Map every other column to (run, direction); unknown columns are an error, not ignored.
    let mut cols: Vec<(usize, u32, Direction)> = Vec::new();
    let mut run_columns: BTreeMap<u32, (bool, bool)> = BTreeMap::new();
    for (i, n) in names.iter().enumerate() {
        if i == ct {
            continue;
        }
        let parsed = n.strip_prefix("run").and_then(|rest| {
            let (k, dir) = if let Some(k) = rest.strip_suffix("_fwd_um") {
                (k, Direction::Forward)
            } else {
                (rest.strip_suffix("_rev_um")?, Direction::Reverse)
            };
            k.parse::<u32>().ok().map(|k| (k, dir))
        });
        match parsed {
            Some((k, d)) => {
                cols.push((i, k, d));
                let e = run_columns.entry(k).or_default();
                match d {
                    Direction::Forward => e.0 = true,
                    Direction::Reverse => e.1 = true,
                }
            }
            None => sink.push(
                header_line,
                Some(n),
                "expected `run<k>_fwd_um` or `run<k>_rev_um`",
            ),
        }
    }
    for (k, (f, r)) in &run_columns {
        if !(*f && *r) {
            sink.push(
                header_line,
                None,
                format!("run {k} needs both `run{k}_fwd_um` and `run{k}_rev_um`"),
            );
        }
    }
    if !sink.is_empty() {
        return sink.finish(Vec::new());
    }
    let mut out = Vec::new();
    let mut seen = Seen::new();
    for_each_row(&mut sink, rdr, names.len(), |sink, line, rec| {
        let Some(target_mm) = sink.parse_f64(line, "target_mm", &rec[ct]) else {
            return;
        };
        for &(i, run, direction) in &cols {
            if let Some(deviation_um) = sink.parse_f64(line, names[i], &rec[i]) {
                let r = Reading {
                    target_mm,
                    run,
                    direction,
                    deviation_um,
                };
                check_duplicate(sink, &mut seen, &r, line);
                out.push(r);
            }
        }
    });
    finish_rows(sink, header_line, out.is_empty(), out)
}

/// Removes a linear drift across measurement cycles (Spaan Ch3: "linear time drift is removed per
/// cycle"). Each run (one forward and one reverse pass) is one cycle; the mean deviation of each run
/// is fitted by a straight line against the run number, and the slope × (run − first run) is
/// subtracted from every reading of that run, so the first run is the reference.
///
/// Returns the removed slope in µm per cycle. With fewer than two runs nothing is changed (slope 0).
/// Spaan applies it only when there is no backlash-driven structure in the run means; the caller
/// decides (the CLI makes it opt-in).
pub fn remove_linear_drift(readings: &mut [Reading]) -> f64 {
    let mut per_run: BTreeMap<u32, (f64, usize)> = BTreeMap::new();
    for r in readings.iter() {
        let e = per_run.entry(r.run).or_default();
        e.0 += r.deviation_um;
        e.1 += 1;
    }
    if per_run.len() < 2 {
        return 0.0;
    }
    let pts: Vec<(f64, f64)> = per_run
        .iter()
        .map(|(k, (s, n))| (f64::from(*k), s / *n as f64))
        .collect();
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    let first = pts[0].0;
    for r in readings.iter_mut() {
        r.deviation_um -= slope * (f64::from(r.run) - first);
    }
    slope
}

/// Reads a bidirectional table from named CSV columns (position, forward, reverse), multiplying
/// the error columns by `to_um` (1000 for tables printed in mm). Bad cells are reported with line
/// and column; positions must increase.
pub fn parse_table_columns(
    file: &str,
    text: &str,
    position_col: &str,
    forward_col: &str,
    reverse_col: &str,
    to_um: f64,
) -> Result<super::table::BidirectionalTable, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let Some((mut rdr, headers, header_line)) = open_csv(&mut sink, text) else {
        return sink.finish(Default::default());
    };
    let names: Vec<&str> = headers.iter().collect();
    let idx: Vec<Option<usize>> = [position_col, forward_col, reverse_col]
        .iter()
        .map(|c| column(&mut sink, &names, c, header_line))
        .collect();
    let (Some(cp), Some(cf), Some(cr)) = (idx[0], idx[1], idx[2]) else {
        return sink.finish(Default::default());
    };
    let mut t = super::table::BidirectionalTable {
        positions_mm: vec![],
        forward_um: vec![],
        reverse_um: vec![],
    };
    for_each_row(&mut sink, &mut rdr, names.len(), |sink, line, rec| {
        let p = sink.parse_f64(line, position_col, &rec[cp]);
        let f = sink.parse_f64(line, forward_col, &rec[cf]);
        let r = sink.parse_f64(line, reverse_col, &rec[cr]);
        let (Some(p), Some(f), Some(r)) = (p, f, r) else {
            return;
        };
        if let Some(&prev) = t.positions_mm.last()
            && p <= prev
        {
            sink.push(
                line,
                Some(position_col),
                format!("positions must increase: {p} follows {prev}"),
            );
            return;
        }
        t.positions_mm.push(p);
        t.forward_um.push(f * to_um);
        t.reverse_um.push(r * to_um);
    });
    let no_rows = t.positions_mm.is_empty();
    finish_rows(sink, header_line, no_rows, t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_and_wide_layouts_give_the_same_readings() {
        let long =
            "target_mm,run,direction,deviation_um\n0,1,+,1.5\n0,1,-,-0.5\n10,1,+,2\n10,1,-,0\n";
        let wide = "# laser export\ntarget_mm,run1_fwd_um,run1_rev_um\n0,1.5,-0.5\n10,2,0\n";
        let mut a = parse_readings("a.csv", long).unwrap();
        let mut b = parse_readings("b.csv", wide).unwrap();
        let order = |x: &Reading, y: &Reading| {
            (x.target_mm.total_cmp(&y.target_mm))
                .then(x.direction.symbol().cmp(&y.direction.symbol()))
        };
        a.sort_by(order);
        b.sort_by(order);
        assert_eq!(a, b);
        assert_eq!(a.len(), 4);
    }

    #[test]
    fn every_bad_cell_is_reported_with_line_and_column() {
        let text =
            "target_mm,run,direction,deviation_um\n0,1,+,1\n0,x,-,2\n10,1,up,nan\n10,1,-,3\n";
        let err = parse_readings("runs.csv", text).unwrap_err();
        let msgs: Vec<String> = err.0.iter().map(|e| e.to_string()).collect();
        assert_eq!(msgs.len(), 3, "{msgs:?}");
        assert!(
            msgs[0].starts_with("runs.csv:3: column `run`"),
            "{}",
            msgs[0]
        );
        assert!(
            msgs[1].starts_with("runs.csv:4: column `direction`"),
            "{}",
            msgs[1]
        );
        assert!(
            msgs[2].starts_with("runs.csv:4: column `deviation_um`"),
            "{}",
            msgs[2]
        );
    }

    #[test]
    fn duplicate_readings_are_reported_not_double_counted() {
        let text = "target_mm,run,direction,deviation_um\n0,1,+,1\n0,1,+,1.2\n0,1,-,0\n";
        let err = parse_readings("d.csv", text).unwrap_err();
        assert_eq!(err.0.len(), 1);
        assert!(
            err.0[0].to_string().starts_with(
                "d.csv:3: second reading for target 0 mm, run 1, direction `+` (first on line 2)"
            ),
            "{}",
            err.0[0]
        );
    }

    #[test]
    fn drift_removal_recovers_the_injected_slope() {
        let mut rs = Vec::new();
        for run in 1..=5u32 {
            for (i, t) in [0.0, 50.0, 100.0].iter().enumerate() {
                let base = i as f64; // same shape every run
                let drift = 0.8 * f64::from(run - 1);
                rs.push(Reading {
                    target_mm: *t,
                    run,
                    direction: Direction::Forward,
                    deviation_um: base + drift,
                });
                rs.push(Reading {
                    target_mm: *t,
                    run,
                    direction: Direction::Reverse,
                    deviation_um: base - 1.0 + drift,
                });
            }
        }
        let slope = remove_linear_drift(&mut rs);
        assert!((slope - 0.8).abs() < 1e-12);
        for r in &rs {
            let expect = r.target_mm / 50.0
                - if r.direction == Direction::Reverse {
                    1.0
                } else {
                    0.0
                };
            assert!((r.deviation_um - expect).abs() < 1e-9);
        }
    }
}
