//! Minimal reader of the recording CSV (DESIGN §4) for fitting: every column must be numeric,
//! `t_s` must exist and never decrease. Each bad cell is reported with line and column; nothing is
//! dropped. (`diagnose` has its own reader; this one only needs columns by name.)

use std::collections::BTreeMap;

use crate::analysis::import_error::{ErrorSink, ImportErrors};

#[derive(Debug, Clone, PartialEq, Default)]
pub struct Recording {
    /// Column names in file order.
    pub names: Vec<String>,
    pub columns: BTreeMap<String, Vec<f64>>,
}

impl Recording {
    pub fn get(&self, name: &str) -> Option<&Vec<f64>> {
        self.columns.get(name)
    }
    pub fn len(&self) -> usize {
        self.columns.get("t_s").map_or(0, Vec::len)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Temperature columns `T_<name>_C`.
    pub fn temperatures(&self) -> Vec<&str> {
        self.names
            .iter()
            .filter(|n| n.starts_with("T_") && n.ends_with("_C"))
            .map(String::as_str)
            .collect()
    }
    /// Strain columns `strain_<name>_ue`.
    pub fn strains(&self) -> Vec<&str> {
        self.names
            .iter()
            .filter(|n| n.starts_with("strain_") && n.ends_with("_ue"))
            .map(String::as_str)
            .collect()
    }
}

pub fn parse_recording(file: &str, text: &str) -> Result<Recording, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(true)
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .flexible(true)
        .from_reader(text.as_bytes());
    let headers = match rdr.headers() {
        Ok(h) => h.clone(),
        Err(e) => {
            sink.push(1, None, format!("cannot read the header: {e}"));
            return sink.finish(Recording::default());
        }
    };
    let header_line = rdr.position().line();
    let names: Vec<String> = headers.iter().map(str::to_string).collect();
    if !names.iter().any(|n| n == "t_s") {
        sink.push(header_line, Some("t_s"), "required column is missing");
        return sink.finish(Recording::default());
    }
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let ti = names.iter().position(|n| n == "t_s").expect("checked");
    let mut last_t = f64::NEG_INFINITY;
    for rec in rdr.records() {
        let rec = match rec {
            Ok(r) => r,
            Err(e) => {
                sink.push(
                    e.position().map_or(0, |p| p.line()),
                    None,
                    format!("unreadable row: {e}"),
                );
                continue;
            }
        };
        let line = rec.position().map_or(0, |p| p.line());
        if rec.len() != names.len() {
            sink.push(
                line,
                None,
                format!("expected {} fields, found {}", names.len(), rec.len()),
            );
            continue;
        }
        let vals: Vec<Option<f64>> = names
            .iter()
            .enumerate()
            .map(|(j, n)| sink.parse_f64(line, n, &rec[j]))
            .collect();
        if let Some(t) = vals[ti] {
            if t < last_t {
                sink.push(
                    line,
                    Some("t_s"),
                    format!("time goes backwards: {t} after {last_t}"),
                );
            }
            last_t = t;
        }
        for (j, v) in vals.into_iter().enumerate() {
            cols[j].push(v.unwrap_or(f64::NAN));
        }
    }
    if cols[ti].is_empty() && sink.is_empty() {
        sink.push(header_line, None, "no data rows");
    }
    let columns = names.iter().cloned().zip(cols).collect();
    sink.finish(Recording { names, columns })
}
