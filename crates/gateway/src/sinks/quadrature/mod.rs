//! Quadrature pulse injection (Ni 1996 Fig. 2, Yee & Gavin 1990): the box sits in the encoder feedback
//! path between the scale and the legacy controller, passes the native A/B edges through and adds or
//! removes counts so the servo moves the slide by the correction.
//!
//! Conventions:
//! - Time is integer nanoseconds (`_ns`, u64) on the injector's clock: edge gaps are sub-µs (RS-422 at
//!   400 kHz needs ≥ 0.4 µs between edges), so floats would blur the gap check.
//! - A count is one A/B edge (4 counts per signal period). Position phase `p mod 4` maps to levels
//!   (A,B) = 0:(0,0) 1:(1,0) 2:(1,1) 3:(0,1): A leads B when counting up.
//! - Sign: injecting +n counts makes the controller believe the slide moved +n counts, so its servo
//!   moves the slide by −n counts. To move the slide by a correction `c_um` (= −error), inject
//!   `−c_um / resolution_um` counts (times `count_sign` if the encoder counts opposite to the axis).
//!   [`counts::CountQuantizer`] owns this conversion.
//!
//! Layers: `counts` (µm → whole counts with a carried residual), `gray` (levels ↔ phase, the
//! decoder), `scheduler` (pure edge scheduler merging native and injected edges under the gap and
//! rate limits), `driver` (writes the schedule to two `embedded_hal::digital::OutputPin`s),
//! `injector` (the real-time thread that writes owed edges when due), `gpio` (cargo feature `gpio`:
//! the pins are Linux GPIO character-device lines), [`trace`] (the edge trace the injector threads
//! write: what they put on the lines), `native` (a simulated scale for the simulated sink).

pub(crate) mod config;
pub(crate) mod core;
pub(crate) mod counts;
pub(crate) mod driver;
#[cfg(all(feature = "gpio", target_os = "linux"))]
pub(crate) mod gpio;
pub(crate) mod gray;
pub(crate) mod held;
pub(crate) mod injector;
pub(crate) mod lines;
pub(crate) mod native;
pub(crate) mod scheduler;
pub(crate) mod sink;
pub mod trace;

pub use self::core::QuadratureCore;
pub use config::{QuadratureAxis, QuadratureSink};
pub use counts::{CountError, CountQuantizer};
pub use driver::{PinError, QuadraturePins, SimulatedPin};
pub use gray::{DecodeError, QuadDecoder, Step, levels_of_phase};
pub use held::{HeldCounts, HeldError};
pub use injector::{Feed, Injector, InjectorCounts, run_injector, run_injector_traced};
pub use native::SimulatedNative;
pub use scheduler::{
    EdgeScheduler, Event, SchedulerConfig, SchedulerConfigError, Source, Transition, simulate,
};
