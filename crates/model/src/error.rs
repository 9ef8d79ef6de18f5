//! What the library's typed errors share: each seam has its own error enum (`sink::SinkError`,
//! `gateway::run::GatewayError`, `demo::DemoError`, `telemetry::TelemetryError`, …) whose Display is
//! its own layer only (the key, file or step that failed), with the cause as its `source()`. The
//! command line (the only user of `anyhow`) prints the whole chain; library code that puts an error
//! into a status or a log line prints it with [`Chain`], the same `a: b: c` text.

use std::error::Error;
use std::fmt;

/// A boxed cause, as the seams' error enums hold it.
pub type BoxError = Box<dyn Error + Send + Sync + 'static>;

/// Displays an error and every `source()` under it, joined by `: ` (as `anyhow`'s `{:#}` does),
/// each cause once: a cause whose text the layers above already printed (an error whose message
/// embeds its source, common in third-party crates) is skipped, its own causes are not.
#[derive(Clone, Copy, Debug)]
pub struct Chain<'a>(pub &'a (dyn Error + 'static));

impl fmt::Display for Chain<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut text = self.0.to_string();
        let mut cause = self.0.source();
        while let Some(c) = cause {
            let layer = c.to_string();
            if !layer.is_empty() && !text.contains(&layer) {
                text.push_str(": ");
                text.push_str(&layer);
            }
            cause = c.source();
        }
        f.write_str(&text)
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

    #[derive(Debug, thiserror::Error)]
    #[error("connecting: {0}")]
    struct Embeds(#[source] Outer);

    #[test]
    fn a_cause_the_message_already_shows_is_printed_once() {
        let e = Embeds(Outer {
            what: "f.toml",
            source: std::io::Error::other("denied"),
        });
        // `Embeds` shows `Outer` in its own message: Outer is skipped, Outer's cause is not.
        assert_eq!(Chain(&e).to_string(), "connecting: opening f.toml: denied");
        // Through the binary's anyhow context: src/main.rs's tests.
    }
}
