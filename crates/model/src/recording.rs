//! Reader and writer of the recording CSV (docs/recording-csv.md): one header row, one sample per row, every column
//! numeric, the unit in the column name (`t_s`, `x_mm`, `ex_um`, `sim_ex_um`, `T_<name>_C`, `rpm`,
//! `F_<name>_N`, `strain_<name>_ue`, `tool_mm`, `run`). Errors are actual − nominal in µm.
//!
//! Bad rows (a cell that is not a number, NaN/inf, a short row, time going backwards) are never dropped
//! silently: the strict reader fails with every bad row listed (line number, column, what was expected);
//! the lenient reader returns them next to the good rows so the caller can print them.
//! The writer refuses the same faults, so a recording it wrote always reads back strictly.

use std::fmt;
use std::io::{Read, Write};
use std::path::Path;
use std::sync::Arc;

use crate::units::ChannelKind;

/// One rejected row: its 1-based line number in the file (the header is line 1) and why.
#[derive(Clone, Debug, PartialEq)]
pub struct BadRow {
    pub line: u64,
    pub column: Option<String>,
    pub reason: String,
}

impl fmt::Display for BadRow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.column {
            Some(c) => write!(f, "line {}, column `{}`: {}", self.line, c, self.reason),
            None => write!(f, "line {}: {}", self.line, self.reason),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{source_name}: cannot read: {msg}")]
    Io { source_name: String, msg: String },
    #[error("{source_name}: header: {msg}")]
    Header { source_name: String, msg: String },
    #[error("{source_name}: {} bad row(s), none dropped:\n{}", bad.len(), list_bad(bad))]
    BadRows {
        source_name: String,
        bad: Vec<BadRow>,
    },
    #[error("recording writer: {0}")]
    Write(String),
}

fn list_bad(bad: &[BadRow]) -> String {
    let mut s = String::new();
    for b in bad.iter().take(20) {
        s.push_str("  ");
        s.push_str(&b.to_string());
        s.push('\n');
    }
    if bad.len() > 20 {
        s.push_str(&format!("  … and {} more\n", bad.len() - 20));
    }
    s
}

/// A recording held column-wise (every column has `n_rows()` values, all finite). Columns are
/// shared (`Arc`), so `diagnose`'s context reads them without a copy (a 1M-row recording's
/// columns are 8 MB each; issue 12 item 10).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recording {
    names: Vec<String>,
    cols: Vec<Arc<[f64]>>,
    /// 1-based file line of every kept row (for messages that point back into the file); `None`
    /// when row i is on line i + 2 (no row skipped: the common case, 8 bytes a row saved).
    lines: Option<Vec<u64>>,
}

/// The three Cartesian axes a recording may carry.
pub const AXES: [char; 3] = ['x', 'y', 'z'];

impl Recording {
    /// Build from named columns (all the same length, finite, `t_s` present and non-decreasing).
    pub fn from_columns(named: Vec<(String, Vec<f64>)>) -> Result<Self, RecordingError> {
        let (names, cols): (Vec<_>, Vec<_>) = named.into_iter().unzip();
        let n = cols.first().map_or(0, |c| c.len());
        if cols.iter().any(|c| c.len() != n) {
            return Err(RecordingError::Header {
                source_name: "columns".into(),
                msg: "columns of different lengths".into(),
            });
        }
        validate_header(&names).map_err(|msg| RecordingError::Header {
            source_name: "columns".into(),
            msg,
        })?;
        let t = &cols[names.iter().position(|n| n == "t_s").expect("validated")];
        for i in 0..n {
            let line = i as u64 + 2;
            if let Some(j) = cols.iter().position(|c| !c[i].is_finite()) {
                return Err(RecordingError::Write(format!(
                    "line {line}, column `{}`: not finite",
                    names[j]
                )));
            }
            if i > 0 && t[i] < t[i - 1] {
                return Err(RecordingError::Write(format!(
                    "line {line}: time goes backwards"
                )));
            }
        }
        Ok(Recording {
            names,
            cols: cols.into_iter().map(Arc::from).collect(),
            lines: None,
        })
    }

