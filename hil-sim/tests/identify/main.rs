//! Artefact identification against hil-sim's truth: hole plates (Spaan 1995), the probe's range,
//! the lead-screw wave, and the VMC's lead error.
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test -p hil-sim --test identify lead_wave::`.

mod lead_wave;
mod probe_range;
mod truth;
mod vmc_lead;
