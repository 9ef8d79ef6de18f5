//! The portable CAN frame: classic CAN 2.0A/B, up to 8 data bytes, remote frames allowed.
//!
//! It implements `embedded_can::Frame` so the same decoders serve embedded targets, and converts to and
//! from `socketcan::CanFrame` (feature `socketcan`) so the kernel backend is a thin shell.

use embedded_can::{ExtendedId, Id, StandardId};

/// A classic CAN frame. Invariant: `len <= 8`; bytes past `len` are zero.
#[derive(Clone, Copy, PartialEq, Eq, Debug, Hash)]
pub struct Frame {
    id: Id,
    remote: bool,
    len: u8,
    data: [u8; 8],
}

impl Frame {
    /// Data frame with an 11-bit identifier. `None` if `raw_id > 0x7FF` or `data.len() > 8`.
    pub fn standard(raw_id: u16, data: &[u8]) -> Option<Self> {
        embedded_can::Frame::new(StandardId::new(raw_id)?, data)
    }

    /// Data frame with a 29-bit identifier. `None` if `raw_id > 0x1FFF_FFFF` or `data.len() > 8`.
    pub fn extended(raw_id: u32, data: &[u8]) -> Option<Self> {
        embedded_can::Frame::new(ExtendedId::new(raw_id)?, data)
    }

    /// The identifier as a plain number (11 or 29 bits); see [`embedded_can::Frame::is_extended`].
    pub fn raw_id(&self) -> u32 {
        match self.id {
            Id::Standard(s) => u32::from(s.as_raw()),
            Id::Extended(e) => e.as_raw(),
        }
    }
}

impl embedded_can::Frame for Frame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        if data.len() > 8 {
            return None;
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Some(Frame {
            id: id.into(),
            remote: false,
            len: u8::try_from(data.len()).expect("checked ≤ 8 above"),
            data: buf,
        })
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        if dlc > 8 {
            return None;
        }
        Some(Frame {
            id: id.into(),
            remote: true,
            len: u8::try_from(dlc).expect("checked ≤ 8 above"),
            data: [0; 8],
        })
    }

    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    fn is_remote_frame(&self) -> bool {
        self.remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        usize::from(self.len)
    }

    fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..usize::from(self.len)]
        }
    }
}

#[cfg(all(feature = "socketcan", target_os = "linux"))]
mod socketcan_conv {
    use super::Frame;
    use embedded_can::Frame as _;

    impl From<Frame> for socketcan::CanFrame {
        fn from(f: Frame) -> Self {
            let built = if f.is_remote_frame() {
                socketcan::CanFrame::new_remote(f.id(), f.dlc())
            } else {
                socketcan::CanFrame::new(f.id(), f.data())
            };
            // Both types enforce the same limits (id width, dlc <= 8), so construction cannot fail.
            built.expect("portable frame is always a valid classic CAN frame")
        }
    }

    impl TryFrom<socketcan::CanFrame> for Frame {
        type Error = socketcan::CanFrame;

        /// Error frames carry bus state, not data: they are handed back to the caller to count.
        fn try_from(f: socketcan::CanFrame) -> Result<Self, Self::Error> {
            match f {
                socketcan::CanFrame::Data(_) => Frame::new(f.id(), f.data()).ok_or(f),
                socketcan::CanFrame::Remote(_) => Frame::new_remote(f.id(), f.dlc()).ok_or(f),
                socketcan::CanFrame::Error(_) => Err(f),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_can::Frame as _;

    #[test]
    fn limits_are_enforced() {
        assert!(Frame::standard(0x800, &[]).is_none());
        assert!(Frame::extended(0x2000_0000, &[]).is_none());
        assert!(Frame::standard(0x181, &[0; 9]).is_none());
        let f = Frame::standard(0x181, &[1, 2, 3]).unwrap();
        assert_eq!(
            (f.raw_id(), f.dlc(), f.data()),
            (0x181, 3, &[1u8, 2, 3][..])
        );
        assert!(!f.is_extended());
    }

    #[cfg(all(feature = "socketcan", target_os = "linux"))]
    #[test]
    fn socketcan_round_trip() {
        for f in [
            Frame::standard(0x7FF, &[0xde, 0xad]).unwrap(),
            Frame::extended(0x18FF_50E5, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
            Frame::new_remote(StandardId::new(0x123).unwrap(), 4).unwrap(),
        ] {
            let k: socketcan::CanFrame = f.into();
            assert_eq!(Frame::try_from(k).unwrap(), f);
        }
    }
}