    /// Strict read of a file: any bad row is an error listing all of them.
    pub fn read_path(path: &Path) -> Result<Self, RecordingError> {
        let f = std::fs::File::open(path).map_err(|e| RecordingError::Io {
            source_name: path.display().to_string(),
            msg: e.to_string(),
        })?;
        Self::read_strict(f, &path.display().to_string())
    }

    pub fn read_strict<R: Read>(rdr: R, source_name: &str) -> Result<Self, RecordingError> {
        let (rec, bad) = Self::read_lenient(rdr, source_name)?;
        if bad.is_empty() {
            Ok(rec)
        } else {
            Err(RecordingError::BadRows {
                source_name: source_name.into(),
                bad,
            })
        }
    }

    /// Lenient read: good rows are kept, bad rows are returned (with line numbers) for the caller to
    /// report. A row whose time goes backwards relative to the last kept row is a bad row.
    pub fn read_lenient<R: Read>(
        rdr: R,
        source_name: &str,
    ) -> Result<(Self, Vec<BadRow>), RecordingError> {
        let mut r = csv::ReaderBuilder::new()
            .has_headers(true)
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(rdr);
        let io = |e: csv::Error| RecordingError::Io {
            source_name: source_name.into(),
            msg: e.to_string(),
        };
        let names: Vec<String> = r
            .headers()
            .map_err(io)?
            .iter()
            .map(str::to_string)
            .collect();
        validate_header(&names).map_err(|msg| RecordingError::Header {
            source_name: source_name.into(),
            msg,
        })?;
        let t_idx = names.iter().position(|n| n == "t_s").expect("validated");
        let mut cols = vec![Vec::new(); names.len()];
        let mut lines = Vec::new();
        let mut bad = Vec::new();
        let mut last_t = f64::NEG_INFINITY;
        let mut row = vec![0.0; names.len()];
        for rec in r.records() {
            let rec = rec.map_err(io)?;
            let line = rec.position().map_or(0, |p| p.line());
            if rec.len() != names.len() {
                bad.push(BadRow {
                    line,
                    column: None,
                    reason: format!(
                        "{} fields, expected {} (one per header column)",
                        rec.len(),
                        names.len()
                    ),
                });
                continue;
            }
            let mut ok = true;
            for (j, cell) in rec.iter().enumerate() {
                match cell.parse::<f64>() {
                    Ok(v) if v.is_finite() => row[j] = v,
                    Ok(_) => {
                        bad.push(BadRow {
                            line,
                            column: Some(names[j].clone()),
                            reason: format!("`{cell}` is not a finite number"),
                        });
                        ok = false;
                        break;
                    }
                    Err(_) => {
                        bad.push(BadRow {
                            line,
                            column: Some(names[j].clone()),
                            reason: format!("`{cell}` is not a number"),
                        });
                        ok = false;
                        break;
                    }
                }
            }
            if !ok {
                continue;
            }
            if row[t_idx] < last_t {
                bad.push(BadRow {
                    line,
                    column: Some("t_s".into()),
                    reason: format!("time goes backwards ({} after {})", row[t_idx], last_t),
                });
                continue;
            }
            last_t = row[t_idx];
            for (c, v) in cols.iter_mut().zip(&row) {
                c.push(*v);
            }
            lines.push(line);
        }
        let contiguous = lines.iter().zip(2u64..).all(|(l, k)| *l == k);
        let rec = Recording {
            names,
            cols: cols.into_iter().map(Arc::from).collect(),
            lines: (!contiguous).then_some(lines),
        };
        Ok((rec, bad))
    }

