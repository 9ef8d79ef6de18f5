//! The machine model TOML, with the write → read round trip.
//! The check lives in tests/fuzz_checks/mod.rs, shared with the regression suite
//! (tests/gateway/fuzz_regressions.rs runs every input kept in tests/fuzz_corpus/model_toml/ through it).
#![no_main]

#[path = "../../tests/fuzz_checks/mod.rs"]
#[allow(dead_code, reason = "one target uses one check of the shared module")]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::model_toml(data));
