//! ISG-style axis error CSV (ISG kernel / TwinCAT CNC volumetric compensation input): one row per
//! position of the moving axis K with its six error motions in ISO 230-1 names,
//! header `K EXK EYK EZK EAK EBK ECK` (e.g. `X EXX EYX EZX EAX EBX ECX`).
//!
//! Units here: K in mm, translations in µm, rotations in µrad (stated in a `#` comment line the
//! reader skips). Sign: error = actual − nominal; the CNC applies −error. Separators accepted on
//! read: comma, semicolon, or whitespace; written with single spaces as in the header above.

use std::fmt::Write as _;

use crate::import_error::{ErrorSink, ImportErrors};

/// The six error motions of one linear axis along its travel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AxisErrorMotions {
    /// Moving axis: 'X', 'Y' or 'Z'.
    pub axis: char,
    pub positions_mm: Vec<f64>,
    /// EXK, EYK, EZK in µm.
    pub translations_um: [Vec<f64>; 3],
    /// EAK, EBK, ECK in µrad.
    pub rotations_urad: [Vec<f64>; 3],
}

/// Column names for axis `k`.
pub fn header(k: char) -> [String; 7] {
    [
        k.to_string(),
        format!("EX{k}"),
        format!("EY{k}"),
        format!("EZ{k}"),
        format!("EA{k}"),
        format!("EB{k}"),
        format!("EC{k}"),
    ]
}

pub fn write_isg(m: &AxisErrorMotions) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# units: {} mm; EX{0} EY{0} EZ{0} µm; EA{0} EB{0} EC{0} µrad; error = actual - nominal",
        m.axis
    );
    let _ = writeln!(s, "{}", header(m.axis).join(" "));
    for i in 0..m.positions_mm.len() {
        let _ = write!(s, "{:.4}", m.positions_mm[i]);
        for c in m.translations_um.iter().chain(&m.rotations_urad) {
            let _ = write!(s, " {:.4}", c[i]);
        }
        s.push('\n');
    }
    s
}

pub fn read_isg(file: &str, text: &str) -> Result<AxisErrorMotions, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut out = AxisErrorMotions::default();
    let mut names: Option<[String; 7]> = None;
    let split = |l: &str| -> Vec<String> {
        l.split([',', ';', ' ', '\t'])
            .filter(|w| !w.is_empty())
            .map(str::to_string)
            .collect()
    };
    for (i, raw) in text.lines().enumerate() {
        let line = i as u64 + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            continue;
        }
        let f = split(body);
        let Some(h) = &names else {
            let k = f.first().and_then(|w| w.chars().next()).unwrap_or('?');
            let expect = header(k);
            if !['X', 'Y', 'Z'].contains(&k)
                || f.len() != 7
                || f.iter().zip(&expect).any(|(a, b)| a != b)
            {
                sink.push(
                    line,
                    None,
                    format!(
                        "expected header `{}` (K = X, Y or Z), found `{body}`",
                        header('X').join(" ")
                    ),
                );
                return sink.finish(out);
            }
            out.axis = k;
            names = Some(expect);
            continue;
        };
        if f.len() != 7 {
            sink.push(line, None, format!("expected 7 fields, found {}", f.len()));
            continue;
        }
        let vals: Vec<Option<f64>> = f
            .iter()
            .zip(h.iter())
            .map(|(w, n)| sink.parse_f64(line, n, w))
            .collect();
        if vals.iter().all(Option::is_some) {
            let v: Vec<f64> = vals.into_iter().flatten().collect();
            if let Some(&prev) = out.positions_mm.last()
                && v[0] <= prev
            {
                sink.push(
                    line,
                    Some(&h[0]),
                    format!("positions must increase: {} follows {prev}", v[0]),
                );
                continue;
            }
            out.positions_mm.push(v[0]);
            for c in 0..3 {
                out.translations_um[c].push(v[1 + c]);
                out.rotations_urad[c].push(v[4 + c]);
            }
        }
    }
    if names.is_none() {
        sink.push(0, None, "no header line");
    } else if out.positions_mm.is_empty() && sink.is_empty() {
        sink.push(0, None, "no data rows");
    }
    sink.finish(out)
}
