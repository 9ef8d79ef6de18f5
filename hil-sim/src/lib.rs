//! hil-sim: the virtual legacy CNC.
