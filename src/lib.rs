//! retrocomp's demo application (`retrocomp demo`): a simulated mill, three runs, the figures and the
//! report; and the DNC drip-feed (`retrocomp dnc`, `dnc/`), which joins the gateway's guard and
//! model to the toolkit's NC rewriter. The binary (`src/main.rs`, the command line in `src/cli/`) is the only other part of
//! this package; the gateway, the toolkit and the model are the crates under `crates/`.

pub mod demo;
pub mod dnc;
