//! LinuxCNC screw-compensation files (`[JOINT_n] COMP_FILE`, `COMP_FILE_TYPE`): one triplet per line,
//! `nominal forward reverse`, in machine units (mm here), nominal strictly increasing, at most 256
//! triplets per joint (`EMCMOT_COMP_SIZE`).
//!
//! - Type 0: forward/reverse are the **actual** positions reached when `nominal` is commanded
//!   moving in the positive / negative direction: `nominal + error`.
//! - Type 1: forward/reverse are the differences `nominal − actual` = **correction** = −error.
//!
//! LinuxCNC interpolates linearly between triplets, like [`BidirectionalTable::error_um`].

use std::fmt::Write as _;

use crate::import_error::{ErrorSink, ImportErrors};
use crate::table::BidirectionalTable;

/// LinuxCNC's per-joint limit.
pub const MAX_TRIPLETS: usize = 256;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CompFileType {
    /// Absolute actual positions.
    Actual = 0,
    /// Offsets nominal − actual.
    Offset = 1,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LinuxCncError {
    #[error("{n} triplets exceed LinuxCNC's limit of {MAX_TRIPLETS} per joint")]
    TooMany { n: usize },
}

/// Writes a comp file. Values are printed with 6 decimals (1 nm), below any controller resolution.
pub fn write_comp(table: &BidirectionalTable, kind: CompFileType) -> Result<String, LinuxCncError> {
    if table.len() > MAX_TRIPLETS {
        return Err(LinuxCncError::TooMany { n: table.len() });
    }
    let mut s = String::new();
    for i in 0..table.len() {
        let p = table.positions_mm[i];
        let (f, r) = (table.forward_um[i] / 1000.0, table.reverse_um[i] / 1000.0);
        let (a, b) = match kind {
            CompFileType::Actual => (p + f, p + r),
            CompFileType::Offset => (-f, -r),
        };
        let _ = writeln!(s, "{p:.6} {a:.6} {b:.6}");
    }
    Ok(s)
}

/// Reads a comp file of the given type. `#` starts a comment. Every malformed line is reported.
pub fn read_comp(
    file: &str,
    text: &str,
    kind: CompFileType,
) -> Result<BidirectionalTable, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let (mut pos, mut fwd, mut rev) = (Vec::new(), Vec::new(), Vec::new());
    let mut last_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let line = i as u64 + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            continue;
        }
        let f: Vec<&str> = body.split_whitespace().collect();
        if f.len() != 3 {
            sink.push(
                line,
                None,
                format!(
                    "expected 3 numbers `nominal forward reverse`, found {}",
                    f.len()
                ),
            );
            continue;
        }
        let n = sink.parse_f64(line, "nominal", f[0]);
        let a = sink.parse_f64(line, "forward", f[1]);
        let b = sink.parse_f64(line, "reverse", f[2]);
        let (Some(n), Some(a), Some(b)) = (n, a, b) else {
            continue;
        };
        if let Some(&prev) = pos.last()
            && n <= prev
        {
            sink.push(
                line,
                Some("nominal"),
                format!("nominal positions must increase: {n} follows {prev} (line {last_line})"),
            );
            continue;
        }
        let (e_f, e_r) = match kind {
            CompFileType::Actual => (a - n, b - n),
            CompFileType::Offset => (-a, -b),
        };
        pos.push(n);
        fwd.push(e_f * 1000.0);
        rev.push(e_r * 1000.0);
        last_line = line;
    }
    if pos.is_empty() && sink.is_empty() {
        sink.push(0, None, "no triplets");
    }
    if pos.len() > MAX_TRIPLETS {
        sink.push(
            0,
            None,
            format!(
                "{} triplets exceed LinuxCNC's limit of {MAX_TRIPLETS}",
                pos.len()
            ),
        );
    }
    let table = BidirectionalTable {
        positions_mm: pos,
        forward_um: fwd,
        reverse_um: rev,
    };
    sink.finish(table)
}
