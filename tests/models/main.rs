//! The volumetric error model's tests: evaluation against the seeds (Asad Ullah 2013), broken
//! models refused, the kinematic chain, the `models` CLI, the fast path against the reference
//! evaluator, lag state, TOML round trip, and the sign conventions.
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test --test models asadullah::`.

mod asadullah;
mod broken;
mod chain;
mod cli;
mod fastpath;
mod lag_state;
mod roundtrip;
mod signs;