    pub fn n_rows(&self) -> usize {
        self.cols.first().map_or(0, |c| c.len())
    }
    pub fn names(&self) -> &[String] {
        &self.names
    }
    /// Drop every column but `t_s` that `keep` rejects (its memory is freed unless a context
    /// still shares it): `diagnose` drops the error and sim columns once it has the residuals.
    pub fn retain_columns(&mut self, mut keep: impl FnMut(&str) -> bool) {
        let mask: Vec<bool> = self.names.iter().map(|n| n == "t_s" || keep(n)).collect();
        let mut m = mask.iter();
        self.cols
            .retain(|_| *m.next().expect("one flag per column"));
        let mut m = mask.iter();
        self.names
            .retain(|_| *m.next().expect("one flag per column"));
    }
    pub fn col(&self, name: &str) -> Option<&[f64]> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| &*self.cols[i])
    }
    /// The column `name`, shared with the recording (no copy).
    pub fn col_shared(&self, name: &str) -> Option<Arc<[f64]>> {
        self.names
            .iter()
            .position(|n| n == name)
            .map(|i| Arc::clone(&self.cols[i]))
    }
    pub fn line_of_row(&self, row: usize) -> u64 {
        match &self.lines {
            Some(l) => l[row],
            None => row as u64 + 2,
        }
    }
    pub fn t_s(&self) -> &[f64] {
        self.col("t_s").expect("t_s is validated at construction")
    }
    /// Axes with a nominal position column (`x_mm` …).
    pub fn position_axes(&self) -> Vec<char> {
        AXES.iter()
            .copied()
            .filter(|a| self.col(&format!("{a}_mm")).is_some())
            .collect()
    }
    /// Measured error signals present (`ex_um` …), in x, y, z order.
    pub fn error_signals(&self) -> Vec<String> {
        AXES.iter()
            .map(|a| format!("e{a}_um"))
            .filter(|n| self.col(n).is_some())
            .collect()
    }
    /// Temperature channels `T_<name>_C`.
    pub fn temperature_channels(&self) -> Vec<String> {
        self.names
            .iter()
            .filter(|n| ChannelKind::of(n) == ChannelKind::TemperatureC)
            .cloned()
            .collect()
    }
    /// Strain channels `strain_<name>_ue`.
    pub fn strain_channels(&self) -> Vec<String> {
        self.names
            .iter()
            .filter(|n| ChannelKind::of(n) == ChannelKind::StrainUe)
            .cloned()
            .collect()
    }
    /// Force (`F_<name>_N`) and strain (`strain_<name>_ue`) channels.
    pub fn load_channels(&self) -> Vec<String> {
        self.names
            .iter()
            .filter(|n| ChannelKind::of(n).is_load())
            .cloned()
            .collect()
    }
    /// Columns with no role in docs/recording-csv.md: candidate context signals (possibly decoys).
    pub fn other_channels(&self) -> Vec<String> {
        let known = self
            .temperature_channels()
            .into_iter()
            .chain(self.load_channels())
            .collect::<Vec<_>>();
        self.names
            .iter()
            .filter(|n| !known.contains(n) && column_role(n).is_none())
            .cloned()
            .collect()
    }

    /// Write the whole recording as docs/recording-csv.md CSV.
    pub fn write_csv<W: Write>(&self, w: W) -> Result<(), RecordingError> {
        let names: Vec<&str> = self.names.iter().map(String::as_str).collect();
        let mut wr = RecordingWriter::new(w, &names)?;
        let mut row = vec![0.0; names.len()];
        for i in 0..self.n_rows() {
            for (j, c) in self.cols.iter().enumerate() {
                row[j] = c[i];
            }
            wr.write_row(&row)?;
        }
        wr.flush()
    }
}

