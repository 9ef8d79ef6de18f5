//! Artefact identification against hil-sim's truth: hole plates (Spaan 1995), the probe's range,
//! the lead-screw wave, and the VMC's lead error.
//!
//! A module of hil-sim's in-process test binary; a test is named `identify::<module>::<test>`,
//! e.g. `cargo test -p hil-sim --test sim identify::lead_wave::`.

mod lead_wave;
mod probe_range;
mod truth;
mod vmc_lead;
