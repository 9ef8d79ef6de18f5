//! Controller compensation tables, written from and read back into [`BidirectionalTable`]s:
//! Fanuc pitch-error compensation (parameters 3620–3624 + backlash 1851), LinuxCNC screw-compensation
//! files (nominal / forward / reverse triplets) and ISG-style CSV (`X EXX EYX EZX EAX EBX ECX`).
//!
//! Each format states its sign: the tables here hold **errors** (actual − nominal, µm); a controller
//! applies the **correction** (−error). Every writer has a reader, and round trips are tested.
//!
//! [`BidirectionalTable`]: crate::table::BidirectionalTable

pub mod fanuc;
pub mod isg;
pub mod linuxcnc;
