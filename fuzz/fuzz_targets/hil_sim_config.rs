//! hil-sim's config (`hil-sim run/serve --config`): a config or an error, never a panic.
//! Found inputs are replayed by hil-sim/tests/sim/fuzz_regressions.rs (hil-sim/tests/fuzz_corpus/).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = hil_sim::SimConfig::from_toml_str(text, None);
    }
});
