//! A small Modbus server (tokio-modbus) over a shared register image: the simulator serves its
//! PT100/strain channels and its origin-shift registers with it, and the gateway tests read and write it.
//!
//! Supports FC03, FC04, FC06 and FC16. Writes are allowed only to holding registers in the write
//! allow-list, and a multi-register write is applied all-or-nothing under one lock, so a reader never
//! sees half of a 32-bit offset. Unmapped addresses give exception 02 (illegal data address), other
//! function codes exception 01. On TCP every unit id is answered (connections kept by the listener
//! policy, `crate::listen`, framed in `tcp_conn.rs`: writes only from `allow_writes_from`, others get
//! exception 01); on RTU only the configured slave id
//! (others are silent, as on a multi-drop line). Addresses are 0-based protocol addresses.

use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};
use tokio_modbus::server::Service;

use super::tcp_conn;
use crate::listen::{Handler, ListenPolicy, ListenerHealth, Listening, Spec, listen};

#[derive(Debug, Default)]
struct Image {
    holding: BTreeMap<u16, u16>,
    input: BTreeMap<u16, u16>,
    writable: BTreeSet<u16>,
    /// Registers a client has written since the bank was made (the 0 a writable register is
    /// created with is nobody's value).
    written: BTreeSet<u16>,
}

/// The shared register image. Clone it to hand the same registers to the server and to the code that
/// updates or inspects them.
#[derive(Debug, Clone)]
pub struct RegisterBank {
    image: Arc<Mutex<Image>>,
    /// Counts accepted client writes; `changed()` on a receiver wakes on each.
    writes: Arc<watch::Sender<u64>>,
}

impl Default for RegisterBank {
    fn default() -> Self {
        Self::new()
    }
}

