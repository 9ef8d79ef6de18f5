//! The offline toolkit's tests: ISO 230-2, circular tests, fitting (FL_THERMAL compensation,
//! compensation terms), controller-table export, NC rewriting, identify (hole plates, the lead
//! wave), the HTML/PDF reports, `eval` streaming, and the CLI's handling of bad rows.
//!
//! One test binary for these files (each was its own binary, every one linking the whole crate);
//! a test is named `<module>::<test>`, e.g. `cargo test --test analysis circular::`.

#[path = "../fl_support/mod.rs"]
mod fl_support;
#[path = "../gateway_support/hil_sim.rs"]
mod hil_sim;
#[path = "../identify_support/cli.rs"]
mod identify_support;
#[path = "../figure_support/pixels.rs"]
mod pixels;
#[path = "../analysis_support/runs.rs"]
mod runs;

mod circular;
mod cli;
mod compensation_terms;
mod eval_streaming;
mod export;
mod fit;
mod fl_compensation;
mod identify_cli;
mod identify_contracts;
mod identify_lead_cli;
mod iso230_2;
mod nc;
mod report_html_pdf;
mod skip_bad_rows_cli;
