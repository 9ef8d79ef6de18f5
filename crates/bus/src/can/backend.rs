//! CAN backend selection from the field TOML:
//! ```toml
//! [can]
//! backend = "socketcand"   # or "socketcan" (Linux kernel CAN) or "mem" (in-process)
//! host = "127.0.0.1"
//! port = 29536
//! channel = "can0"
//! ```
//! `socketcan` needs `interface = "can0"`. On a host without kernel CAN it fails at start with
//! [`CanError::Unsupported`], never a panic.

use super::mem::{MemBus, MemEndpoint};
use super::socketcand_bus::{DEFAULT_PORT, SocketcandBus};
use super::{CanBus, CanError, Frame};

fn default_port() -> u16 {
    DEFAULT_PORT
}
fn default_host() -> String {
    "127.0.0.1".into()
}

#[derive(Clone, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(tag = "backend", rename_all = "snake_case")]
pub enum CanBackendConfig {
    /// Kernel SocketCAN (`can0`, `vcan0`); Linux with the `socketcan` feature.
    Socketcan { interface: String },
    /// A socketcand server (daemon or the in-process hub).
    Socketcand {
        #[serde(default = "default_host")]
        host: String,
        #[serde(default = "default_port")]
        port: u16,
        channel: String,
    },
    /// An in-process [`MemBus`] passed to [`open`].
    Mem,
}

/// How error messages name a backend: `socketcand 127.0.0.1:29536 channel can0`.
impl std::fmt::Display for CanBackendConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CanBackendConfig::Socketcan { interface } => write!(f, "socketcan {interface}"),
            CanBackendConfig::Socketcand {
                host,
                port,
                channel,
            } => write!(f, "socketcand {host}:{port} channel {channel}"),
            CanBackendConfig::Mem => f.write_str("mem"),
        }
    }
}

/// Any configured backend, behind one `CanBus` impl.
#[derive(Debug)]
pub enum AnyCanBus {
    Socketcand(SocketcandBus),
    Mem(MemEndpoint),
    #[cfg(all(feature = "socketcan", target_os = "linux"))]
    Socketcan(super::socketcan::SocketCanBus),
}

/// Open the configured backend. `mem` is the in-process bus used when `backend = "mem"`.
pub async fn open(cfg: &CanBackendConfig, mem: Option<&MemBus>) -> Result<AnyCanBus, CanError> {
    match cfg {
        CanBackendConfig::Socketcand {
            host,
            port,
            channel,
        } => Ok(AnyCanBus::Socketcand(
            SocketcandBus::connect((host.as_str(), *port), channel).await?,
        )),
        CanBackendConfig::Mem => mem.map(|m| AnyCanBus::Mem(m.endpoint())).ok_or_else(|| {
            CanError::Unsupported(
                "backend = \"mem\" needs an in-process bus (tests and hil-sim only)".into(),
            )
        }),
        CanBackendConfig::Socketcan { interface } => open_socketcan(interface),
    }
}

#[cfg(all(feature = "socketcan", target_os = "linux"))]
fn open_socketcan(interface: &str) -> Result<AnyCanBus, CanError> {
    super::socketcan::SocketCanBus::open(interface).map(AnyCanBus::Socketcan)
}

#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
fn open_socketcan(interface: &str) -> Result<AnyCanBus, CanError> {
    Err(CanError::Unsupported(format!(
        "backend = \"socketcan\" (interface `{interface}`) is not built into this binary: it needs Linux \
         and the `socketcan` cargo feature"
    )))
}

impl CanBus for AnyCanBus {
    fn bus_errors(&self) -> super::BusErrors {
        match self {
            AnyCanBus::Socketcand(b) => b.bus_errors(),
            AnyCanBus::Mem(_) => super::BusErrors::default(),
            #[cfg(all(feature = "socketcan", target_os = "linux"))]
            AnyCanBus::Socketcan(b) => b.bus_errors(),
        }
    }

    async fn send(&mut self, frame: &Frame) -> Result<(), CanError> {
        match self {
            AnyCanBus::Socketcand(b) => b.send(frame).await,
            AnyCanBus::Mem(b) => b.send(frame).await,
            #[cfg(all(feature = "socketcan", target_os = "linux"))]
            AnyCanBus::Socketcan(b) => b.send(frame).await,
        }
    }

    async fn recv(&mut self) -> Result<Frame, CanError> {
        match self {
            AnyCanBus::Socketcand(b) => b.recv().await,
            AnyCanBus::Mem(b) => b.recv().await,
            #[cfg(all(feature = "socketcan", target_os = "linux"))]
            AnyCanBus::Socketcan(b) => b.recv().await,
        }
    }

    async fn recv_event(&mut self) -> Result<Option<Frame>, CanError> {
        match self {
            AnyCanBus::Socketcand(b) => b.recv_event().await,
            AnyCanBus::Mem(b) => b.recv_event().await,
            #[cfg(all(feature = "socketcan", target_os = "linux"))]
            AnyCanBus::Socketcan(b) => b.recv_event().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Deserialize)]
    struct Doc {
        can: CanBackendConfig,
    }

    #[test]
    fn parses_each_backend_with_defaults() {
        let d: Doc =
            toml::from_str("[can]\nbackend = \"socketcand\"\nchannel = \"can0\"\n").unwrap();
        assert_eq!(
            d.can,
            CanBackendConfig::Socketcand {
                host: "127.0.0.1".into(),
                port: 29536,
                channel: "can0".into()
            }
        );
        let d: Doc =
            toml::from_str("[can]\nbackend = \"socketcan\"\ninterface = \"vcan0\"\n").unwrap();
        assert_eq!(
            d.can,
            CanBackendConfig::Socketcan {
                interface: "vcan0".into()
            }
        );
        let e = toml::from_str::<Doc>("[can]\nbackend = \"serialcan\"\n")
            .err()
            .unwrap();
        assert!(e.to_string().contains("serialcan"), "{e}");
    }

    #[tokio::test]
    async fn mem_without_bus_is_a_clear_error() {
        let e = open(&CanBackendConfig::Mem, None).await.unwrap_err();
        assert!(e.to_string().contains("in-process bus"), "{e}");
    }
}