impl RegisterBank {
    pub fn new() -> Self {
        RegisterBank {
            image: Arc::default(),
            writes: Arc::new(watch::channel(0).0),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Image> {
        // A panic while holding the lock cannot leave the maps inconsistent (each op is one insert
        // loop), so a poisoned lock is still usable.
        self.image.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Set holding registers from `addr` on (creating them). Not subject to the allow-list: this is
    /// the device's own side.
    pub fn set_holding(&self, addr: u16, words: &[u16]) {
        let mut im = self.lock();
        for (k, w) in (0u16..).zip(words) {
            im.holding.insert(addr.wrapping_add(k), *w);
        }
    }

    /// Remove `count` holding registers from `addr` on: reads of them get exception 02 again (a
    /// served value the device withdraws).
    pub fn clear_holding(&self, addr: u16, count: u16) {
        let mut im = self.lock();
        for i in 0..count {
            im.holding.remove(&addr.wrapping_add(i));
        }
    }

    pub fn set_input(&self, addr: u16, words: &[u16]) {
        let mut im = self.lock();
        for (k, w) in (0u16..).zip(words) {
            im.input.insert(addr.wrapping_add(k), *w);
        }
    }

    /// Let clients write `count` holding registers from `addr` (they are created as 0 if absent).
    pub fn allow_writes(&self, addr: u16, count: u16) {
        let mut im = self.lock();
        for a in addr..addr.saturating_add(count) {
            im.writable.insert(a);
            im.holding.entry(a).or_insert(0);
        }
    }

    pub fn holding(&self, addr: u16, count: u16) -> Option<Vec<u16>> {
        read(&self.lock().holding, addr, count).ok()
    }

    /// [`Self::holding`] into `out` (`out.len()` registers from `addr`) without allocating; false
    /// when any of them does not exist.
    pub fn holding_into(&self, addr: u16, out: &mut [u16]) -> bool {
        let im = self.lock();
        for (i, w) in out.iter_mut().enumerate() {
            let Some(v) = u16::try_from(i)
                .ok()
                .and_then(|i| addr.checked_add(i))
                .and_then(|a| im.holding.get(&a))
            else {
                return false;
            };
            *w = *v;
        }
        true
    }

    /// [`Self::holding_into`], but only registers a client has written (a writable register the
    /// client has not written yet reads as absent, not as its initial 0): what a device takes as
    /// the client's report.
    pub fn client_written_into(&self, addr: u16, out: &mut [u16]) -> bool {
        let im = self.lock();
        for (i, w) in out.iter_mut().enumerate() {
            let Some(v) = u16::try_from(i)
                .ok()
                .and_then(|i| addr.checked_add(i))
                .filter(|a| im.written.contains(a))
                .and_then(|a| im.holding.get(&a))
            else {
                return false;
            };
            *w = *v;
        }
        true
    }

    /// Read `count` holding registers, let `f` change them, write them back, all under one lock (a
    /// device's scan: no client write lands between its read and its write-back).
    pub fn update_holding<R>(
        &self,
        addr: u16,
        count: u16,
        f: impl FnOnce(&mut [u16]) -> R,
    ) -> Option<R> {
        let mut im = self.lock();
        let mut words = read(&im.holding, addr, count).ok()?;
        let r = f(&mut words);
        for (k, w) in (0u16..).zip(words) {
            im.holding.insert(addr.wrapping_add(k), w);
        }
        Some(r)
    }

    pub fn input(&self, addr: u16, count: u16) -> Option<Vec<u16>> {
        read(&self.lock().input, addr, count).ok()
    }

    /// A receiver of the count of accepted client writes.
    pub fn subscribe_writes(&self) -> watch::Receiver<u64> {
        self.writes.subscribe()
    }

    /// Apply a client write: all registers must be in the allow-list, else nothing changes.
    pub fn client_write(&self, addr: u16, words: &[u16]) -> Result<(), ExceptionCode> {
        if words.is_empty() || usize::from(addr) + words.len() > 0x1_0000 {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        {
            let mut im = self.lock();
            // Every address must exist: one past u16::MAX is not writable either.
            let Ok(n) = u16::try_from(words.len()) else {
                return Err(ExceptionCode::IllegalDataAddress);
            };
            let writable = |k: u16| {
                addr.checked_add(k)
                    .is_some_and(|a| im.writable.contains(&a))
            };
            if !(0..n).all(writable) {
                return Err(ExceptionCode::IllegalDataAddress);
            }
            for (k, w) in (0u16..).zip(words) {
                im.holding.insert(addr + k, *w);
                im.written.insert(addr + k);
            }
        }
        self.writes.send_modify(|n| *n += 1);
        Ok(())
    }

    /// Answer one request (the sans-IO core of the service).
    pub fn handle(&self, req: &Request<'_>) -> Result<Response, ExceptionCode> {
        match req {
            Request::ReadHoldingRegisters(a, n) => {
                read(&self.lock().holding, *a, *n).map(Response::ReadHoldingRegisters)
            }
            Request::ReadInputRegisters(a, n) => {
                read(&self.lock().input, *a, *n).map(Response::ReadInputRegisters)
            }
            Request::WriteSingleRegister(a, w) => self
                .client_write(*a, &[*w])
                .map(|()| Response::WriteSingleRegister(*a, *w)),
            Request::WriteMultipleRegisters(a, ws) => self.client_write(*a, ws).map(|()| {
                // client_write refused more words than addresses.
                let n = u16::try_from(ws.len()).unwrap_or(u16::MAX);
                Response::WriteMultipleRegisters(*a, n)
            }),
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

fn read(map: &BTreeMap<u16, u16>, addr: u16, count: u16) -> Result<Vec<u16>, ExceptionCode> {
    if count == 0 || count > 125 {
        return Err(ExceptionCode::IllegalDataValue);
    }
    (0..count)
        .map(|i| {
            addr.checked_add(i)
                .and_then(|a| map.get(&a).copied())
                .ok_or(ExceptionCode::IllegalDataAddress)
        })
        .collect()
}

/// tokio-modbus service over a [`RegisterBank`]. `slave = None` answers every unit id (TCP).
#[derive(Debug, Clone)]
pub struct RegisterService {
    pub bank: RegisterBank,
    pub slave: Option<u8>,
}

impl Service for RegisterService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        let for_us = match self.slave {
            None => true,
            // Unit 0 is broadcast: writes apply, nobody answers.
            Some(s) => req.slave == s || req.slave == 0,
        };
        if !for_us {
            return std::future::ready(Ok(None));
        }
        let r = self.bank.handle(&req.request);
        if self.slave.is_some() && req.slave == 0 {
            return std::future::ready(Ok(None));
        }
        std::future::ready(r.map(Some))
    }
}

/// A running Modbus TCP server on the listener policy (`crate::listen`): connection caps, idle
/// timeout, descriptor reserve, accept backoff, restart; writes only from `allow_writes_from`.
/// Dropping it stops the listener and every connection.
#[derive(Debug)]
pub struct TcpServer {
    listening: Listening,
}

impl TcpServer {
    /// Serve `bank` on `addr` (tests: `127.0.0.1:0`) with the default policy (writes from loopback).
    pub async fn start(addr: SocketAddr, bank: RegisterBank) -> std::io::Result<TcpServer> {
        Self::start_with(addr, bank, ListenPolicy::default()).await
    }

    /// Serve `bank` on `addr` with `policy`.
    pub async fn start_with(
        addr: SocketAddr,
        bank: RegisterBank,
        policy: ListenPolicy,
    ) -> std::io::Result<TcpServer> {
        let handler: Handler = Arc::new(move |conn| Box::pin(tcp_conn::serve(conn, bank.clone())));
        let spec = Spec {
            name: "modbus_server",
            policy,
            refusal: b"",
            handler,
        };
        Ok(TcpServer {
            listening: listen(addr, spec).await?,
        })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.listening.addr
    }

    /// The listener's faults (refusals, restarts, writes refused from peers).
    pub fn health(&self) -> &ListenerHealth {
        &self.listening.health
    }
}

/// Serve `bank` as RTU slave `slave` on a serial stream (a pty in tests). Abort the handle to stop.
pub fn spawn_rtu(
    serial: tokio_serial::SerialStream,
    bank: RegisterBank,
    slave: u8,
) -> JoinHandle<std::io::Result<()>> {
    let server = tokio_modbus::server::rtu::Server::new(serial);
    tokio::spawn(server.serve_forever(RegisterService {
        bank,
        slave: Some(slave),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::borrow::Cow;

    /// A writable register reads 0 before any client wrote it, but that 0 is not a client's
    /// report: only registers a client wrote count, the device's own writes do not.
    #[test]
    fn only_what_a_client_wrote_is_its_report() {
        let b = RegisterBank::new();
        b.allow_writes(20, 4);
        let mut two = [9u16; 2];
        assert!(b.holding_into(20, &mut two), "readable as 0");
        assert!(!b.client_written_into(20, &mut two), "nobody wrote it");
        assert!(b.handle(&Request::WriteSingleRegister(20, 7)).is_ok());
        assert!(!b.client_written_into(20, &mut two), "21 still unwritten");
        let mut one = [0u16; 1];
        assert!(b.client_written_into(20, &mut one));
        assert_eq!(one, [7]);
        b.set_holding(22, &[1, 2]);
        assert!(
            !b.client_written_into(22, &mut two),
            "the device's own write"
        );
        assert!(b.client_write(21, &[5, 6, 8]).is_ok());
        let mut four = [0u16; 4];
        assert!(b.client_written_into(20, &mut four));
        assert_eq!(four, [7, 5, 6, 8]);
    }

    #[test]
    fn reads_writes_and_exceptions() {
        let b = RegisterBank::new();
        b.set_input(0, &[235, 236]);
        b.allow_writes(100, 2);
        assert_eq!(
            b.handle(&Request::ReadInputRegisters(0, 2)),
            Ok(Response::ReadInputRegisters(vec![235, 236]))
        );
        assert_eq!(
            b.handle(&Request::ReadInputRegisters(1, 2)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            b.handle(&Request::ReadHoldingRegisters(0, 1)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        let w = Request::WriteMultipleRegisters(100, Cow::Owned(vec![0xFFFF, 0xFFFE]));
        assert!(b.handle(&w).is_ok());
        assert_eq!(b.holding(100, 2), Some(vec![0xFFFF, 0xFFFE]));
        // 101..103 is partly outside the allow-list: nothing is written.
        let w = Request::WriteMultipleRegisters(101, Cow::Owned(vec![1, 2]));
        assert_eq!(b.handle(&w), Err(ExceptionCode::IllegalDataAddress));
        assert_eq!(b.holding(100, 2), Some(vec![0xFFFF, 0xFFFE]));
        // The allocation-free read gives the same words, and false past the last register.
        let mut two = [0u16; 2];
        assert!(b.holding_into(100, &mut two));
        assert_eq!(two, [0xFFFF, 0xFFFE]);
        assert!(!b.holding_into(101, &mut two));
        assert_eq!(b.holding(101, 2), None);
        assert_eq!(*b.subscribe_writes().borrow(), 1);
        assert_eq!(
            b.handle(&Request::ReadCoils(0, 1)),
            Err(ExceptionCode::IllegalFunction)
        );
    }
}
