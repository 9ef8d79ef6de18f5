//! DNC drip-feed with live offsets (Spaan 1995, Ch7 stage 2): the box sits in the RS-232 cable
//! between a program source (a file, or the shop's DNC sender on a second port or a TCP socket)
//! and a controller that takes programs only this way, and adds to each motion block, as it is
//! sent, the correction the live model has for the block's end point, through the one last-step
//! guard (`sinks/guard.rs`).
//!
//! - `retrocomp_gateway::sinks::dnc::config`: the `[dnc]` section of the field config (link
//!   settings, the control's line length and buffer).
//! - `live`: the correction of one block (model at the end point, guard: clamp and per-block cap).
//! - `drift`: the correction predicted for when a block runs (slope at the present, bounded).
//! - `lead`: the estimate of the control's buffer that holds a block until it is due.
//! - `core`: the sans-IO drip-feed (flow control, stall fault, line-length refusal, resume, log).
//! - `faults`: the transfer's faults (start and clear) and its status for `/status`, `/metrics`.
//! - `shell`: the async shell on tokio-serial / TCP (`retrocomp dnc`).
//!
//! Signs and units: corrections µm, = −error; a block's end point is nominal + correction (mm).

pub(crate) mod core;
pub(crate) mod drift;
pub(crate) mod faults;
pub(crate) mod lead;
pub(crate) mod live;
pub(crate) mod shell;

pub use self::core::{CoreConfig, DncCore, DncError, SentBlock, StallEdge};
pub use drift::DriftConfig;
pub use faults::StatusTx;
pub use lead::LeadConfig;
pub use live::{Applied, CorrectionAt, EngineAtPoint, LiveCorrections};
pub use shell::{DncIo, DncSummary, ProgramSource, run_dnc};

#[cfg(test)]
mod drift_tests;
#[cfg(test)]
mod lead_tests;
#[cfg(test)]
mod tests;
