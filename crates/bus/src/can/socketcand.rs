//! Sans-IO codec for the socketcand rawmode protocol (linux-can/socketcand `doc/protocol.md`).
//!
//! Every message is ASCII framed as `< word args… >`, with no newline. The rawmode subset used here:
//! - server greeting `< hi >`; client `< open <bus> >` → `< ok >`; `< rawmode >` → `< ok >`;
//! - client TX `< send <id-hex> <dlc> <byte-hex>… >` (bytes space-separated, 1–2 hex digits each);
//! - server RX `< frame <id-hex> <sec>.<usec> <hexbytes> >` (bytes contiguous, 2 digits each);
//! - `< error <text> >`, `< echo >`;
//! - server RX of a bus error frame `< error <class-hex> <sec>.<usec> >` (socketcand `state_raw.c`
//!   forwards `can_id & CAN_EFF_MASK` of each `CAN_ERR_FLAG` frame): [`Message::ErrorFrame`].
//!
//! Identifier width follows python-can and socketcand: an id written with **exactly 3 hex digits or fewer
//! is standard (11-bit)**, anything longer is extended (29-bit); the encoder always writes 3 or 8 digits.
//! Timestamps are seconds (f64) on the sender's clock.
//!
//! [`Decoder`] takes bytes as they arrive and yields messages; bytes outside `<…>` are counted as
//! garbage and skipped, and an unterminated message longer than [`MAX_MESSAGE_LEN`] is dropped, so no
//! input can make it panic or grow without bound.

use super::Frame;
use embedded_can::{ExtendedId, Frame as _, Id, StandardId};
use std::fmt::Write as _;

/// Longest message accepted, in bytes between `<` and `>` (a full `send` is ~45 bytes).
pub const MAX_MESSAGE_LEN: usize = 256;

/// One protocol message.
#[derive(Clone, Debug, PartialEq)]
pub enum Message {
    Hi,
    Ok,
    Echo,
    Open(String),
    RawMode,
    /// Client → server: put a frame on the bus.
    Send(Frame),
    /// Server → client: a frame seen on the bus, with its timestamp in seconds.
    Frame {
        frame: Frame,
        t_s: f64,
    },
    Error(String),
    /// Server → client: an error frame seen on the bus (class bits of linux/can/error.h only).
    ErrorFrame {
        class: u32,
        t_s: f64,
    },
    /// A well-formed message with a command this codec does not implement (e.g. `bcmmode`); kept so
    /// a server can answer `< error … >` instead of dropping it.
    Other(String),
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    #[error("socketcand: malformed `{command}` message: {why}: `< {text} >`")]
    Malformed {
        command: String,
        why: &'static str,
        text: String,
    },
    #[error("socketcand: message longer than {MAX_MESSAGE_LEN} bytes dropped")]
    TooLong,
    #[error("socketcand: message is not ASCII")]
    NotAscii,
}

