//! The telemetry's one error type at its seams: what a publisher or a recording shipment cannot
//! start with and the config check cannot see (an unreadable queue directory, password file or
//! certificate), and a recording that cannot be shipped as given. Display names the config key or
//! the recording; the cause is its `source()`.

/// Why telemetry could not start or a recording could not be shipped.
#[derive(Debug, thiserror::Error)]
pub enum TelemetryError {
    /// What `what` names (a config key and its file, a directory) could not be used.
    #[error("{what}")]
    Setup {
        what: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A value that is wrong as given (the message says what was expected).
    #[error("{0}")]
    Invalid(String),
}

impl TelemetryError {
    /// A `map_err` adapter: the failure of what `what` names.
    pub fn setup<E: Into<Box<dyn std::error::Error + Send + Sync>>>(
        what: impl Into<String>,
    ) -> impl FnOnce(E) -> Self {
        let what = what.into();
        move |e| TelemetryError::Setup {
            what,
            source: e.into(),
        }
    }
}
