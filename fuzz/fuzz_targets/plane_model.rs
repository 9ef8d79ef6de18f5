//! The Z–X plane model loader (`retrocomp nc --plane-model`) and its evaluation.
//! The check lives in tests/fuzz_checks/mod.rs, shared with the regression suite
//! (tests/gateway/fuzz_regressions.rs runs every input kept in tests/fuzz_corpus/plane_model/ through it).
#![no_main]

#[path = "../../tests/fuzz_checks/mod.rs"]
#[allow(dead_code, reason = "one target uses one check of the shared module")]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::plane_model(data));