/// Parse the text between `<` and `>` (surrounding spaces allowed).
pub fn parse_message(inner: &str) -> Result<Message, CodecError> {
    let text = inner.trim();
    let mut words = text.split_ascii_whitespace();
    let command = words.next().unwrap_or("");
    let bad = |why: &'static str| CodecError::Malformed {
        command: command.to_string(),
        why,
        text: text.to_string(),
    };
    match command {
        "hi" => Ok(Message::Hi),
        "ok" => Ok(Message::Ok),
        "echo" => Ok(Message::Echo),
        "rawmode" => Ok(Message::RawMode),
        "open" => words
            .next()
            .map(|b| Message::Open(b.to_string()))
            .ok_or_else(|| bad("missing bus name")),
        "error" => Ok(parse_error_frame(text).unwrap_or_else(|| {
            Message::Error(text.strip_prefix("error").unwrap_or("").trim().to_string())
        })),
        "send" => {
            let id = parse_id(words.next().ok_or_else(|| bad("missing id"))?)
                .ok_or_else(|| bad("id is not a valid hex CAN id"))?;
            let dlc = words
                .next()
                .and_then(|d| u8::from_str_radix(d, 16).ok())
                .filter(|&d| d <= 8)
                .ok_or_else(|| bad("dlc must be 0..8"))?;
            let mut data = [0u8; 8];
            let mut n = 0usize;
            for w in words {
                if n == 8 || w.len() > 2 {
                    return Err(bad("more than 8 bytes or a byte wider than 2 hex digits"));
                }
                data[n] = u8::from_str_radix(w, 16).map_err(|_| bad("byte is not hex"))?;
                n += 1;
            }
            if n != usize::from(dlc) {
                return Err(bad("byte count differs from dlc"));
            }
            Frame::new(id, &data[..n])
                .map(Message::Send)
                .ok_or_else(|| bad("invalid frame"))
        }
        "frame" => {
            let id = parse_id(words.next().ok_or_else(|| bad("missing id"))?)
                .ok_or_else(|| bad("id is not a valid hex CAN id"))?;
            let t_s = words
                .next()
                .and_then(|t| t.parse::<f64>().ok())
                .filter(|t| t.is_finite() && *t >= 0.0)
                .ok_or_else(|| bad("timestamp must be <sec>.<usec>"))?;
            // Data may be one contiguous hex string or space-separated pairs (python-can accepts both).
            let mut data = [0u8; 8];
            let mut n = 0usize;
            for w in words {
                let b = w.as_bytes();
                if b.len() % 2 != 0 {
                    return Err(bad("odd number of hex digits"));
                }
                for pair in b.chunks_exact(2) {
                    if n == 8 {
                        return Err(bad("more than 8 data bytes"));
                    }
                    data[n] = hex_pair(pair).ok_or_else(|| bad("data is not hex"))?;
                    n += 1;
                }
            }
            let frame = Frame::new(id, &data[..n]).ok_or_else(|| bad("invalid frame"))?;
            Ok(Message::Frame { frame, t_s })
        }
        "" => Err(bad("empty message")),
        _ => Ok(Message::Other(text.to_string())),
    }
}

/// `error <class-hex> <sec>.<usec>` (exactly these two words) is a bus error frame; any other
/// `error` text is a server message.
fn parse_error_frame(text: &str) -> Option<Message> {
    let mut w = text.split_ascii_whitespace().skip(1);
    let (class, t, rest) = (w.next()?, w.next()?, w.next());
    if rest.is_some() || class.len() > 8 || !class.bytes().all(|c| c.is_ascii_hexdigit()) {
        return None;
    }
    let class = u32::from_str_radix(class, 16).ok()? & 0x1FFF_FFFF;
    let t_s = t
        .parse::<f64>()
        .ok()
        .filter(|t| t.is_finite() && *t >= 0.0)?;
    t.contains('.')
        .then_some(Message::ErrorFrame { class, t_s })
}

fn hex_pair(p: &[u8]) -> Option<u8> {
    let d = |c: u8| (c as char).to_digit(16);
    u8::try_from(d(p[0])? * 16 + d(p[1])?).ok()
}

/// `≤ 3` hex digits → standard id, more → extended (python-can and socketcand use the digit count).
fn parse_id(s: &str) -> Option<Id> {
    if s.is_empty() || s.len() > 8 || !s.bytes().all(|c| c.is_ascii_hexdigit()) {
        return None;
    }
    let v = u32::from_str_radix(s, 16).ok()?;
    if s.len() <= 3 {
        StandardId::new(u16::try_from(v).ok()?).map(Id::Standard)
    } else {
        ExtendedId::new(v).map(Id::Extended)
    }
}

fn write_id(out: &mut String, f: &Frame) {
    match f.id() {
        Id::Standard(s) => write!(out, "{:03X}", s.as_raw()),
        Id::Extended(e) => write!(out, "{:08X}", e.as_raw()),
    }
    .expect("writing to a String cannot fail");
}

