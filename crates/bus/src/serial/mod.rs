//! Serial line sources (DROs, digital gauges, weighing indicators): the line framer ([`LineFramer`]),
//! the line formats ([`parse_heidenhain`], [`parse_weighing`], …) and the source that maps readings to
//! channels ([`LineSource`]).

mod formats;
mod framer;
mod source;

pub use formats::{
    GenericFormat, LineError, Reading, parse_generic, parse_heidenhain, parse_mitutoyo,
    parse_nd522, parse_weighing,
};
pub use framer::LineFramer;
pub use source::{
    LineFormat, LineSource, SerialChannel, SerialCounters, SerialSourceConfig, open, run,
};
