//! retrocomp's demo application (`retrocomp demo`): a simulated mill, three runs, the figures and the
//! report; and the DNC drip-feed (`retrocomp dnc`, `dnc/`), which joins the gateway's guard and
//! model to the toolkit's NC rewriter. The binary (`src/main.rs`, the command line in `src/cli/`) is the only other part of
//! this package; the gateway, the toolkit and the model are the crates under `crates/`.
//!
//! Every numeric conversion that could truncate, wrap or lose a sign is a `try_from`, or an `as`
//! after a clamp or check with its reason beside it (these lints are errors in CI).
#![warn(
    unreachable_pub,
    unnameable_types,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]
#![cfg_attr(
    test,
    allow(
        clippy::float_cmp,
        reason = "tests assert values that are exact in binary or parsed from the same decimal text"
    )
)]

pub mod demo;
pub mod dnc;
