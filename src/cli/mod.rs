//! Subcommand implementations. `main.rs` only holds the clap enum and the dispatch.

pub mod circle;
pub mod export;
pub mod import;
pub mod iso230_2;
pub mod nc;
pub mod util;
