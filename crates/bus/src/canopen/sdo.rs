//! SDO expedited transfers (CiA 301 §7.2.4.3): up to 4 bytes in one frame each way. Used to set the
//! encoder's cyclic timer (6200h, ms) and preset (6003h). Client→server on 0x600 + node, server→client
//! on 0x580 + node; 8 data bytes: command specifier, index (LE u16), subindex, data (LE, zero-padded).

use crate::can::Frame;
use embedded_can::Frame as _;

/// CiA 406 cyclic timer object: TPDO1 event time in ms (U16).
pub const CYCLIC_TIMER_6200: u16 = 0x6200;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoRequest {
    /// Expedited download (write) of 1..=4 bytes.
    Download {
        index: u16,
        sub: u8,
        data: [u8; 4],
        len: u8,
    },
    /// Upload (read) initiate.
    Upload { index: u16, sub: u8 },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SdoResponse {
    DownloadAck {
        index: u16,
        sub: u8,
    },
    UploadExpedited {
        index: u16,
        sub: u8,
        data: [u8; 4],
        len: u8,
    },
    Abort {
        index: u16,
        sub: u8,
        code: u32,
    },
}

impl SdoRequest {
    /// Write a U16 (e.g. 6200h cyclic timer in ms).
    pub fn write_u16(index: u16, sub: u8, v: u16) -> Self {
        let b = v.to_le_bytes();
        SdoRequest::Download {
            index,
            sub,
            data: [b[0], b[1], 0, 0],
            len: 2,
        }
    }

    pub fn write_u32(index: u16, sub: u8, v: u32) -> Self {
        SdoRequest::Download {
            index,
            sub,
            data: v.to_le_bytes(),
            len: 4,
        }
    }

    pub fn encode(&self, node: u8) -> Frame {
        let mut b = [0u8; 8];
        let (index, sub) = match *self {
            SdoRequest::Download {
                index,
                sub,
                data,
                len,
            } => {
                let len = len.clamp(1, 4);
                // ccs=1, n = unused bytes, e=1, s=1
                b[0] = 0x20 | ((4 - len) << 2) | 0x03;
                b[4..8].copy_from_slice(&data);
                for x in &mut b[4 + usize::from(len)..] {
                    *x = 0;
                }
                (index, sub)
            }
            SdoRequest::Upload { index, sub } => {
                b[0] = 0x40;
                (index, sub)
            }
        };
        sdo_frame(0x600, node, index, sub, b)
    }

    /// `Some((node, request))` for an SDO request frame this codec understands.
    pub fn decode(f: &Frame) -> Option<(u8, SdoRequest)> {
        let (id, d, index, sub) = sdo_fields(f, 0x601..=0x67F)?;
        let req = match d[0] {
            0x40 => SdoRequest::Upload { index, sub },
            cs if cs & 0xE3 == 0x23 => {
                let len = 4 - ((cs >> 2) & 0x03);
                let mut data = [0u8; 4];
                data[..usize::from(len)].copy_from_slice(&d[4..4 + usize::from(len)]);
                SdoRequest::Download {
                    index,
                    sub,
                    data,
                    len,
                }
            }
            _ => return None,
        };
        Some((u8::try_from(id - 0x600).ok()?, req))
    }
}

/// An 8-byte SDO frame to or from `node` on COB-ID `cob_base + node`, with the multiplexer
/// (index little-endian, sub-index) written into bytes 1..4 of `b`.
fn sdo_frame(cob_base: u16, node: u8, index: u16, sub: u8, mut b: [u8; 8]) -> Frame {
    b[1..3].copy_from_slice(&index.to_le_bytes());
    b[3] = sub;
    Frame::standard(cob_base + u16::from(node & 0x7F), &b).expect("valid SDO frame")
}

/// `(id, data, index, sub)` of a standard 8-byte frame whose id is in `ids`, else `None`.
fn sdo_fields(f: &Frame, ids: std::ops::RangeInclusive<u32>) -> Option<(u32, &[u8], u16, u8)> {
    let id = f.raw_id();
    if f.is_extended() || !ids.contains(&id) || f.data().len() != 8 {
        return None;
    }
    let d = f.data();
    Some((id, d, u16::from_le_bytes([d[1], d[2]]), d[3]))
}

impl SdoResponse {
    pub fn encode(&self, node: u8) -> Frame {
        let mut b = [0u8; 8];
        let (index, sub) = match *self {
            SdoResponse::DownloadAck { index, sub } => {
                b[0] = 0x60;
                (index, sub)
            }
            SdoResponse::UploadExpedited {
                index,
                sub,
                data,
                len,
            } => {
                let len = len.clamp(1, 4);
                b[0] = 0x40 | ((4 - len) << 2) | 0x03;
                b[4..4 + usize::from(len)].copy_from_slice(&data[..usize::from(len)]);
                (index, sub)
            }
            SdoResponse::Abort { index, sub, code } => {
                b[0] = 0x80;
                b[4..8].copy_from_slice(&code.to_le_bytes());
                (index, sub)
            }
        };
        sdo_frame(0x580, node, index, sub, b)
    }

    pub fn decode(f: &Frame) -> Option<(u8, SdoResponse)> {
        let (id, d, index, sub) = sdo_fields(f, 0x581..=0x5FF)?;
        let resp = match d[0] {
            0x60 => SdoResponse::DownloadAck { index, sub },
            0x80 => SdoResponse::Abort {
                index,
                sub,
                code: u32::from_le_bytes([d[4], d[5], d[6], d[7]]),
            },
            cs if cs & 0xE3 == 0x43 => {
                let len = 4 - ((cs >> 2) & 0x03);
                let mut data = [0u8; 4];
                data[..usize::from(len)].copy_from_slice(&d[4..4 + usize::from(len)]);
                SdoResponse::UploadExpedited {
                    index,
                    sub,
                    data,
                    len,
                }
            }
            _ => return None,
        };
        Some((u8::try_from(id - 0x580).ok()?, resp))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Abort code (CiA 301): object does not exist in the object dictionary.
    const ABORT_NO_OBJECT: u32 = 0x0602_0000;

    #[test]
    fn cyclic_timer_write_wire_form() {
        // Set 6200h to 10 ms on node 2: 602#2B 00 62 00 0A 00 00 00 (2-byte expedited download).
        let f = SdoRequest::write_u16(CYCLIC_TIMER_6200, 0, 10).encode(2);
        assert_eq!(f.raw_id(), 0x602);
        assert_eq!(f.data(), &[0x2B, 0x00, 0x62, 0x00, 0x0A, 0, 0, 0]);
        let (node, req) = SdoRequest::decode(&f).unwrap();
        assert_eq!((node, req), (2, SdoRequest::write_u16(0x6200, 0, 10)));
        let ack = SdoResponse::DownloadAck {
            index: 0x6200,
            sub: 0,
        }
        .encode(2);
        assert_eq!(ack.data(), &[0x60, 0x00, 0x62, 0, 0, 0, 0, 0]);
        assert_eq!(SdoResponse::decode(&ack).unwrap().0, 2);
    }

    #[test]
    fn abort_and_upload_round_trip() {
        for r in [
            SdoResponse::Abort {
                index: 0x6004,
                sub: 0,
                code: ABORT_NO_OBJECT,
            },
            SdoResponse::UploadExpedited {
                index: 0x6004,
                sub: 0,
                data: 0x0012_3456u32.to_le_bytes(),
                len: 4,
            },
        ] {
            assert_eq!(SdoResponse::decode(&r.encode(9)), Some((9, r)));
        }
        let up = SdoRequest::Upload {
            index: 0x6004,
            sub: 0,
        };
        assert_eq!(SdoRequest::decode(&up.encode(1)), Some((1, up)));
    }
}
