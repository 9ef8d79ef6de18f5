//! What the `retrocomp identify` end-to-end tests share: the binary, a command's stdout (or a
//! failure with its stderr), the CSVs `hil-sim artefacts` wrote into a folder, sorted, and
//! `check-config` on a written model.

use std::path::{Path, PathBuf};
use std::process::Command;

pub(crate) fn retrocomp() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

pub(crate) fn csvs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .collect();
    v.sort();
    v
}

pub(crate) fn ok(out: &std::process::Output, what: &str) -> String {
    assert!(
        out.status.success(),
        "{what} failed: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout.clone()).unwrap()
}

/// `retrocomp check-config` loads the identified model.
pub(crate) fn check_config(model: &Path) {
    ok(
        &retrocomp().arg("check-config").arg(model).output().unwrap(),
        "check-config on the identified model",
    );
}
