//! The hil-sim binary for binary-level gateway tests: (re)built next to retrocomp's with the same
//! profile and target dir, so it is never stale when only this crate's tests were built.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

pub(crate) fn hil_sim_next_to_retrocomp() -> PathBuf {
    let exe = Path::new(env!("CARGO_BIN_EXE_retrocomp"));
    let bin_dir = exe.parent().unwrap();
    let target_dir = bin_dir.parent().unwrap();
    let mut cmd = Command::new(env!("CARGO"));
    cmd.args(["build", "-q", "-p", "hil-sim", "--bin", "hil-sim"])
        .env("CARGO_TARGET_DIR", target_dir)
        .current_dir(env!("CARGO_MANIFEST_DIR"));
    // Same profile as this test's build, so the retrocomp library and every dependency are reused.
    if bin_dir.file_name().is_some_and(|n| n == "release") {
        cmd.arg("--release");
    } else {
        cmd.args(["--profile", "test"]);
    }
    let st = cmd.status().expect("running cargo to build hil-sim");
    assert!(st.success(), "cargo build -p hil-sim failed: {st}");
    let p = bin_dir.join("hil-sim");
    assert!(p.is_file(), "{} missing after the build", p.display());
    p
}
