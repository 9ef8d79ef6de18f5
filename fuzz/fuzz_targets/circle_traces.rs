//! Circular-test traces and the ISO 230-4 analysis.
//! The check lives in tests/fuzz_checks/mod.rs, shared with the regression suite
//! (tests/gateway/fuzz_regressions.rs runs every input kept in tests/fuzz_corpus/circle_traces/ through it).
#![no_main]

#[path = "../../tests/fuzz_checks/mod.rs"]
#[allow(dead_code, reason = "one target uses one check of the shared module")]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::circle_traces(data));
