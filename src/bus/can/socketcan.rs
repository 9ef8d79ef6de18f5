//! The `socketcan` backend: a real kernel CAN interface (can0, vcan0) through a raw CAN socket.
//!
//! A thin async shell over `socketcan::tokio::CanSocket`; all frame conversion lives in
//! [`super::frame`] and the mapping of `open` failures to clear errors is the pure function
//! [`classify_open_error`], so it is unit-tested on any host.
//!
//! Open failures, by errno (see `net/can/af_can.c` and `net/can/raw.c`):
//! - 97 EAFNOSUPPORT / 93 EPROTONOSUPPORT: the kernel has no SocketCAN (CONFIG_CAN or can-raw
//!   missing) → [`CanError::Unsupported`].
//! - 19 ENODEV: `if_nametoindex` failed or the device is not a CAN device. The socketcan crate looks
//!   the name up *before* it creates the socket, so a kernel without CAN also says ENODEV here; we
//!   tell the two apart by probing for a CAN socket bound to all interfaces (ifindex 0): if that
//!   fails too → `Unsupported`, otherwise the interface is missing → `CanError::Io` with
//!   `ErrorKind::NotFound` and a hint how to create it.
//!
//! Error frames (`CAN_ERR_FLAG`) carry bus state, not data: [`SocketCanBus`] subscribes to all error
//! classes, counts them ([`SocketCanBus::error_frames`]) and keeps reading, so `recv` only ever
//! returns data and remote frames.

use super::{CanBus, CanError, Frame};
use ::socketcan::{Socket as _, SocketOptions as _};
use std::io;

/// errno values the kernel returns when opening a raw CAN socket (Linux x86-64/arm64 numbering).
const ENODEV: i32 = 19;
const EPROTONOSUPPORT: i32 = 93;
const EAFNOSUPPORT: i32 = 97;
/// IFNAMSIZ − 1: longer names can never name an interface.
const MAX_IFNAME_LEN: usize = 15;
/// `CAN_ERR_MASK` from linux/can.h: every error class.
const CAN_ERR_MASK_ALL: u32 = 0x1FFF_FFFF;

/// A bus on one kernel CAN interface. Frames sent are looped back to *other* sockets on the host
/// (kernel default), so `candump` on the same interface sees them; the sender does not.
#[derive(Debug)]
pub struct SocketCanBus {
    ifname: String,
    socket: ::socketcan::tokio::CanSocket,
    error_frames: u64,
}

impl SocketCanBus {
    /// Opens `ifname` (e.g. `"can0"`, `"vcan0"`). Needs a tokio runtime (the socket registers with
    /// its reactor). Never panics: a host without SocketCAN gives [`CanError::Unsupported`], a
    /// missing interface an [`CanError::Io`] of kind `NotFound`, both naming the interface.
    pub fn open(ifname: &str) -> Result<Self, CanError> {
        validate_ifname(ifname)?;
        let socket = match ::socketcan::tokio::CanSocket::open(ifname) {
            Ok(s) => s,
            Err(e) => return Err(classify_open_error(ifname, &e, can_family_available)),
        };
        socket.set_error_filter(CAN_ERR_MASK_ALL).map_err(|e| {
            CanError::Io(io::Error::new(
                e.kind(),
                format!("CAN interface '{ifname}': cannot subscribe to error frames: {e}"),
            ))
        })?;
        Ok(SocketCanBus {
            ifname: ifname.to_owned(),
            socket,
            error_frames: 0,
        })
    }

    /// The interface this bus is bound to.
    pub fn ifname(&self) -> &str {
        &self.ifname
    }

    /// Error frames received (and skipped) since `open`.
    pub fn error_frames(&self) -> u64 {
        self.error_frames
    }
}

impl CanBus for SocketCanBus {
    async fn send(&mut self, frame: &Frame) -> Result<(), CanError> {
        let kframe: ::socketcan::CanFrame = (*frame).into();
        self.socket
            .write_frame(kframe)
            .await
            .map_err(|e| io_context(&self.ifname, "send", e))
    }

    async fn recv(&mut self) -> Result<Frame, CanError> {
        loop {
            let kframe = self
                .socket
                .read_frame()
                .await
                .map_err(|e| io_context(&self.ifname, "recv", e))?;
            match Frame::try_from(kframe) {
                Ok(f) => return Ok(f),
                Err(error_frame) => {
                    self.error_frames += 1;
                    tracing::debug!(ifname = %self.ifname, ?error_frame, "CAN error frame");
                }
            }
        }
    }
}

/// Keeps the errno and kind (callers match on them) and adds which interface and operation failed.
fn io_context(ifname: &str, op: &str, e: io::Error) -> CanError {
    // ENETDOWN (100) is the usual one: the interface exists but is administratively down.
    CanError::Io(io::Error::new(
        e.kind(),
        format!("CAN interface '{ifname}': {op} failed: {e}"),
    ))
}

fn validate_ifname(ifname: &str) -> Result<(), CanError> {
    let ok = !ifname.is_empty()
        && ifname.len() <= MAX_IFNAME_LEN
        && !ifname
            .chars()
            .any(|c| c == '/' || c == '\0' || c.is_whitespace());
    if ok {
        Ok(())
    } else {
        Err(CanError::Io(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "invalid CAN interface name {ifname:?}: expected 1..={MAX_IFNAME_LEN} bytes \
                 without '/', NUL or whitespace (e.g. \"can0\", \"vcan0\")"
            ),
        )))
    }
}