/// Fixed roles of docs/recording-csv.md (not temperatures/forces, which are matched by prefix/suffix).
fn column_role(name: &str) -> Option<&'static str> {
    match name {
        "t_s" => Some("time"),
        "x_mm" | "y_mm" | "z_mm" => Some("position"),
        "ex_um" | "ey_um" | "ez_um" => Some("error"),
        "sim_ex_um" | "sim_ey_um" | "sim_ez_um" => Some("simulation"),
        "rpm" => Some("spindle"),
        "tool_mm" => Some("tool"),
        "run" => Some("block"),
        _ => None,
    }
}

fn validate_header(names: &[String]) -> Result<(), String> {
    if !names.iter().any(|n| n == "t_s") {
        return Err(format!(
            "required column `t_s` missing (found: {})",
            names.join(", ")
        ));
    }
    if !names
        .iter()
        .any(|n| matches!(n.as_str(), "ex_um" | "ey_um" | "ez_um"))
    {
        return Err(
            "at least one measured error column (`ex_um`, `ey_um`, `ez_um`) is required".into(),
        );
    }
    for (i, n) in names.iter().enumerate() {
        if n.is_empty() {
            return Err(format!("column {} has an empty name", i + 1));
        }
        if names[..i].contains(n) {
            return Err(format!("column `{n}` appears twice"));
        }
    }
    Ok(())
}

/// Streaming writer of the recording CSV. Rejects a row with the wrong width, a non-finite value or
/// time going backwards, so the simulator and gateway cannot produce a file the reader would refuse.
#[derive(Debug)]
pub struct RecordingWriter<W: Write> {
    w: csv::Writer<W>,
    width: usize,
    t_idx: usize,
    last_t: f64,
    rows: u64,
    names: Vec<String>,
    /// One cell's text, reused: no allocation per row.
    cell: Vec<u8>,
}

impl<W: Write> RecordingWriter<W> {
    pub fn new(w: W, header: &[&str]) -> Result<Self, RecordingError> {
        let names: Vec<String> = header.iter().map(|s| s.to_string()).collect();
        validate_header(&names).map_err(|msg| RecordingError::Header {
            source_name: "recording writer".into(),
            msg,
        })?;
        let mut w = csv::Writer::from_writer(w);
        w.write_record(header)
            .map_err(|e| RecordingError::Write(e.to_string()))?;
        let t_idx = names.iter().position(|n| n == "t_s").expect("validated");
        Ok(RecordingWriter {
            w,
            width: names.len(),
            t_idx,
            last_t: f64::NEG_INFINITY,
            rows: 0,
            names,
            cell: Vec::with_capacity(32),
        })
    }

    pub fn write_row(&mut self, row: &[f64]) -> Result<(), RecordingError> {
        let line = self.rows + 2;
        if row.len() != self.width {
            return Err(RecordingError::Write(format!(
                "line {line}: {} values, expected {}",
                row.len(),
                self.width
            )));
        }
        if let Some(j) = row.iter().position(|v| !v.is_finite()) {
            return Err(RecordingError::Write(format!(
                "line {line}, column `{}`: {} is not finite",
                self.names[j], row[j]
            )));
        }
        if row[self.t_idx] < self.last_t {
            return Err(RecordingError::Write(format!(
                "line {line}: time goes backwards ({} after {})",
                row[self.t_idx], self.last_t
            )));
        }
        self.last_t = row[self.t_idx];
        // The shortest string that parses back to the same value (byte for byte `{}` on f64, without
        // `core::fmt`): lossless round trip.
        let err = |e: csv::Error| RecordingError::Write(e.to_string());
        for v in row {
            self.cell.clear();
            crate::decimal::push_shortest(&mut self.cell, *v);
            self.w.write_field(&self.cell).map_err(err)?;
        }
        self.w.write_record(None::<&[u8]>).map_err(err)?;
        self.rows += 1;
        Ok(())
    }

