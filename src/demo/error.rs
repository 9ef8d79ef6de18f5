//! The demo's one error type ([`DemoError`]) and the adapter its files use to name what failed
//! (`Context`, as the command line's `anyhow` does, but typed). Display is this layer only (the
//! step, file or run that failed); the cause is its `source()`, so `retrocomp demo` prints
//! `gateway (full): binding status endpoint 127.0.0.1:0: …` as before.

use retrocomp_model::error::BoxError;

/// Why the demo (a measurement run, the fit, one of the four runs, the plots) failed.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// What `what` names (a file, a run, a task) failed.
    #[error("{what}")]
    Context {
        what: String,
        #[source]
        source: BoxError,
    },
    /// A failure the message says all about (a missing column, a sim that exited, a bad value).
    #[error("{0}")]
    Failed(String),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    #[error(transparent)]
    Recording(#[from] retrocomp_model::recording::RecordingError),
    #[error(transparent)]
    Config(#[from] retrocomp_model::ConfigError),
    #[error(transparent)]
    Toml(#[from] toml::ser::Error),
    /// The fitted terms do not make a model.
    #[error(transparent)]
    Fit(#[from] retrocomp_analysis::fit::to_model::ToModelError),
    #[error(transparent)]
    Gateway(#[from] retrocomp_gateway::error::GatewayError),
}

/// Name what failed: `Result` errors become the source of a [`DemoError::Context`], an empty
/// `Option` a [`DemoError::Failed`] with that text.
pub(crate) trait Context<T> {
    fn context(self, what: impl Into<String>) -> Result<T, DemoError>;
    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, DemoError>;
}

impl<T, E: Into<BoxError>> Context<T> for Result<T, E> {
    fn context(self, what: impl Into<String>) -> Result<T, DemoError> {
        self.with_context(|| what)
    }

    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, DemoError> {
        self.map_err(|e| DemoError::Context {
            what: what().into(),
            source: e.into(),
        })
    }
}

impl<T> Context<T> for Option<T> {
    fn context(self, what: impl Into<String>) -> Result<T, DemoError> {
        self.with_context(|| what)
    }

    fn with_context<S: Into<String>>(self, what: impl FnOnce() -> S) -> Result<T, DemoError> {
        self.ok_or_else(|| DemoError::Failed(what().into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_model::error::Chain;

    #[test]
    fn context_keeps_the_cause_as_source() {
        let r: Result<(), std::io::Error> = Err(std::io::Error::other("denied"));
        let e = r.with_context(|| "creating out").unwrap_err();
        assert_eq!(e.to_string(), "creating out");
        assert_eq!(Chain(&e).to_string(), "creating out: denied");
        let e = None::<u8>.context("no column `t_s`").unwrap_err();
        assert_eq!(Chain(&e).to_string(), "no column `t_s`");
    }
}
