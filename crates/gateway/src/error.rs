//! The gateway runtime's one error type at its seam ([`crate::run::run`], the sources, the OPC UA
//! endpoint): what could not start, or why a running gateway stopped. Display is this layer only
//! (the config key, the step or the source that failed); the cause is its `source()`, so the
//! command line prints `gateway.status_listen: invalid socket address syntax` as before.

use retrocomp_model::error::BoxError;

/// Why the gateway could not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    /// What `what` names (a config key, a source, a thread, an endpoint) could not be set up.
    #[error("{what}")]
    Setup {
        what: String,
        #[source]
        source: BoxError,
    },
    /// Refused as configured, or a part that could not start (the message says which).
    #[error("{0}")]
    Refused(String),
    /// A source, the sink or the cycle thread ended: the gateway stops so the service manager
    /// restarts it.
    #[error("{0}")]
    Stopped(String),
    #[error(transparent)]
    Sink(#[from] crate::sinks::SinkError),
    #[cfg(feature = "opcua")]
    #[error(transparent)]
    OpcUa(#[from] crate::northbound::opcua::OpcUaError),
    #[error(transparent)]
    Telemetry(#[from] crate::northbound::telemetry::TelemetryError),
    /// The field config's safety section cannot make an engine.
    #[error(transparent)]
    Safety(#[from] crate::engine::safety::SafetyError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

impl GatewayError {
    /// The failure of what `what` names, caused by `source`.
    pub fn setup(what: impl Into<String>, source: impl Into<BoxError>) -> Self {
        GatewayError::Setup {
            what: what.into(),
            source: source.into(),
        }
    }
}
