//! `CanBus` over TCP with the socketcand rawmode protocol: joins a real socketcand daemon (which serves
//! a physical or virtual CAN interface) or the in-process [`super::hub::Hub`].
//!
//! `recv` is cancel-safe (bytes read are kept in the decoder), so it can sit in a `tokio::select!`
//! next to a timer that sends. Received timestamps are the server's, in seconds.

use super::bus_state::{BusErrors, ErrorFrame};
use super::socketcand::{Decoder, Message, encode_into};
use super::{CanBus, CanError, Frame};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpStream, ToSocketAddrs};

/// The socketcand default TCP port.
pub(crate) const DEFAULT_PORT: u16 = 29536;

/// How long the handshake may take before `connect` gives up.
pub(crate) const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

#[derive(Debug)]
pub struct SocketcandBus {
    stream: TcpStream,
    dec: Decoder,
    out: String,
    /// `< error … >` messages received from the server (e.g. `lagged N` from the hub).
    pub server_errors: u64,
    /// Malformed messages received and skipped.
    pub bad_messages: u64,
    /// Bus state from the server's forwarded error frames.
    errors: BusErrors,
}

impl SocketcandBus {
    /// Connect and complete the rawmode handshake on `bus` (e.g. `can0`, `vcan0`).
    pub async fn connect(addr: impl ToSocketAddrs, bus: &str) -> Result<Self, CanError> {
        if bus.is_empty() || bus.contains(|c: char| c.is_whitespace() || c == '<' || c == '>') {
            return Err(CanError::Protocol(format!("invalid bus name `{bus}`")));
        }
        let stream = TcpStream::connect(addr).await?;
        stream.set_nodelay(true)?;
        let mut me = SocketcandBus {
            stream,
            dec: Decoder::new(),
            out: String::with_capacity(64),
            server_errors: 0,
            bad_messages: 0,
            errors: BusErrors::default(),
        };
        tokio::time::timeout(HANDSHAKE_TIMEOUT, me.handshake(bus))
            .await
            .map_err(|_| CanError::Protocol("socketcand handshake timed out".into()))??;
        Ok(me)
    }

    async fn handshake(&mut self, bus: &str) -> Result<(), CanError> {
        self.expect(Message::Hi, "greeting `< hi >`").await?;
        self.write(&Message::Open(bus.to_string())).await?;
        self.expect(Message::Ok, "`< ok >` after open").await?;
        self.write(&Message::RawMode).await?;
        self.expect(Message::Ok, "`< ok >` after rawmode").await
    }

    async fn next_message(&mut self) -> Result<Message, CanError> {
        loop {
            while let Some(m) = self.dec.next_message() {
                match m {
                    Ok(m) => return Ok(m),
                    Err(_) => self.bad_messages += 1,
                }
            }
            let mut buf = [0u8; 4096];
            let n = self.stream.read(&mut buf).await?;
            if n == 0 {
                return Err(CanError::Closed);
            }
            self.dec.push(&buf[..n]);
        }
    }

    async fn expect(&mut self, want: Message, what: &str) -> Result<(), CanError> {
        match self.next_message().await? {
            m if m == want => Ok(()),
            Message::Error(e) => Err(CanError::Protocol(format!(
                "socketcand server refused: {e} (expected {what})"
            ))),
            m => Err(CanError::Protocol(format!(
                "socketcand: expected {what}, got {m:?}"
            ))),
        }
    }

    async fn write(&mut self, msg: &Message) -> Result<(), CanError> {
        self.out.clear();
        encode_into(&mut self.out, msg);
        self.stream.write_all(self.out.as_bytes()).await?;
        Ok(())
    }

    /// Send several frames in one write (used by benchmarks and bursty senders).
    pub async fn send_all(&mut self, frames: &[Frame]) -> Result<(), CanError> {
        self.out.clear();
        for f in frames {
            encode_into(&mut self.out, &Message::Send(*f));
        }
        self.stream.write_all(self.out.as_bytes()).await?;
        Ok(())
    }

    /// The next frame with the server's timestamp in seconds. Cancel-safe.
    pub async fn recv_timestamped(&mut self) -> Result<(Frame, f64), CanError> {
        loop {
            if let Some(got) = self.recv_timestamped_event().await? {
                return Ok(got);
            }
        }
    }

    /// The next frame with the server's timestamp, or `None` after an error frame. Cancel-safe.
    async fn recv_timestamped_event(&mut self) -> Result<Option<(Frame, f64)>, CanError> {
        loop {
            match self.next_message().await? {
                Message::Frame { frame, t_s } => {
                    self.errors.handle_frame();
                    return Ok(Some((frame, t_s)));
                }
                Message::ErrorFrame { class, .. } => {
                    self.errors
                        .handle_error_frame(&ErrorFrame::class_only(class));
                    return Ok(None);
                }
                Message::Error(_) => self.server_errors += 1,
                _ => {}
            }
        }
    }
}

impl CanBus for SocketcandBus {
    /// What the server's error frames said about the bus since it was opened.
    fn bus_errors(&self) -> BusErrors {
        self.errors
    }

    async fn send(&mut self, frame: &Frame) -> Result<(), CanError> {
        self.write(&Message::Send(*frame)).await
    }

    async fn recv(&mut self) -> Result<Frame, CanError> {
        self.recv_timestamped().await.map(|(f, _)| f)
    }

    async fn recv_event(&mut self) -> Result<Option<Frame>, CanError> {
        Ok(self.recv_timestamped_event().await?.map(|(f, _)| f))
    }
}
