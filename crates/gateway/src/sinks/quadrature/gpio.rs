//! Real GPIO for the injector (cargo feature `gpio`, Linux only): the A and B lines are requested as
//! outputs through the GPIO character device (`/dev/gpiochipN`, linux-embedded-hal's `CdevPin`) with
//! the scheduler's current levels as their initial values, so taking the lines causes no edge.
//!
//! Userspace cannot follow native encoder edges at RS-422 rates, so this shell drives a quadrature
//! input that carries only the injected counts (a controller's handwheel/"manual handle interrupt"
//! input, or an interposer that merges the edges in hardware with [`super::scheduler`] as its
//! reference). Pins are held by the injector thread for the whole run; the kernel releases them when
//! the process ends.

use linux_embedded_hal::CdevPin;
use linux_embedded_hal::gpio_cdev::{Chip, LineRequestFlags};

use super::config::GpioLines;
use crate::sinks::SinkError;

const CONSUMER: &str = "retrocomp-quadrature";

/// Request both lines as outputs at `levels` (A, B). Errors name the chip and the line.
pub(crate) fn open_output_pins(
    lines: &GpioLines,
    levels: (bool, bool),
) -> Result<(CdevPin, CdevPin), SinkError> {
    let mut chip = Chip::new(&lines.chip).map_err(|e| {
        SinkError::setup(
            format!(
                "GPIO chip {}: cannot open (is the path right, and may this user open it?)",
                lines.chip
            ),
            e,
        )
    })?;
    let mut request = |offset: u32, name: char, high: bool| -> Result<CdevPin, SinkError> {
        let handle = chip
            .get_line(offset)
            .and_then(|l| l.request(LineRequestFlags::OUTPUT, u8::from(high), CONSUMER))
            .map_err(|e| {
                SinkError::setup(
                    format!(
                        "GPIO {} line {offset} (quadrature {name}): cannot request it as an output",
                        lines.chip
                    ),
                    e,
                )
            })?;
        CdevPin::new(handle).map_err(|e| {
            SinkError::setup(format!("GPIO {} line {offset}: line info", lines.chip), e)
        })
    };
    let a = request(lines.line_a, 'A', levels.0)?;
    let b = request(lines.line_b, 'B', levels.1)?;
    Ok((a, b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_chip_is_a_clear_error_naming_it() {
        let lines = GpioLines {
            chip: "/dev/gpiochip-retrocomp-test-absent".into(),
            line_a: 17,
            line_b: 18,
        };
        let Err(err) = open_output_pins(&lines, (false, false)) else {
            panic!("opening an absent chip succeeded");
        };
        let err = retrocomp_model::error::Chain(&err).to_string();
        assert!(err.contains("/dev/gpiochip-retrocomp-test-absent"), "{err}");
        assert!(err.contains("cannot open"), "{err}");
    }
}
