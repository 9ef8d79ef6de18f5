//! The PLC's Modbus TCP server, stoppable and restartable on the same port (the `modbus_down`
//! transport fault), with a log of every client write for observers: after each accepted write to the
//! holding block, the simulated time and the three origin-shift registers as they now stand, decoded
//! in µm (register value × `plc.lsb_um`; + moves the slide +, i.e. register = correction), and the
//! client's TCP port (a new port = a new connection: a reconnect or a restarted gateway). The log is
//! written as `plc_writes.csv` next to the recording (`t_s,address,count,x_um,y_um,z_um,client_port`).
//!
//! Stopping drops the listener and every live connection (tokio-modbus cancels its connection tasks
//! when `serve` is dropped); the register bank is kept, so the controller holds its shift across the
//! comms loss, as a real one does.

use crate::config::PlcConfig;
use crate::controller::plc::decode_shift;
use retrocomp_bus::modbus::{RegisterBank, RegisterService};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};
use tokio_modbus::server::Service;

/// The simulated time, shared with the server so writes are stamped on the sim clock.
#[derive(Clone, Debug, Default)]
pub(crate) struct SimClock(Arc<AtomicU64>);

impl SimClock {
    pub(crate) fn set(&self, t_s: f64) {
        self.0.store(t_s.to_bits(), Ordering::Relaxed);
    }
    pub(crate) fn get(&self) -> f64 {
        f64::from_bits(self.0.load(Ordering::Relaxed))
    }
}

/// One accepted client write.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct WriteEvent {
    pub t_s: f64,
    pub address: u16,
    pub count: u16,
    /// The shift registers of x, y, z after the write, µm.
    pub shifts_um: [f64; 3],
    /// The writer's TCP source port.
    pub client_port: u16,
}

impl WriteEvent {
    pub(crate) const CSV_HEADER: &'static str = "t_s,address,count,x_um,y_um,z_um,client_port\n";

    pub(crate) fn csv_row(&self) -> String {
        let [x, y, z] = self.shifts_um;
        format!(
            "{:.4},{},{},{x},{y},{z},{}\n",
            self.t_s, self.address, self.count, self.client_port
        )
    }
}

/// The shift registers of a PLC window (words from address 0), µm.
pub(crate) fn shifts_um(plc: &PlcConfig, window: &[u16]) -> [f64; 3] {
    let words = usize::from(plc.word.words());
    std::array::from_fn(|axis| {
        let a = plc.first_register as usize + axis * words;
        window.get(a..a + words).map_or(f64::NAN, |r| {
            decode_shift(plc.word, plc.word_order, r) as f64 * plc.lsb_um
        })
    })
}

#[derive(Clone)]
struct LoggedService {
    inner: RegisterService,
    plc: PlcConfig,
    window_len: u16,
    clock: SimClock,
    log: mpsc::UnboundedSender<WriteEvent>,
    client_port: u16,
}

impl Service for LoggedService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        let write = match &req.request {
            Request::WriteMultipleRegisters(a, w) => {
                Some((*a, u16::try_from(w.len()).unwrap_or(u16::MAX)))
            }
            Request::WriteSingleRegister(a, _) => Some((*a, 1)),
            _ => None,
        };
        let r = self.inner.call(req).into_inner();
        if let (Some((address, count)), Ok(_)) = (write, &r)
            && let Some(window) = self.inner.bank.holding(0, self.window_len)
        {
            let _ = self.log.send(WriteEvent {
                t_s: self.clock.get(),
                address,
                count,
                shifts_um: shifts_um(&self.plc, &window),
                client_port: self.client_port,
            });
        }
        std::future::ready(r)
    }
}

/// A Modbus TCP server over the PLC's register bank that can go down and come back on its port.
pub(crate) struct PlcServer {
    addr: SocketAddr,
    svc: LoggedService,
    task: Option<JoinHandle<()>>,
}

// By hand: the register service is internal.
impl std::fmt::Debug for PlcServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlcServer")
            .field("addr", &self.addr)
            .field("running", &self.task.is_some())
            .finish_non_exhaustive()
    }
}

impl PlcServer {
    /// Listen on `bind` (port 0 picks one; a restart reuses the port that was picked). Accepted
    /// writes go to `log`.
    pub(crate) async fn start(
        bind: SocketAddr,
        bank: RegisterBank,
        plc: PlcConfig,
        window_len: u16,
        clock: SimClock,
        log: mpsc::UnboundedSender<WriteEvent>,
    ) -> std::io::Result<Self> {
        let svc = LoggedService {
            inner: RegisterService { bank, slave: None },
            plc,
            window_len,
            clock,
            log,
            client_port: 0,
        };
        let listener = TcpListener::bind(bind).await?;
        let addr = listener.local_addr()?;
        let mut s = Self {
            addr,
            svc,
            task: None,
        };
        s.serve(listener);
        Ok(s)
    }

