//! What the library's typed errors share: each seam has its own error enum (`sink::SinkError`,
//! `gateway::run::GatewayError`, `demo::DemoError`, `telemetry::TelemetryError`, …) whose Display is
//! its own layer only (the key, file or step that failed), with the cause as its `source()`. The
//! command line (the only user of `anyhow`) prints the whole chain; library code that puts an error
//! into a status or a log line prints it with [`Chain`], the same `a: b: c` text.

use std::error::Error;
use std::fmt;

/// A boxed cause, as the seams' error enums hold it.
pub type BoxError = Box<dyn Error + Send + Sync + 'static>;

/// Displays an error and every `source()` under it, joined by `: ` (as `anyhow`'s `{:#}` does).
#[derive(Clone, Copy, Debug)]
pub struct Chain<'a>(pub &'a (dyn Error + 'static));

impl fmt::Display for Chain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)?;
        let mut cause = self.0.source();
        while let Some(c) = cause {
            write!(f, ": {c}")?;
            cause = c.source();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("opening {what}")]
    struct Outer {
        what: &'static str,
        #[source]
        source: std::io::Error,
    }

    #[test]
    fn the_chain_joins_every_layer() {
        let e = Outer {
            what: "f.toml",
            source: std::io::Error::other("denied"),
        };
        assert_eq!(e.to_string(), "opening f.toml");
        assert_eq!(Chain(&e).to_string(), "opening f.toml: denied");
    }
}
