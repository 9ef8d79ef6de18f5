// Shared helpers for the sim_* integration tests (included with `mod sim_common;`).

use hil_sim::SimConfig;

/// Parse a TOML config given inline.
pub(crate) fn cfg(toml: &str) -> SimConfig {
    SimConfig::from_toml_str(toml, None).expect("test config parses")
}

/// Read a recording CSV into (header, rows of cells).
pub(crate) fn read_csv(bytes: &[u8]) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_reader(bytes);
    let h = r.headers().unwrap().iter().map(String::from).collect();
    let rows = r
        .records()
        .map(|x| x.unwrap().iter().map(String::from).collect())
        .collect();
    (h, rows)
}

pub(crate) fn col(h: &[String], name: &str) -> usize {
    h.iter()
        .position(|c| c == name)
        .unwrap_or_else(|| panic!("column {name} missing in {h:?}"))
}
