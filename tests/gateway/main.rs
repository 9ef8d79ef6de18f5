//! The gateway's in-process tests: field config and its refusals (with file, line, key), the
//! engine, the model adapter, the safety guard on every sink (the client sink, the quadrature
//! injector, all sinks against one adversary), the HTTP endpoint, `check-config` on a field file,
//! the bus layer's decoders (proptests) and socketcand hub on loopback, the fuzzers' kept inputs,
//! and the paths that must allocate nothing (`no_alloc`: the cycle and the wire-to-words path;
//! `quadrature_trace`: the traced injector loop), counted per thread by the allocator below (other
//! tests run on other threads).
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test --test gateway config::`.

#[path = "../gateway_support/base_field.rs"]
mod base_field;
#[path = "../gateway_support/counting_alloc.rs"]
mod counting_alloc;
#[path = "../fuzz_checks/mod.rs"]
mod fuzz_checks;

#[global_allocator]
static GLOBAL: counting_alloc::Counting = counting_alloc::Counting;

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
mod no_alloc;
mod quadrature;
mod quadrature_trace;
mod safety;
mod sink_guard;
