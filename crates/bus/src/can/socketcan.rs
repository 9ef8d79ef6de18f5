//! The `socketcan` backend: a real kernel CAN interface (can0, vcan0) through a raw CAN socket.
//!
//! A thin async shell over the socketcan crate's raw `CanSocket` registered with tokio's reactor
//! (`AsyncFd`); all frame conversion lives in [`super::frame`] and the mapping of `open` failures to
//! clear errors is the pure function [`classify_open_error`], so it is unit-tested on any host.
//!
//! Why not `socketcan::tokio::CanSocket`: its `read_frame` waits for READABLE only, but when the
//! interface goes down (ENETDOWN) or is deleted (ENODEV) the kernel reports the socket error as
//! EPOLLERR without EPOLLIN (`raw_notify` → `sk_error_report`), so it waits forever (tokio-rs/tokio
//! #7938; the QEMU guest check `interface_down_is_an_error_not_a_hang` reproduced it). We wait for
//! READABLE | ERROR, so `recv` returns the error.
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
//! classes, feeds them to a [`BusErrors`] tracker (bus-off, error-passive, counters:
//! [`SocketCanBus::bus_errors`]) and keeps reading, so `recv` only ever returns data and remote
//! frames.
//!
//! Receive timestamps are the kernel's arrival time (`SO_TIMESTAMPNS`, wall clock), taken before
//! any userspace scheduling delay: use [`SocketCanBus::recv_timestamped`] when a sample's `t_s`
//! matters. Acceptance filters ([`IdFilter`]) run in the kernel, so a busy bus costs no wakeups.

use super::bus_state::{BusErrors, ErrorFrame};
use super::{CanBus, CanError, Frame};
use ::socketcan::{Socket as _, SocketOptions as _};
use embedded_can::Id;
use std::io;
use std::time::SystemTime;
use tokio::io::Interest;
use tokio::io::unix::AsyncFd;

/// errno values the kernel returns when opening a raw CAN socket (Linux x86-64/arm64 numbering).
const ENODEV: i32 = 19;
const EPROTONOSUPPORT: i32 = 93;
const EAFNOSUPPORT: i32 = 97;
/// Reads wait for data OR a socket error (EPOLLERR): see the module comment.
const READ_OR_ERROR: Interest = Interest::READABLE.add(Interest::ERROR);
const REGISTERED: Interest = Interest::READABLE
    .add(Interest::WRITABLE)
    .add(Interest::ERROR);
/// IFNAMSIZ − 1: longer names can never name an interface.
const MAX_IFNAME_LEN: usize = 15;
/// `CAN_ERR_MASK` from linux/can.h: every error class.
const CAN_ERR_MASK_ALL: u32 = 0x1FFF_FFFF;
/// linux/can.h: the id-width flag inside a kernel `can_id`, and the id bits of each width.
const CAN_EFF_FLAG: u32 = 0x8000_0000;
const CAN_SFF_MASK: u32 = 0x7FF;
const CAN_EFF_MASK: u32 = 0x1FFF_FFFF;

/// A kernel acceptance filter: a frame passes if it has the same id width as `id` and
/// `frame_id & mask == id & mask` (mask bits beyond the id width are ignored). Data and remote
/// frames both pass. Example: all CANopen TPDO1s (0x181..=0x1FF) = standard 0x180, mask 0x780.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IdFilter {
    pub id: Id,
    pub mask: u32,
}

impl IdFilter {
    /// The `(can_id, can_mask)` pair of `struct can_filter` (linux/can.h): the EFF flag is part of
    /// both, so a standard filter never matches an extended frame with the same low bits.
    pub fn to_kernel(self) -> (u32, u32) {
        match self.id {
            Id::Standard(s) => (
                u32::from(s.as_raw()),
                (self.mask & CAN_SFF_MASK) | CAN_EFF_FLAG,
            ),
            Id::Extended(e) => (
                e.as_raw() | CAN_EFF_FLAG,
                (self.mask & CAN_EFF_MASK) | CAN_EFF_FLAG,
            ),
        }
    }
}

/// A bus on one kernel CAN interface. Frames sent are looped back to *other* sockets on the host
/// (kernel default), so `candump` on the same interface sees them; the sender does not.
/// `recv`, `recv_timestamped` and `send` are cancel-safe (a frame is taken from the socket only
/// inside one non-blocking syscall), so they can sit in `tokio::select!` or under a timeout.
#[derive(Debug)]
pub struct SocketCanBus {
    ifname: String,
    /// Non-blocking raw socket bound to `ifname`.
    socket: AsyncFd<::socketcan::CanSocket>,
    errors: BusErrors,
}

