//! The hil-sim binary for binary-level gateway tests: (re)built next to retrocomp's with the same
//! profile, features and target dir, so it is never stale when only this crate's tests were built.
//! Included by `analysis`, `real_peers` and the `fleet_processes` bench, each using part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub(crate) fn hil_sim_next_to_retrocomp() -> PathBuf {
    hil_sim_bin("hil-sim")
}

/// hil-sim's `faulty_box`: `retrocomp run` with one injected fault (the supervision tests).
pub(crate) fn faulty_box_next_to_retrocomp() -> PathBuf {
    hil_sim_bin("faulty_box")
}

/// hil-sim's `fleet_load`: simulated boxes or a fleet host (the multi-process fleet load test).
pub(crate) fn fleet_load_next_to_retrocomp() -> PathBuf {
    hil_sim_bin("fleet_load")
}

/// The binary `name` of the hil-sim package, built as [`hil_sim_next_to_retrocomp`] says.
fn hil_sim_bin(name: &str) -> PathBuf {
    let exe = Path::new(env!("CARGO_BIN_EXE_retrocomp"));
    let bin_dir = exe.parent().unwrap();
    let target_dir = bin_dir.parent().unwrap();
    let mut cmd = Command::new(env!("CARGO"));
    cmd.env("CARGO_TARGET_DIR", target_dir)
        .current_dir(env!("CARGO_MANIFEST_DIR"));
    // What cargo sets for this test process only. ring's build script reruns when
    // CARGO_MANIFEST_DIR changes, so passing these on made the nested cargo rebuild ring, rustls
    // and everything above them, and the next plain `cargo test` rebuild them back.
    for (key, _) in std::env::vars_os() {
        let key = key.to_string_lossy();
        if key.starts_with("CARGO_PKG_")
            || [
                "CARGO_MANIFEST_DIR",
                "CARGO_MANIFEST_PATH",
                "CARGO_CRATE_NAME",
                "CARGO_PRIMARY_PACKAGE",
            ]
            .contains(&key.as_ref())
        {
            cmd.env_remove(key.as_ref());
        }
    }
    if bin_dir.file_name().is_some_and(|n| n == "release") {
        cmd.args(["build", "-q", "--release", "-p", "hil-sim", "--bins"]);
    } else {
        // Exactly the build `cargo test --workspace` does (it builds hil-sim for hil-sim's own
        // integration tests), so after that command this is a no-op (≈ 0.3 s) and reuses its
        // hil-sim. `build -p hil-sim` resolves features for hil-sim alone (no dev-dependencies), so
        // it rebuilt rand, nalgebra, async-opcua and retrocomp a second time: ≈ 2 min and ≈ 1 GB of
        // target/ per CI run. After a partial build this builds every test target once.
        cmd.args(["test", "-q", "--workspace", "--no-run"]);
    }
    let st = cmd.status().expect("running cargo to build hil-sim");
    assert!(st.success(), "cargo build -p hil-sim failed: {st}");
    let p = bin_dir.join(name);
    assert!(p.is_file(), "{} missing after the build", p.display());
    p
}