/// Append the wire form of `msg` to `out`.
pub fn encode_into(out: &mut String, msg: &Message) {
    out.push_str("< ");
    match msg {
        Message::Hi => out.push_str("hi"),
        Message::Ok => out.push_str("ok"),
        Message::Echo => out.push_str("echo"),
        Message::RawMode => out.push_str("rawmode"),
        Message::Open(bus) => {
            out.push_str("open ");
            out.push_str(bus);
        }
        Message::Error(text) => {
            out.push_str("error ");
            out.push_str(text);
        }
        Message::Other(text) => out.push_str(text),
        Message::ErrorFrame { class, t_s } => {
            out.push_str("error ");
            let _ = write!(out, "{class:03X}");
            write_time(out, *t_s);
            out.push(' ');
        }
        Message::Send(f) => {
            out.push_str("send ");
            write_id(out, f);
            let _ = write!(out, " {}", f.data().len());
            for b in f.data() {
                let _ = write!(out, " {b:02X}");
            }
        }
        Message::Frame { frame, t_s } => {
            out.push_str("frame ");
            write_id(out, frame);
            write_time(out, *t_s);
            out.push(' ');
            for b in frame.data() {
                let _ = write!(out, "{b:02X}");
            }
        }
    }
    out.push_str(" >");
}

/// ` <sec>.<usec>` (negative or non-finite times are written as 0).
fn write_time(out: &mut String, t_s: f64) {
    let t = if t_s.is_finite() && t_s >= 0.0 {
        t_s
    } else {
        0.0
    };
    let sec = t.trunc();
    let usec = ((t - sec) * 1e6).round().clamp(0.0, 999_999.0);
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        reason = "t is finite and ≥ 0 (0.0 otherwise, above): whole seconds saturate only past 5·10¹¹ years; usec is clamped to 0..=999 999"
    )]
    let (sec, usec) = (sec as u64, usec as u32);
    let _ = write!(out, " {sec}.{usec:06}");
}

/// The wire form of `msg`.
pub fn encode(msg: &Message) -> String {
    let mut s = String::with_capacity(48);
    encode_into(&mut s, msg);
    s
}

/// Incremental decoder: feed bytes with [`Decoder::push`], take messages with [`Decoder::next_message`].
#[derive(Debug, Default)]
pub struct Decoder {
    buf: Vec<u8>,
    /// Bytes seen outside any `<…>` (other than whitespace), skipped.
    pub garbage_bytes: u64,
    /// Messages that were dropped because they did not parse.
    pub bad_messages: u64,
}

impl Decoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes buffered but not yet consumed.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// The next complete message, `Some(Err)` for one that was malformed (already skipped), `None` when
    /// more bytes are needed.
    pub fn next_message(&mut self) -> Option<Result<Message, CodecError>> {
        // Skip to the next '<', counting what is not whitespace as garbage.
        let start = match self.buf.iter().position(|&c| c == b'<') {
            Some(i) => i,
            None => {
                self.garbage_bytes += count_non_ws(&self.buf);
                self.buf.clear();
                return None;
            }
        };
        if start > 0 {
            self.garbage_bytes += count_non_ws(&self.buf[..start]);
            self.buf.drain(..start);
        }
        // A second '<' before '>' means the first message was cut: drop it and resync there.
        let body = &self.buf[1..];
        let end = body.iter().position(|&c| c == b'>' || c == b'<');
        match end {
            None if body.len() > MAX_MESSAGE_LEN => {
                self.buf.clear();
                self.bad_messages += 1;
                Some(Err(CodecError::TooLong))
            }
            None => None,
            Some(i) if body[i] == b'<' => {
                self.garbage_bytes += (i + 1) as u64;
                self.buf.drain(..=i);
                self.bad_messages += 1;
                Some(Err(CodecError::Malformed {
                    command: String::new(),
                    why: "message interrupted by '<'",
                    text: String::new(),
                }))
            }
            Some(i) => {
                let parsed = if i > MAX_MESSAGE_LEN {
                    Err(CodecError::TooLong)
                } else {
                    match std::str::from_utf8(&body[..i]) {
                        Ok(s) if s.is_ascii() => parse_message(s),
                        _ => Err(CodecError::NotAscii),
                    }
                };
                self.buf.drain(..i + 2);
                if parsed.is_err() {
                    self.bad_messages += 1;
                }
                Some(parsed)
            }
        }
    }
}

