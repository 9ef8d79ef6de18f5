//! Field-bus sources: sans-IO codecs (CANopen, Modbus register decoding, serial line formats) with thin
//! async I/O shells (socketcan, socketcand, tokio-modbus, tokio-serial). Every source turns bytes into
//! timestamped [`Sample`]s that carry their health.

pub mod can;
pub mod canopen;
pub mod modbus;
pub mod sample;

pub use sample::{Health, Sample};
