//! Writes scheduled transitions to two `embedded_hal::digital::OutputPin`s (A and B).
//!
//! Any `OutputPin` works: embedded-hal-mock pins in tests; on Linux the `CdevPin` of linux-embedded-hal
//! (GPIO character device). The crate does not depend on a GPIO crate itself (cargo feature `gpio`
//! is reserved for that shell); timing is the caller's job — userspace GPIO jitters, so a real
//! injector should run the scheduler on a timer-driven core or FPGA and keep this as the reference.

use embedded_hal::digital::OutputPin;

use super::scheduler::Transition;

#[derive(Debug, thiserror::Error)]
pub enum PinError<E: core::fmt::Debug> {
    #[error("GPIO write to line {line} failed: {err:?}")]
    Gpio { line: char, err: E },
}

/// The two output lines and the levels last written to them.
#[derive(Debug)]
pub struct QuadraturePins<A, B> {
    a: A,
    b: B,
    levels: (bool, bool),
}

impl<A, B, E> QuadraturePins<A, B>
where
    A: OutputPin<Error = E>,
    B: OutputPin<Error = E>,
    E: core::fmt::Debug,
{
    /// Drive both lines to the initial levels (the scheduler's `levels()`).
    pub fn new(mut a: A, mut b: B, levels: (bool, bool)) -> Result<Self, PinError<E>> {
        set(&mut a, levels.0).map_err(|err| PinError::Gpio { line: 'A', err })?;
        set(&mut b, levels.1).map_err(|err| PinError::Gpio { line: 'B', err })?;
        Ok(Self { a, b, levels })
    }

    /// Write one transition: exactly one line changes (Gray code), so exactly one pin is written.
    pub fn apply(&mut self, tr: &Transition) -> Result<(), PinError<E>> {
        if tr.a != self.levels.0 {
            set(&mut self.a, tr.a).map_err(|err| PinError::Gpio { line: 'A', err })?;
        }
        if tr.b != self.levels.1 {
            set(&mut self.b, tr.b).map_err(|err| PinError::Gpio { line: 'B', err })?;
        }
        self.levels = (tr.a, tr.b);
        Ok(())
    }

    pub fn levels(&self) -> (bool, bool) {
        self.levels
    }

    /// Give the pins back (e.g. to check a mock's expectations).
    pub fn release(self) -> (A, B) {
        (self.a, self.b)
    }
}

fn set<P: OutputPin>(p: &mut P, high: bool) -> Result<(), P::Error> {
    if high { p.set_high() } else { p.set_low() }
}

/// A line that only holds its level: the simulated sink's pins (no GPIO), so the simulated sink runs
/// the same injector thread as the `gpio` build and its trace is what that thread wrote.
#[derive(Debug, Default)]
pub struct SimulatedPin {
    high: bool,
}

impl SimulatedPin {
    pub fn is_high(&self) -> bool {
        self.high
    }
}

impl embedded_hal::digital::ErrorType for SimulatedPin {
    type Error = core::convert::Infallible;
}

impl OutputPin for SimulatedPin {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        self.high = false;
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        self.high = true;
        Ok(())
    }
}
