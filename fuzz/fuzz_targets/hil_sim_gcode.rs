//! hil-sim's G-code parser: a block list or an error naming the line, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = hil_sim::controller::gcode::parse(text, [0.0, 0.0, 5.0], 10_000.0);
    }
});
