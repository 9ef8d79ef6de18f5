//! The field TOML loader: arbitrary text must give a config or an error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = retrocomp::bus::config::parse(text, "fuzz.toml");
    }
});
