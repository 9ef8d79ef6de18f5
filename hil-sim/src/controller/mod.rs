//! The legacy controller: part-program interpreter, interpolator, per-axis position loop, and the PLC
//! window through which origin shifts arrive.

pub(crate) mod dnc;
pub mod gcode;
pub(crate) mod interp;
pub(crate) mod plc;
pub(crate) mod servo;

pub use dnc::{DncConfig, DncCounts, DncEvent, DncEventKind, DncInput, DncStream};
pub use interp::{ProgramRunner, Setpoint};
pub use plc::{OriginShiftPlc, PlcEvent, PlcEventKind, RegisterError};
