//! CAN: the portable frame, the async bus trait every backend implements, and the backends.

// The socketcand ASCII codec stays a public namespace (`socketcand::encode`, `socketcand::Decoder`);
// the backends' types are re-exported here from private modules.
pub mod socketcand;

mod backend;
mod bus_state;
mod frame;
mod hub;
mod mem;
#[cfg(all(feature = "socketcan", target_os = "linux"))]
mod socketcan;
mod socketcand_bus;

pub use backend::{AnyCanBus, CanBackendConfig, open};
pub use bus_state::{BusErrors, BusState, CAN_ERR_BUSOFF, ErrorFrame};
pub use frame::Frame;
pub use hub::{Hub, HubStats};
pub use mem::{MemBus, MemEndpoint};
#[cfg(all(feature = "socketcan", target_os = "linux"))]
pub use socketcan::{IdFilter, SocketCanBus};
pub use socketcand_bus::SocketcandBus;

use std::future::Future;

/// Errors a CAN backend reports. `Unsupported` is for hosts without the transport (e.g. no SocketCAN).
#[derive(Debug, thiserror::Error)]
pub enum CanError {
    #[error("CAN transport unsupported on this host: {0}")]
    Unsupported(String),
    #[error("CAN bus closed")]
    Closed,
    /// The receiver fell behind and this many frames were lost (in-memory and hub backends).
    #[error("CAN receive overrun: {0} frames lost")]
    Overrun(u64),
    #[error("CAN protocol error: {0}")]
    Protocol(String),
    /// The I/O error is shown in the message and is not also the `source()`, so an error chain
    /// (`{:#}`) prints it once.
    #[error("CAN I/O error: {0}")]
    Io(std::io::Error),
}

impl From<std::io::Error> for CanError {
    fn from(e: std::io::Error) -> Self {
        CanError::Io(e)
    }
}

/// An async CAN bus: the one interface the gateway, the simulator and the tests use.
pub trait CanBus: Send {
    fn send(&mut self, frame: &Frame) -> impl Future<Output = Result<(), CanError>> + Send;
    /// The next data or remote frame (error frames only update [`Self::bus_errors`]).
    fn recv(&mut self) -> impl Future<Output = Result<Frame, CanError>> + Send;
    /// The next thing the bus received: `Some` data or remote frame, or `None` when an error
    /// frame changed [`Self::bus_errors`]. A reader that reports the bus state wakes on it this
    /// way (a bus that went bus-off carries no data frames to wake on). Cancel-safe where `recv`
    /// is. Backends without error frames return only frames.
    fn recv_event(&mut self) -> impl Future<Output = Result<Option<Frame>, CanError>> + Send {
        async { self.recv().await.map(Some) }
    }
    /// Bus state from the error frames seen since the bus was opened (none on in-memory buses).
    fn bus_errors(&self) -> BusErrors {
        BusErrors::default()
    }
}
