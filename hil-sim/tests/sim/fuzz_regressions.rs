//! hil-sim's side of the fuzz regressions (see tests/gateway/fuzz_regressions.rs at the root): every input
//! kept in hil-sim/tests/fuzz_corpus/<target>/ goes through the check of the cargo-fuzz target of
//! that name (fuzz/fuzz_targets/hil_sim_gcode.rs, hil_sim_config.rs): an error is fine, a panic is not.

use std::path::Path;

fn replay(target: &str, check: impl Fn(&str)) -> usize {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_corpus")
        .join(target);
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = e.unwrap().path();
        let bytes = std::fs::read(&path).unwrap();
        // The fuzz targets only look at valid UTF-8.
        if let Ok(text) = std::str::from_utf8(&bytes) {
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| check(text)));
            assert!(outcome.is_ok(), "{target}: {} panics", path.display());
        }
        n += 1;
    }
    assert!(n > 0, "{} holds no input", dir.display());
    n
}

#[test]
fn gcode_inputs_give_blocks_or_errors() {
    replay("hil_sim_gcode", |t| {
        let _ = hil_sim::controller::gcode::parse(t, [0.0, 0.0, 5.0], 10_000.0);
    });
}

#[test]
fn config_inputs_give_configs_or_errors() {
    replay("hil_sim_config", |t| {
        let _ = hil_sim::SimConfig::from_toml_str(t, None);
    });
}

/// docs/walkthrough.md's simulator side loads as written (its truth model path is relative to it).
#[test]
fn walkthrough_sim_config_loads() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/walkthrough/sim.toml");
    let cfg = hil_sim::SimConfig::from_toml_path(&p).unwrap_or_else(|e| panic!("{e:#}"));
    let truth = cfg.truth.model_path.as_ref().expect("[truth] model_path");
    assert!(truth.is_file(), "{}", truth.display());
}
