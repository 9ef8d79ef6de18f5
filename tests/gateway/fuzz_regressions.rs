//! Inputs the fuzzers found (crashes, after the fix) and a few seeds per target, replayed through
//! the same checks the cargo-fuzz targets run (tests/fuzz_checks/mod.rs), so a regression fails the
//! normal suite. Inputs live in tests/fuzz_corpus/<target>/, one file each; how they were found and
//! how to fuzz further: docs/fuzzing.md.

use crate::fuzz_checks;

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

/// The plane-model target parses in memory (no file per input): its seed must load through that
/// path and give the same model as `retrocomp nc --plane-model`'s file loader on the same tables.
#[test]
fn plane_model_target_parses_like_the_file_loader() {
    use retrocomp_analysis::nc::ErrorFunction;
    use retrocomp_analysis::table::Direction;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let seed = std::fs::read(root.join("tests/fuzz_corpus/plane_model/asadullah")).unwrap();
    let mem = fuzz_checks::plane_model_parse(&seed).expect("the seed loads from memory");
    let text = String::from_utf8(seed).unwrap();
    let parts: Vec<&str> = text.splitn(3, "\n%%\n").collect();
    let dir = tempfile::tempdir().unwrap();
    for (name, body) in ["plane.toml", "a.csv", "b.csv"].iter().zip(&parts) {
        std::fs::write(dir.path().join(name), body).unwrap();
    }
    let file =
        retrocomp_analysis::plane_model::load_plane_model(&dir.path().join("plane.toml")).unwrap();
    let mut compared = 0;
    for z in [0.0, 40.0, 170.0] {
        for x in [0.0, 20.0, 85.0] {
            for d in [Direction::Forward, Direction::Reverse] {
                let a = mem.error_um([x, 0.0, z], [d; 3]);
                assert_eq!(a, file.error_um([x, 0.0, z], [d; 3]), "x {x} z {z}");
                compared += usize::from(a.is_some());
            }
        }
    }
    assert!(
        compared > 0,
        "the model must be defined somewhere on the grid"
    );
}

/// The modbus_server target skips the PDUs that panic tokio-modbus 0.17's request decoder
/// (tests/fuzz_checks/net.rs, `panics_tokio_modbus`): an FC16 register count of 0x8000 or more
/// (`quantity * 2` in u16: a panic where overflow is checked, as in this test build; wrapped and
/// refused in a release build) and an FC15 with more coils than data bytes (a panic in every
/// build). When a tokio-modbus release stops panicking on one, this fails: drop its skip.
#[test]
fn tokio_modbus_still_panics_on_the_skipped_requests() {
    use tokio_modbus::bytes::Bytes;
    use tokio_modbus::prelude::Request;
    let decode = |pdu: &[u8]| {
        assert!(fuzz_checks::net::panics_tokio_modbus(pdu), "{pdu:02x?}");
        let pdu = Bytes::copy_from_slice(pdu);
        std::panic::catch_unwind(|| Request::try_from(pdu).is_ok())
    };
    // The kept input's first PDU (length-prefixed): FC16 at 10, quantity 0xAA05.
    let kept = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fuzz_corpus/modbus_server/crash-fc16-quantity-0xaa05"),
    )
    .unwrap();
    let fc16 = decode(&kept[1..=usize::from(kept[0])]);
    if cfg!(debug_assertions) {
        assert!(fc16.is_err(), "FC16 0xAA05 decodes without a panic now");
    } else {
        assert_eq!(fc16.ok(), Some(false), "a release build refuses it");
    }
    // FC15 at 0: 9 coils in 1 data byte.
    let fc15 = decode(&[0x0F, 0, 0, 0, 9, 1, 0xFF]);
    assert!(
        fc15.is_err(),
        "FC15 with 9 coils in 1 byte decodes without a panic now"
    );
    // What the skip lets through still decodes (or is refused) without a panic.
    for ok in [
        &[0x0F, 0, 0, 0, 8, 1, 0xFF][..],
        &[0x10, 0, 0, 0, 1, 2, 0, 7],
    ] {
        assert!(!fuzz_checks::net::panics_tokio_modbus(ok));
        assert!(Request::try_from(Bytes::copy_from_slice(ok)).is_ok());
    }
}
