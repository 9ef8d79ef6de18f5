//! The legacy controller: part-program interpreter, interpolator, per-axis position loop, and the PLC
//! window through which origin shifts arrive.

pub mod dnc;
pub mod gcode;
pub mod interp;
pub mod plc;
pub mod servo;
