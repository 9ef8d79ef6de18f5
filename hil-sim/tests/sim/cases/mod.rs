//! `hil-sim gen-cases`: the concealed-effect benchmark families, their manifests and model files,
//! the hard families, sensor faults, thermal channel naming, two effects at once, and the null walks.
//!
//! A module of hil-sim's in-process test binary; a test is named `cases::<module>::<test>`, e.g.
//! `cargo test -p hil-sim --test sim cases::benchmark::`.

mod benchmark;
mod cli;
mod forward_drop;
mod hard_benchmark;
mod hard_families;
mod model_out;
mod sensor_faults;
mod thermal_naming;
mod two_effects;
mod walk_nulls;
