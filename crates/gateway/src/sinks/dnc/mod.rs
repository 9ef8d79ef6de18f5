//! The `[dnc]` section of the field config (`config`): the serial link to a controller's DNC
//! input. The drip-feed itself (it needs the NC rewriter of the offline toolkit, which the
//! appliance's gateway does not build) is `src/dnc/` of the `retrocomp` package (`retrocomp dnc`).

pub(crate) mod config;

pub use config::{DncSection, Flow, LineEnd};
