//! What the gateway's run loop knows about a sink: the [`Sink`] trait every output implements (the
//! origin-shift client `origin_shift::sink_task`, the origin-shift server `origin_shift::server`,
//! the quadrature injector `quadrature::sink`), the channels it is driven through ([`SinkIo`]) and
//! what it reports ([`SinkStatus`]). It sits below the gateway and the sinks so each sink's shell
//! lives with its core and none imports the gateway.
//!
//! Units and signs: outputs are corrections per axis, µm, = −error (the engine's convention);
//! the start values are what the controller holds per axis, µm, with the same sign.

pub mod dnc;
pub mod guard;
pub mod origin_shift;
pub mod quadrature;

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;

use serde::Serialize;
use tokio::sync::{mpsc, watch};

use retrocomp_bus::Sample;
use retrocomp_bus::fault::FaultKind;
use retrocomp_model::Axis;

/// A future run on the sink thread's current-thread runtime (not `Send`: it never leaves it).
pub type LocalFuture<'a, T> = Pin<Box<dyn Future<Output = T> + 'a>>;

/// Start values per axis, µm, as the controller holds them (the engine continues from them).
pub type StartValues = BTreeMap<String, f64>;

/// The channels between the cycle and a sink.
#[derive(Debug)]
pub struct SinkIo {
    /// The cycle's outputs (axis, correction µm); dropped by the runtime when the run ends.
    pub out_rx: watch::Receiver<Vec<(Axis, f64)>>,
    /// What the controller holds when it changed behind our back (axis, µm): reseeds the engine.
    pub reseed_tx: mpsc::Sender<(Axis, f64)>,
    pub status: watch::Sender<SinkStatus>,
    /// `Some(max_s)`: ramp the correction out (for at most `max_s`), then return.
    pub stop: watch::Receiver<Option<f64>>,
    /// Positions the controller writes into a served register image (origin-shift server).
    pub served: mpsc::Sender<Sample>,
}

/// One output to the controller, driven by the run loop on the sink thread: first [`Sink::start`]
/// (what the controller holds before the engine starts, so a restart does not jump), then
/// [`Sink::run`] until the runtime drops the outputs or the sink fails (returning is an end the
/// runtime treats as a failure, except after a requested stop).
pub trait Sink {
    /// Connect and return what the controller holds per axis (empty when the sink holds no state
    /// the engine must continue from). Waits for the controller as long as it takes.
    fn start<'a>(&'a mut self, io: &'a SinkIo) -> LocalFuture<'a, Result<StartValues, SinkError>>;

    /// Follow the cycle's outputs until the runtime drops them, a stop ramp ends, or the sink fails.
    fn run(self: Box<Self>, io: SinkIo) -> LocalFuture<'static, ()>;
}

/// Why a sink could not be built or started: the sinks' one error type at this seam. Display is the
/// config key or axis that failed (the cause is its `source()`), or the whole message.
#[derive(Debug, thiserror::Error)]
pub enum SinkError {
    /// What `what` names (a config key, an axis, a thread) could not be set up.
    #[error("{what}")]
    Setup {
        what: String,
        #[source]
        source: retrocomp_model::error::BoxError,
    },
    /// Refused as configured (the message says what to change).
    #[error("{0}")]
    Refused(String),
}

impl SinkError {
    /// The failure of what `what` names, caused by `source`.
    pub fn setup(
        what: impl Into<String>,
        source: impl Into<retrocomp_model::error::BoxError>,
    ) -> Self {
        SinkError::Setup {
            what: what.into(),
            source: source.into(),
        }
    }
}

/// A sink's state as `/status` and `/metrics` show it (one per gateway).
#[derive(Clone, Debug, PartialEq, Serialize, Default)]
pub struct SinkStatus {
    pub kind: String,
    pub connected: bool,
    pub writes_ok: u64,
    pub writes_failed: u64,
    pub last_error: Option<String>,
    /// What the controller's registers hold per axis, µm, as last read (origin shift only).
    pub held_um: BTreeMap<String, f64>,
    /// The sink's active faults: (source, fault, since t_s).
    pub faults: Vec<(String, FaultKind, f64)>,
}
