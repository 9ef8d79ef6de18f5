//! A fake PLC for the gateway tests: a tokio-modbus TCP server on 127.0.0.1 holding registers in a
//! map, logging every write, optionally acknowledging the strobe like a cooperating PLC program.

use std::collections::HashMap;
use std::future;
use std::sync::{Arc, Mutex};

use tokio::net::TcpListener;
use tokio_modbus::prelude::*;
use tokio_modbus::server::tcp::{Server, accept_tcp_connection};

#[derive(Default)]
pub(crate) struct Plc {
    pub regs: HashMap<u16, u16>,
    /// Every write request: (address, words).
    pub writes: Vec<(u16, Vec<u16>)>,
    /// Every write with the register words it replaced: (address, before, after).
    pub history: Vec<(u16, Vec<u16>, Vec<u16>)>,
    /// Copy the strobe into the ack register (a cooperating PLC).
    pub auto_ack: bool,
}

pub(crate) const STROBE: u16 = 110;
pub(crate) const ACK: u16 = 111;

#[derive(Clone)]
pub(crate) struct Svc(pub Arc<Mutex<Plc>>);

impl tokio_modbus::server::Service for Svc {
    type Request = Request<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        let mut plc = self.0.lock().unwrap();
        let r = match req {
            Request::ReadHoldingRegisters(a, n) => Ok(Response::ReadHoldingRegisters(
                (a..a + n)
                    .map(|k| *plc.regs.get(&k).unwrap_or(&0))
                    .collect(),
            )),
            Request::WriteMultipleRegisters(a, words) => {
                plc.writes.push((a, words.to_vec()));
                let before: Vec<u16> = (a..a + words.len() as u16)
                    .map(|k| *plc.regs.get(&k).unwrap_or(&0))
                    .collect();
                plc.history.push((a, before, words.to_vec()));
                for (k, w) in words.iter().enumerate() {
                    plc.regs.insert(a + k as u16, *w);
                }
                if plc.auto_ack && a == STROBE {
                    let s = words[0];
                    plc.regs.insert(ACK, s);
                }
                Ok(Response::WriteMultipleRegisters(a, words.len() as u16))
            }
            _ => Err(ExceptionCode::IllegalFunction),
        };
        future::ready(r)
    }
}

pub(crate) async fn serve(listener: TcpListener, plc: Arc<Mutex<Plc>>) {
    let server = Server::new(listener);
    let on_connected = move |stream, addr| {
        let svc = Svc(plc.clone());
        async move { accept_tcp_connection(stream, addr, move |_| Ok(Some(svc.clone()))) }
    };
    let _ = server.serve(&on_connected, |_e| {}).await;
}