impl SocketCanBus {
    /// Opens `ifname` (e.g. `"can0"`, `"vcan0"`). Needs a tokio runtime (the socket registers with
    /// its reactor). Never panics: a host without SocketCAN gives [`CanError::Unsupported`], a
    /// missing interface an [`CanError::Io`] of kind `NotFound`, both naming the interface.
    pub fn open(ifname: &str) -> Result<Self, CanError> {
        validate_ifname(ifname)?;
        // Registering with tokio outside a runtime panics; say so instead.
        if tokio::runtime::Handle::try_current().is_err() {
            return Err(CanError::Io(io::Error::other(format!(
                "SocketCanBus::open({ifname:?}) must be called inside a tokio runtime"
            ))));
        }
        let socket = match ::socketcan::CanSocket::open(ifname) {
            Ok(s) => s,
            Err(e) => return Err(classify_open_error(ifname, &e, can_family_available)),
        };
        socket
            .set_nonblocking(true)
            .map_err(|e| io_context(ifname, "setting O_NONBLOCK", e))?;
        socket
            .set_error_filter(CAN_ERR_MASK_ALL)
            .map_err(|e| io_context(ifname, "subscribing to error frames", e))?;
        socket
            .set_recv_timestamp(true)
            .map_err(|e| io_context(ifname, "enabling SO_TIMESTAMPNS", e))?;
        // SAFETY: `socketcan::CanSocket` owns its descriptor (an `OwnedFd` inside socket2) and never
        // replaces it, and the `AsyncFd` owns the socket until both are dropped together, so the
        // fd stays open and the same for the registration's whole lifetime.
        let socket = unsafe { AsyncFd::register_with_interest(socket, REGISTERED) }
            .map_err(|e| io_context(ifname, "registering with tokio", e.into()))?;
        Ok(SocketCanBus {
            ifname: ifname.to_owned(),
            socket,
            errors: BusErrors::default(),
        })
    }

    /// The interface this bus is bound to.
    pub fn ifname(&self) -> &str {
        &self.ifname
    }

    /// Error frames received (and skipped) since `open`.
    pub fn error_frames(&self) -> u64 {
        self.errors.error_frames
    }

    /// Receive only frames passing at least one of `filters` (replaces earlier filters; error
    /// frames are not affected). An empty list is rejected: the kernel would read it as "drop
    /// everything", which is never what a gateway wants; use [`Self::accept_all`] to reset.
    pub fn set_filters(&mut self, filters: &[IdFilter]) -> Result<(), CanError> {
        if filters.is_empty() {
            return Err(CanError::Io(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "CAN interface '{}': empty filter list would drop every frame",
                    self.ifname
                ),
            )));
        }
        let kernel: Vec<(u32, u32)> = filters.iter().map(|f| f.to_kernel()).collect();
        self.socket
            .get_ref()
            .set_filters(&kernel)
            .map_err(|e| io_context(&self.ifname, "setting filters", e))
    }

    /// Receive every data and remote frame again (the kernel default, filter 0/0).
    pub fn accept_all(&mut self) -> Result<(), CanError> {
        self.socket
            .get_ref()
            .set_filters(&[(0u32, 0u32)])
            .map_err(|e| io_context(&self.ifname, "setting filters", e))
    }

    /// Like [`CanBus::recv`], with the kernel's arrival time of the frame (wall clock).
    pub async fn recv_timestamped(&mut self) -> Result<(Frame, SystemTime), CanError> {
        loop {
            let (kframe, at) = self
                .socket
                .async_io(READ_OR_ERROR, |s| s.read_frame_with_timestamp())
                .await
                .map_err(|e| io_context(&self.ifname, "recv", e))?;
            if let Some(f) = self.accept(kframe) {
                return Ok((f, at));
            }
        }
    }

    /// Data and remote frames pass; error frames go to the bus-state tracker.
    fn accept(&mut self, kframe: ::socketcan::CanFrame) -> Option<Frame> {
        match Frame::try_from(kframe) {
            Ok(f) => {
                self.errors.handle_frame();
                Some(f)
            }
            Err(::socketcan::CanFrame::Error(ef)) => {
                let mut data = [0u8; 8];
                let d = embedded_can::Frame::data(&ef);
                let n = d.len().min(8);
                data[..n].copy_from_slice(&d[..n]);
                self.errors.handle_error_frame(&ErrorFrame {
                    class: ef.error_bits(),
                    data,
                });
                None
            }
            // A data/remote frame our portable type cannot hold (cannot happen for classic CAN).
            Err(other) => {
                tracing::debug!(ifname = %self.ifname, ?other, "CAN frame dropped");
                None
            }
        }
    }
}

impl CanBus for SocketCanBus {
    /// What the kernel's error frames said about the bus since it was opened.
    fn bus_errors(&self) -> BusErrors {
        self.errors
    }

