//! Serial line sources (DROs, digital gauges, weighing indicators): the line framer ([`framer`]), the
//! line formats ([`formats`]) and the source that maps readings to channels ([`source`]).

pub mod formats;
pub mod framer;
pub mod source;

pub use source::{LineFormat, LineSource, SerialChannel, SerialSourceConfig};
