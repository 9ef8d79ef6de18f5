//! Inputs the fuzzers found (crashes, after the fix) and a few seeds per target, replayed through
//! the same checks the cargo-fuzz targets run (tests/fuzz_checks/mod.rs), so a regression fails the
//! normal suite. Inputs live in tests/fuzz_corpus/<target>/, one file each; how they were found and
//! how to fuzz further: README, Fuzzing.

mod fuzz_checks;

use std::path::Path;

#[test]
fn every_kept_input_passes_its_check() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_corpus");
    let mut ran = Vec::new();
    for (target, check) in fuzz_checks::TARGETS {
        let dir = root.join(target);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut files: Vec<_> = entries.map(|e| e.unwrap().path()).collect();
        files.sort();
        for f in files {
            let data = std::fs::read(&f).unwrap();
            let outcome = std::panic::catch_unwind(|| check(&data));
            assert!(outcome.is_ok(), "{target}: {} fails its check", f.display());
            ran.push(format!(
                "{target}/{}",
                f.file_name().unwrap().to_string_lossy()
            ));
        }
    }
    // Every folder holds at least one input, and each folder names a target.
    for d in std::fs::read_dir(&root).unwrap() {
        let name = d.unwrap().file_name().to_string_lossy().into_owned();
        assert!(
            fuzz_checks::TARGETS.iter().any(|(t, _)| *t == name),
            "tests/fuzz_corpus/{name} is not a fuzz target"
        );
        assert!(
            ran.iter().any(|r| r.starts_with(&format!("{name}/"))),
            "{name} is empty"
        );
    }
    eprintln!("{} kept inputs replayed", ran.len());
}
