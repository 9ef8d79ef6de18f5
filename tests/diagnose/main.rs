//! `retrocomp diagnose`'s tests: the seeds (Asad Ullah 2013), the CLI and its figures, drivers,
//! FL_THERMAL (the judge forward in time, leave-one-out, the thermal fit), motion, sensor faults and
//! the spectrum.
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test --test diagnose asadullah::`.

#[path = "../diagnose_sensor_support/mod.rs"]
mod diagnose_sensor_support;
#[path = "../diagnose_spectrum_support/mod.rs"]
mod diagnose_spectrum_support;
#[path = "../fl_support/mod.rs"]
mod fl_support;
#[path = "../figure_support/pixels.rs"]
mod pixels;

mod asadullah;
mod cli;
mod drivers;
mod fl_judge;
mod fl_loo;
mod fl_thermal;
mod motion;
mod sensor;
mod spectrum;
