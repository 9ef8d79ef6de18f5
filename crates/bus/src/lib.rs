//! retrocomp's bus crate. Field-bus sources: sans-IO codecs (socketcand, CANopen, Modbus register decoding, serial line
//! formats) with thin async I/O shells (socketcand TCP, in-memory bus, tokio-modbus, tokio-serial).
//! Every source turns bytes into timestamped [`Sample`]s that carry their health, and keeps counters.
//!
//! Value convention for non-`Ok` samples: `Stale` carries the last good value (NaN if there was none),
//! `DecodeError` carries NaN (CiA 406: the last good position), `OutOfRange` the decoded value. A
//! consumer must look at `health` before it uses `value`. See `docs/buses.md`.

pub mod backoff;
pub mod can;
pub mod canopen;
pub mod config;
pub mod fault;
pub mod listen;
pub mod modbus;
pub mod realtime;
pub mod sample;
pub mod serial;

pub use backoff::Backoff;
pub use sample::{ChannelId, Health, Sample};
