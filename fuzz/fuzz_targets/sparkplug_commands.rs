//! The edge node's decoders of what the broker delivers: NCMD (rebirth request) and a host's STATE.
//! The check lives in tests/fuzz_checks/net.rs, shared with the regression suite
//! (tests/gateway/fuzz_regressions.rs runs every input kept in tests/fuzz_corpus/sparkplug_commands/ through it).
#![no_main]

#[path = "../../tests/fuzz_checks/mod.rs"]
#[allow(dead_code, reason = "one target uses one check of the shared module")]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::sparkplug_commands(data));
