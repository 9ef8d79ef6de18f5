//! Small I/O helpers for the toolkit commands (reading inputs with their path in errors, writing
//! outputs, the simple bidirectional-table CSV).

use std::path::Path;

use anyhow::Context;
use retrocomp_analysis::laser_import::parse_table_columns;
use retrocomp_analysis::table::BidirectionalTable;

pub(crate) fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

pub(crate) fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes `text` to `out` or stdout.
pub(crate) fn emit(out: Option<&Path>, text: &str) -> anyhow::Result<()> {
    match out {
        Some(p) => write(p, text),
        None => {
            print!("{text}");
            Ok(())
        }
    }
}

/// The toolkit's table CSV: `position_mm,forward_um,reverse_um` (error = actual − nominal).
pub(crate) fn read_table(path: &Path) -> anyhow::Result<BidirectionalTable> {
    let text = read(path)?;
    Ok(parse_table_columns(
        &path.display().to_string(),
        &text,
        "position_mm",
        "forward_um",
        "reverse_um",
        1.0,
    )?)
}

pub(crate) fn table_csv(t: &BidirectionalTable) -> String {
    let mut s = String::from(
        "# error = actual - nominal; forward = approached in +, reverse = approached in -\nposition_mm,forward_um,reverse_um\n",
    );
    for i in 0..t.len() {
        s.push_str(&format!(
            "{},{:.4},{:.4}\n",
            t.positions_mm[i], t.forward_um[i], t.reverse_um[i]
        ));
    }
    s
}