    async fn send(&mut self, frame: &Frame) -> Result<(), CanError> {
        let kframe: ::socketcan::CanFrame = (*frame).into();
        self.socket
            .async_io(Interest::WRITABLE, |s| s.write_frame(&kframe))
            .await
            .map_err(|e| io_context(&self.ifname, "send", e))
    }

    async fn recv(&mut self) -> Result<Frame, CanError> {
        loop {
            if let Some(f) = self.recv_event().await? {
                return Ok(f);
            }
        }
    }

    /// One read of the socket: `None` when it was an error frame (now in [`Self::bus_errors`]).
    async fn recv_event(&mut self) -> Result<Option<Frame>, CanError> {
        let kframe = self
            .socket
            .async_io(READ_OR_ERROR, |s| s.read_frame())
            .await
            .map_err(|e| io_context(&self.ifname, "recv", e))?;
        Ok(self.accept(kframe))
    }
}

/// Adds which interface and operation failed; keeps the kind (callers match on it) and the
/// "(os error N)" text. ENETDOWN (kind `NetworkDown`): the interface is down, the socket recovers
/// when it comes back up. ENODEV after `open` (kind `NotFound`): the interface was deleted and the
/// socket is unbound for good, so the caller must open it again.
/// ENOBUFS on send (a real controller's TX queue is full; the socket still polls writable, so it
/// is not EAGAIN) is passed on as is for the caller to retry later; vcan has no queue to test it.
fn io_context(ifname: &str, op: &str, e: io::Error) -> CanError {
    if e.raw_os_error() == Some(ENODEV) {
        return CanError::Io(io::Error::new(
            io::ErrorKind::NotFound,
            format!(
                "CAN interface '{ifname}': {op} failed: the interface was removed ({e}); open it again"
            ),
        ));
    }
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
pub(crate) fn classify_open_error(
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

    #[test]
    fn every_errno_maps_without_panic_and_names_the_interface() {
        for errno_value in 0..=300 {
            for probe in [false, true] {
                let err = classify_open_error("can7", &errno(errno_value), || probe);
                let unsupported = matches!(err, CanError::Unsupported(_));
                let want_unsupported =
                    matches!(errno_value, 93 | 97) || (errno_value == 19 && !probe);
                assert_eq!(
                    unsupported, want_unsupported,
                    "errno {errno_value}, probe {probe}"
                );
                assert!(
                    err.to_string().contains("'can7'"),
                    "errno {errno_value}: {err}"
                );
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(100_000))]

        /// The conversion `send` relies on never panics and loses nothing, for every classic frame.
        #[test]
        fn every_frame_survives_the_kernel_frame_conversion(
            extended in proptest::prelude::any::<bool>(),
            raw_id in 0u32..=0x1FFF_FFFF,
            remote in proptest::prelude::any::<bool>(),
            data in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..=8),
        ) {
            use embedded_can::{ExtendedId, Frame as _, StandardId};
            let id: Id = if extended {
                ExtendedId::new(raw_id).unwrap().into()
            } else {
                StandardId::new((raw_id & 0x7FF) as u16).unwrap().into()
            };
            let frame = if remote {
                Frame::new_remote(id, data.len()).unwrap()
            } else {
                Frame::new(id, &data).unwrap()
            };
            let kernel: ::socketcan::CanFrame = frame.into();
            proptest::prop_assert_eq!(Frame::try_from(kernel).unwrap(), frame);
        }
    }

    #[test]
    fn filters_carry_the_id_width_flag() {
        use embedded_can::{ExtendedId, StandardId};
        let tpdo1 = IdFilter {
            id: Id::Standard(StandardId::new(0x180).unwrap()),
            mask: 0xFFFF_FF80,
        };
        // Mask bits above the 11-bit id are dropped; the EFF flag in the mask demands width 0.
        assert_eq!(tpdo1.to_kernel(), (0x180, 0x8000_0780));
        let j1939 = IdFilter {
            id: Id::Extended(ExtendedId::new(0x18FF_50E5).unwrap()),
            mask: 0x00FF_FF00,
        };
        assert_eq!(j1939.to_kernel(), (0x98FF_50E5, 0x80FF_FF00));
    }

    #[test]
    fn open_outside_a_tokio_runtime_is_an_error_not_a_panic() {
        match SocketCanBus::open("vcan0") {
            Err(CanError::Io(e)) => assert!(e.to_string().contains("tokio runtime"), "{e}"),
            other => panic!("expected an Io error, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn bad_interface_names_are_rejected_before_any_syscall() {
        for bad in ["", "abcdefghijklmnop", "a/b", "vcan 0", "a\0b"] {
            match SocketCanBus::open(bad) {
                Err(CanError::Io(e)) => {
                    assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{bad:?}: {e}");
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
                    );
                }
                (true, false, Err(CanError::Io(e))) => {
                    assert_eq!(e.kind(), io::ErrorKind::NotFound, "{e}");
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