fn count_non_ws(b: &[u8]) -> u64 {
    b.iter().filter(|c| !c.is_ascii_whitespace()).count() as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sf(id: u16, d: &[u8]) -> Frame {
        Frame::standard(id, d).unwrap()
    }

    #[test]
    fn parses_python_can_send_forms() {
        // python-can 4.6.1 writes unpadded lower-case bytes, and a double space for empty data
        // (rust-stack.md §4.1).
        assert_eq!(
            parse_message(" send 181 4 1 2 ab 0 ").unwrap(),
            Message::Send(sf(0x181, &[1, 2, 0xab, 0]))
        );
        assert_eq!(
            parse_message(" send 18FF50E5 0  ").unwrap(),
            Message::Send(Frame::extended(0x18FF_50E5, &[]).unwrap())
        );
    }

    #[test]
    fn three_digits_standard_else_extended() {
        let m = parse_message("frame 7FF 1.5 0102").unwrap();
        assert_eq!(
            m,
            Message::Frame {
                frame: sf(0x7FF, &[1, 2]),
                t_s: 1.5
            }
        );
        let m = parse_message("frame 00000181 0.000001 ").unwrap();
        let Message::Frame { frame, .. } = m else {
            panic!("{m:?}")
        };
        assert!(frame.is_extended());
        assert_eq!(frame.raw_id(), 0x181);
        assert!(parse_message("frame 800 1.0 00").is_err());
    }

    #[test]
    fn round_trip_encode_parse() {
        for msg in [
            Message::Send(sf(0x181, &[0xde, 0xad, 0xbe, 0xef])),
            Message::Send(Frame::extended(0x1234_5678, &[]).unwrap()),
            Message::Frame {
                frame: sf(0x701, &[5]),
                t_s: 12.25,
            },
            Message::Open("vcan0".into()),
            Message::Error("could not open bus".into()),
            Message::Error("lagged 12".into()),
            Message::ErrorFrame {
                class: 0x40,
                t_s: 1700000000.25,
            },
        ] {
            let wire = encode(&msg);
            let mut d = Decoder::new();
            d.push(wire.as_bytes());
            assert_eq!(d.next_message().unwrap().unwrap(), msg, "{wire}");
        }
        assert_eq!(
            encode(&Message::Frame {
                frame: sf(0x123, &[0x11, 0x22]),
                t_s: 3.000_001
            }),
            "< frame 123 3.000001 1122 >"
        );
    }

    #[test]
    fn socketcand_error_frames_are_told_from_server_errors() {
        // socketcand state_raw.c: sprintf("< error %03X %lld.%06lld >", class, sec, usec).
        assert_eq!(
            parse_message("error 040 1700000000.000123").unwrap(),
            Message::ErrorFrame {
                class: 0x40,
                t_s: 1_700_000_000.000123
            }
        );
        for text in [
            "error unknown command",
            "error lagged 3",
            "error 040 x",
            "error 040",
        ] {
            assert!(
                matches!(parse_message(text).unwrap(), Message::Error(_)),
                "{text}"
            );
        }
    }

    #[test]
    fn decoder_handles_split_garbage_and_overlong_input() {
        let mut d = Decoder::new();
        d.push(b"xx< h");
        assert!(d.next_message().is_none());
        d.push(b"i >< ok ><< send 1 1 ff >");
        assert_eq!(d.next_message().unwrap().unwrap(), Message::Hi);
        assert_eq!(d.next_message().unwrap().unwrap(), Message::Ok);
        assert!(d.next_message().unwrap().is_err()); // the empty `<` cut by the next `<`
        assert_eq!(
            d.next_message().unwrap().unwrap(),
            Message::Send(sf(1, &[0xff]))
        );
        assert!(d.next_message().is_none());
        assert_eq!(d.garbage_bytes, 3);
        d.push(&[b'<'; 1]);
        d.push(&[b'a'; MAX_MESSAGE_LEN + 1]);
        assert_eq!(d.next_message(), Some(Err(CodecError::TooLong)));
        assert_eq!(d.pending(), 0);
    }

    #[test]
    fn rejects_dlc_mismatch_and_bad_hex() {
        assert!(parse_message("send 181 2 1").is_err());
        assert!(parse_message("send 181 9 1 2 3 4 5 6 7 8 9").is_err());
        assert!(parse_message("send 181 1 zz").is_err());
        assert!(parse_message("send 181 1 123").is_err());
        assert!(parse_message("frame 181 x 00").is_err());
        assert!(parse_message("frame 181 1.0 001").is_err());
    }
}
