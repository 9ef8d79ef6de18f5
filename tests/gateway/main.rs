//! The gateway's in-process tests: field config and its refusals (with file, line, key), the
//! engine, the model adapter, the safety guard on every sink (the client sink, the quadrature
//! injector, all sinks against one adversary), the HTTP endpoint, `check-config` on a field file,
//! the bus layer's decoders (proptests) and socketcand hub on loopback, and the fuzzers' kept
//! inputs.
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test --test gateway config::`.

#[path = "../gateway_support/base_field.rs"]
mod base_field;
#[path = "../fuzz_checks/mod.rs"]
mod fuzz_checks;

mod bus_hub;
mod bus_proptest;
mod check_config_field_cli;
mod config;
mod config_refusals;
mod engine;
mod fuzz_regressions;
mod guard_all_sinks;
mod http;
mod model_adapter;
mod quadrature;
mod safety;
mod sink_guard;
