//! retrocomp's bus crate. Field-bus sources: sans-IO codecs (socketcand, CANopen, Modbus register decoding, serial line
//! formats) with thin async I/O shells (socketcand TCP, in-memory bus, tokio-modbus, tokio-serial).
//! Every source turns bytes into timestamped [`Sample`]s that carry their health, and keeps counters.
//!
//! Value convention for non-`Ok` samples: `Stale` carries the last good value (NaN if there was none),
//! `DecodeError` carries NaN (CiA 406: the last good position), `OutOfRange` the decoded value. A
//! consumer must look at `health` before it uses `value`. See `docs/buses.md`.
//!
//! Every numeric conversion that could truncate, wrap or lose a sign (register words, CAN ids, DLCs,
//! CiA 404/406 values) is a `try_from`, or an `as` after a range check with its reason beside it
//! (these lints are errors in CI). Tests compare floats exactly where the value is exact.
#![warn(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]
#![warn(unreachable_pub, unnameable_types)]
#![cfg_attr(
    test,
    allow(
        clippy::float_cmp,
        reason = "tests assert values that are exact in binary or parsed from the same decimal text"
    )
)]

// Namespaces of the API stay public modules; `backoff` and `sample` each hold one concept and are
// re-exported here from private modules.
pub mod can;
pub mod canopen;
pub mod config;
pub mod fault;
pub mod listen;
pub mod modbus;
pub mod realtime;
pub mod serial;

mod backoff;
mod deadline;
mod sample;

pub use backoff::Backoff;
pub use sample::{ChannelId, ChannelTable, Health, Sample};