/// Whether the kernel can create a raw CAN socket at all (bound to every CAN interface, ifindex 0).
fn can_family_available() -> bool {
    ::socketcan::CanSocket::open_iface(0).is_ok()
}

/// Maps a failed `open(ifname)` to a clear error. `can_family_available` is only called for ENODEV
/// (see the module comment); it is a parameter so the mapping is testable on any kernel.
pub fn classify_open_error(
    ifname: &str,
    e: &io::Error,
    can_family_available: impl FnOnce() -> bool,
) -> CanError {
    let no_socketcan = |errno: i32| {
        CanError::Unsupported(format!(
            "no SocketCAN on this host: opening CAN interface '{ifname}' failed with os error \
             {errno}; this kernel has no CAN_RAW support (CONFIG_CAN/CONFIG_CAN_RAW unset or the \
             can/can-raw modules not loadable). Use `modprobe can-raw`, a kernel with SocketCAN, or \
             the `socketcand`/`mem` CAN backend"
        ))
    };
    match e.raw_os_error() {
        Some(errno @ (EAFNOSUPPORT | EPROTONOSUPPORT)) => no_socketcan(errno),
        Some(ENODEV) if !can_family_available() => no_socketcan(ENODEV),
        Some(ENODEV) => CanError::Io(io::Error::new(
            io::ErrorKind::NotFound,
            format!(
                "CAN interface '{ifname}' not found or not a CAN device (os error 19); list them \
                 with `ip -details link show type can` / `type vcan`, create a virtual one with \
                 `ip link add dev {ifname} type vcan && ip link set {ifname} up`"
            ),
        )),
        _ => CanError::Io(io::Error::new(
            e.kind(),
            format!("cannot open CAN interface '{ifname}': {e}"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn errno(n: i32) -> io::Error {
        io::Error::from_raw_os_error(n)
    }

    #[test]
    fn eafnosupport_means_no_socketcan_and_never_probes() {
        let err = classify_open_error("vcan0", &errno(97), || panic!("must not probe"));
        match err {
            CanError::Unsupported(msg) => {
                assert!(msg.contains("no SocketCAN"), "{msg}");
                assert!(msg.contains("'vcan0'"), "{msg}");
                assert!(msg.contains("os error 97"), "{msg}");
            }
            other => panic!("expected Unsupported, got {other:?}"),
        }
        assert!(matches!(
            classify_open_error("can0", &errno(93), || true),
            CanError::Unsupported(_)
        ));
    }

    #[test]
    fn enodev_is_unsupported_without_can_family_and_not_found_with_it() {
        match classify_open_error("vcan0", &errno(19), || false) {
            CanError::Unsupported(msg) => assert!(msg.contains("os error 19"), "{msg}"),
            other => panic!("expected Unsupported, got {other:?}"),
        }
        match classify_open_error("nope7", &errno(19), || true) {
            CanError::Io(e) => {
                assert_eq!(e.kind(), io::ErrorKind::NotFound);
                let msg = e.to_string();
                assert!(
                    msg.contains("'nope7'") && msg.contains("type vcan"),
                    "{msg}"
                );
            }
            other => panic!("expected Io(NotFound), got {other:?}"),
        }
    }

    #[test]
    fn other_errnos_keep_their_kind() {
        match classify_open_error("can0", &errno(13), || true) {
            CanError::Io(e) => {
                assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
                assert!(e.to_string().contains("'can0'"));
            }
            other => panic!("expected Io, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn bad_interface_names_are_rejected_before_any_syscall() {
        for bad in ["", "abcdefghijklmnop", "a/b", "vcan 0", "a\0b"] {
            match SocketCanBus::open(bad) {
                Err(CanError::Io(e)) => {
                    assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{bad:?}: {e}")
                }
                other => panic!("{bad:?}: expected InvalidInput, got {other:?}"),
            }
        }
    }

    /// On the real kernel of whatever host runs the tests. The oracle is independent of our code:
    /// `/proc/net/can` exists iff the `can` core is loaded (checked *after* `open`, which may
    /// autoload it), and `/sys/class/net/<if>` iff the interface exists. On the development host
    /// (no CONFIG_CAN) this asserts the clear "no SocketCAN" error; in the QEMU guest it asserts
    /// that vcan0 opens and that a missing interface is NotFound.
    #[tokio::test]
    async fn open_on_this_kernel_gives_ok_or_a_clear_error() {
        for ifname in ["vcan0", "rcnone0"] {
            let result = SocketCanBus::open(ifname);
            let have_can = std::path::Path::new("/proc/net/can").exists();
            let have_if = std::path::Path::new("/sys/class/net").join(ifname).exists();
            match (have_can, have_if, result) {
                (false, _, Err(CanError::Unsupported(msg))) => {
                    assert!(
                        msg.contains("no SocketCAN") && msg.contains(ifname),
                        "{msg}"
                    )
                }
                (true, false, Err(CanError::Io(e))) => {
                    assert_eq!(e.kind(), io::ErrorKind::NotFound, "{e}")
                }
                (true, true, Ok(bus)) => assert_eq!(bus.ifname(), ifname),
                (have_can, have_if, other) => panic!(
                    "{ifname}: /proc/net/can exists={have_can}, interface exists={have_if}, \
                     but open gave {other:?}"
                ),
            }
        }
    }
}
