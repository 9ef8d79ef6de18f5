//! The simulated machine in virtual time: determinism, injected faults, the oracle, Spaan's
//! machine, the truth it records, the toolkit on its artefacts (circle, fit), the closed-loop harness
//! (faults, quadrature, RTU, stop, watchdog), the server mode's guard, the fuzzers' kept inputs, `gen-cases`' benchmark
//! families (`cases::`) and artefact identification against the truth (`identify::`).
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test -p hil-sim --test sim determinism::`.

#[path = "../closed_loop_support/mod.rs"]
mod closed_loop_support;
#[path = "../sim_common/mod.rs"]
mod sim_common;

mod cases;
mod closed_loop_faults;
mod closed_loop_quadrature;
mod closed_loop_rtu;
mod closed_loop_served;
mod closed_loop_stop;
mod closed_loop_watchdog;
mod determinism;
mod faults;
mod fuzz_regressions;
mod identify;
mod oracle;
mod served_guard;
mod spaan;
mod toolkit_circle;
mod toolkit_fit;
mod truth;
