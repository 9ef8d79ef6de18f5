//! hil-sim: the virtual legacy CNC.

pub mod cases;