    fn serve(&mut self, listener: TcpListener) {
        let svc = self.svc.clone();
        self.task = Some(tokio::spawn(async move {
            let server = tokio_modbus::server::tcp::Server::new(listener);
            let on_connected = |stream, peer: SocketAddr| {
                let svc = LoggedService {
                    client_port: peer.port(),
                    ..svc.clone()
                };
                async move {
                    tokio_modbus::server::tcp::accept_tcp_connection(stream, peer, |_| {
                        Ok(Some(svc.clone()))
                    })
                }
            };
            let on_err = |e| tracing::debug!("modbus tcp connection: {e}");
            if let Err(e) = server.serve(&on_connected, on_err).await {
                tracing::warn!("modbus tcp server stopped: {e}");
            }
        }));
    }

    pub(crate) fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    pub(crate) fn is_up(&self) -> bool {
        self.task.is_some()
    }

    /// Close the listener and every live connection.
    pub(crate) fn stop(&mut self) {
        if let Some(t) = self.task.take() {
            t.abort();
        }
    }

    /// Listen again on the same address. The port was ours a moment ago (tokio binds with
    /// SO_REUSEADDR, so our own TIME_WAIT sockets do not block it); retried for up to 2 s in case
    /// the abort has not released the listener yet.
    pub(crate) async fn restart(&mut self) -> std::io::Result<()> {
        if self.is_up() {
            return Ok(());
        }
        let mut last = None;
        for _ in 0..100 {
            match TcpListener::bind(self.addr).await {
                Ok(l) => {
                    self.serve(l);
                    return Ok(());
                }
                Err(e) => last = Some(e),
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        Err(last.unwrap_or_else(|| std::io::Error::other("bind failed")))
    }
}

impl Drop for PlcServer {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{DataType, WordOrder};
    use tokio_modbus::client::{Reader, Writer};

    fn plc() -> PlcConfig {
        PlcConfig {
            word: DataType::Int32,
            word_order: WordOrder::HighFirst,
            lsb_um: 0.5,
            ..Default::default()
        }
    }

    #[test]
    fn shift_registers_decode_in_um() {
        let w = [0xFFFF, 0xFFF6, 0, 4, 0, 0, 0];
        assert_eq!(shifts_um(&plc(), &w), [-5.0, 2.0, 0.0]);
        assert!(shifts_um(&plc(), &w[..4])[2].is_nan(), "short window");
    }

    #[tokio::test]
    async fn goes_down_with_its_connections_and_comes_back_on_the_same_port_holding_its_registers()
    {
        let bank = RegisterBank::new();
        bank.set_holding(0, &[0; 6]);
        bank.allow_writes(0, 6);
        let clock = SimClock::default();
        clock.set(1.25);
        let (tx, mut rx) = mpsc::unbounded_channel();
        let bind: SocketAddr = "127.0.0.1:0".parse().unwrap();
        let mut srv = PlcServer::start(bind, bank.clone(), plc(), 6, clock.clone(), tx)
            .await
            .unwrap();
        let addr = srv.local_addr();
        let mut c = tokio_modbus::client::tcp::connect(addr).await.unwrap();
        c.write_multiple_registers(0, &[0, 7])
            .await
            .unwrap()
            .unwrap();
        let ev = rx.try_recv().unwrap();
        assert_eq!((ev.t_s, ev.address, ev.count), (1.25, 0, 2));
        assert_ne!(ev.client_port, 0);
        assert_eq!(ev.shifts_um, [3.5, 0.0, 0.0]);

        srv.stop();
        let r = tokio::time::timeout(Duration::from_secs(2), c.read_holding_registers(0, 2)).await;
        assert!(
            !matches!(r, Ok(Ok(Ok(_)))),
            "a live connection must be dropped: {r:?}"
        );
        assert!(
            tokio_modbus::client::tcp::connect(addr).await.is_err(),
            "nobody listens while down"
        );
        srv.restart().await.unwrap();
        assert_eq!(srv.local_addr(), addr);
        let mut c = tokio_modbus::client::tcp::connect(addr).await.unwrap();
        assert_eq!(
            c.read_holding_registers(0, 2).await.unwrap().unwrap(),
            vec![0, 7],
            "the registers survive the comms loss"
        );
    }
}