    pub fn flush(&mut self) -> Result<(), RecordingError> {
        self.w
            .flush()
            .map_err(|e| RecordingError::Write(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_lossless_and_roles_are_discovered() {
        let rec = Recording::from_columns(vec![
            ("t_s".into(), vec![0.0, 0.1, 0.1]),
            ("x_mm".into(), vec![0.0, 1.0 / 3.0, 2.5]),
            ("ex_um".into(), vec![1e-9, -2.25, 3.0]),
            ("sim_ex_um".into(), vec![0.0, 0.0, 0.0]),
            ("T_spindle_C".into(), vec![20.0, 20.1, 20.2]),
            ("F_cut_N".into(), vec![0.0, 5.0, 0.0]),
            ("strain_col_ue".into(), vec![0.0, 1.0, 0.0]),
            ("decoy_a".into(), vec![1.0, 2.0, 3.0]),
            ("run".into(), vec![0.0, 0.0, 1.0]),
        ])
        .unwrap();
        let mut buf = Vec::new();
        rec.write_csv(&mut buf).unwrap();
        let back = Recording::read_strict(&buf[..], "mem").unwrap();
        assert_eq!(back.col("x_mm").unwrap()[1], 1.0 / 3.0);
        assert_eq!(back.col("ex_um").unwrap()[0], 1e-9);
        assert_eq!(back.position_axes(), vec!['x']);
        assert_eq!(back.error_signals(), vec!["ex_um".to_string()]);
        assert_eq!(back.temperature_channels(), vec!["T_spindle_C".to_string()]);
        assert_eq!(
            back.load_channels(),
            vec!["F_cut_N".to_string(), "strain_col_ue".to_string()]
        );
        assert_eq!(back.other_channels(), vec!["decoy_a".to_string()]);
        assert_eq!(back.strain_channels(), vec!["strain_col_ue".to_string()]);
    }

    #[test]
    fn bad_rows_are_reported_with_line_and_column_never_dropped() {
        let csv = "t_s,x_mm,ex_um\n0,0,1\n1,abc,2\n2,1,NaN\n-1,2,3\n3,4\n4,5,6\n";
        let err = Recording::read_strict(csv.as_bytes(), "rec.csv")
            .unwrap_err()
            .to_string();
        assert!(err.contains("4 bad row(s)"), "{err}");
        assert!(
            err.contains("line 3, column `x_mm`: `abc` is not a number"),
            "{err}"
        );
        assert!(
            err.contains("line 4, column `ex_um`: `NaN` is not a finite number"),
            "{err}"
        );
        assert!(
            err.contains("line 5, column `t_s`: time goes backwards"),
            "{err}"
        );
        assert!(err.contains("line 6: 2 fields, expected 3"), "{err}");
        let (rec, bad) = Recording::read_lenient(csv.as_bytes(), "rec.csv").unwrap();
        assert_eq!(bad.len(), 4);
        assert_eq!(rec.n_rows(), 2);
        assert_eq!(rec.line_of_row(1), 7);
    }

    #[test]
    fn header_without_time_or_error_is_refused() {
        let e = Recording::read_strict("x_mm,ex_um\n1,2\n".as_bytes(), "a.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`t_s` missing"), "{e}");
        let e = Recording::read_strict("t_s,x_mm\n1,2\n".as_bytes(), "b.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("measured error column"), "{e}");
    }

    #[test]
    fn writer_refuses_nan_backwards_time_and_wrong_width() {
        let mut buf = Vec::new();
        let mut w = RecordingWriter::new(&mut buf, &["t_s", "ex_um"]).unwrap();
        w.write_row(&[1.0, 2.0]).unwrap();
        assert!(
            w.write_row(&[2.0, f64::NAN])
                .unwrap_err()
                .to_string()
                .contains("`ex_um`")
        );
        assert!(
            w.write_row(&[0.5, 1.0])
                .unwrap_err()
                .to_string()
                .contains("backwards")
        );
        assert!(
            w.write_row(&[3.0])
                .unwrap_err()
                .to_string()
                .contains("expected 2")
        );
    }
}
