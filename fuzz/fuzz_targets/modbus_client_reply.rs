//! A Modbus client's read against a peer answering with fuzzed bytes (tokio-modbus reply framing, our length check, register decoding).
//! The check lives in tests/fuzz_checks/net.rs, shared with the regression suite
//! (tests/gateway/fuzz_regressions.rs runs every input kept in tests/fuzz_corpus/modbus_client_reply/ through it).
#![no_main]

#[path = "../../tests/fuzz_checks/mod.rs"]
#[allow(dead_code, reason = "one target uses one check of the shared module")]
mod checks;

libfuzzer_sys::fuzz_target!(|data: &[u8]| checks::modbus_client_reply(data));
