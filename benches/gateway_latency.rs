//! Frame receipt → register write latency on loopback (issue 5 item 8), the whole gateway path:
//! a CiA 406 encoder TPDO sent into an in-process socketcand hub on 127.0.0.1 → the gateway's CAN
//! source (socketcand client, CANopen decode) → sample channel → engine cycle (every `cycle_ms`
//! = 1 ms) → outputs → origin-shift sink (writes every `write_period_ms` = 1 ms) → one FC16 over
//! Modbus TCP → a register server on 127.0.0.1, timestamped when it handles the write.
//!
//! Each sample moves X between 0 and 0.5 mm, so the correction (model: e_x = 1 µm/mm · x) flips
//! between 0 and −0.5 µm: inside the 1 µm/cycle cap, 5 LSB of 0.1 µm, so every sample changes the
//! registers and the latency is "send → first write whose words differ from before". Every await
//! has a timeout: a stalled pipeline fails the bench (a panic naming the step) instead of hanging.
//!
//! The encoder sends at most every [`SOURCE_PERIOD`] (2 ms: a 500 Hz TPDO, slower than the 1 ms
//! cycle, as the field config expects of a source), so each frame finds the cycle free to run
//! when it arrives ([`retrocomp_gateway::pacer`]) and the sink free to write when the cycle's
//! output changes: the figure is the path, not the wait for two unrelated clocks.
//!
//! Printed besides criterion's mean: p50/p99 over 2000 samples of the whole path, and of its two
//! transports alone (the hub hop: send → another hub client receives; one Modbus FC16: client call
//! → server sees it), so the rest is the cycle and write-period waits (each uniform in 0–1 ms) and
//! the in-process hand-offs.
//!
//! Run: `cargo bench -p retrocomp --bench gateway_latency`.

use std::future;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use retrocomp_bus::can::{CanBus, Frame, Hub, SocketcandBus};
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::sources::spawn_sources;
use retrocomp_gateway::{AxisErrors, ErrorModel, MachineState};
use tokio::net::TcpListener;
use tokio::runtime::Runtime;
use tokio::sync::{oneshot, watch};
use tokio_modbus::prelude::*;
use tokio_modbus::server::tcp::{Server, accept_tcp_connection};

/// The encoder's fastest send rate (a 500 Hz TPDO).
const SOURCE_PERIOD: Duration = Duration::from_millis(2);
/// Any single step longer than this is a stall.
const STEP_TIMEOUT: Duration = Duration::from_secs(2);
const SAMPLES: usize = 2000;

async fn within<T>(what: &str, f: impl Future<Output = T>) -> T {
    match tokio::time::timeout(STEP_TIMEOUT, f).await {
        Ok(v) => v,
        Err(_) => panic!("{what}: no progress within {STEP_TIMEOUT:?} (pipeline stalled)"),
    }
}

/// e_x = 1 µm/mm · x.
struct Linear(Arc<str>);

impl ErrorModel for Linear {
    fn required_channels(&self) -> Vec<Arc<str>> {
        Vec::new()
    }
    fn axis_errors(
        &mut self,
        s: &MachineState,
        out: &mut AxisErrors,
    ) -> Result<(), retrocomp_gateway::engine::ModelError> {
        let x = s.position_mm(retrocomp_model::Axis::X).unwrap_or(0.0);
        out.push(retrocomp_model::Axis::X, self.0.clone(), x);
        Ok(())
    }
}

/// The last write the register server handled: its words at address 0..2 and when.
#[derive(Clone, Copy, Debug)]
struct Seen {
    writes: u64,
    words: [u16; 2],
    at: Instant,
}

#[derive(Clone)]
struct Registers(Arc<Mutex<[u16; 2]>>, Arc<watch::Sender<Seen>>);

impl tokio_modbus::server::Service for Registers {
    type Request = Request<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        let at = Instant::now();
        let mut regs = self.0.lock().unwrap();
        future::ready(match req {
            Request::ReadHoldingRegisters(a, n) => Ok(Response::ReadHoldingRegisters(
                (a..a + n)
                    .map(|k| regs.get(k as usize).copied().unwrap_or(0))
                    .collect(),
            )),
            Request::WriteMultipleRegisters(a, words) => {
                for (k, w) in words.iter().enumerate() {
                    if let Some(r) = regs.get_mut(a as usize + k) {
                        *r = *w;
                    }
                }
                let words_now = *regs;
                self.1.send_modify(|s| {
                    s.writes += 1;
                    s.words = words_now;
                    s.at = at;
                });
                Ok(Response::WriteMultipleRegisters(a, words.len() as u16))
            }
            _ => Err(ExceptionCode::IllegalFunction),
        })
    }
}

async fn register_server() -> (std::net::SocketAddr, watch::Receiver<Seen>) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = watch::channel(Seen {
        writes: 0,
        words: [0; 2],
        at: Instant::now(),
    });
    let svc = Registers(Arc::new(Mutex::new([0; 2])), Arc::new(tx));
    tokio::spawn(async move {
        let server = Server::new(listener);
        let on_connected = move |stream, addr| {
            let svc = svc.clone();
            async move { accept_tcp_connection(stream, addr, move |_| Ok(Some(svc.clone()))) }
        };
        let _ = server.serve(&on_connected, |_e| {}).await;
    });
    (addr, rx)
}

fn field(hub: std::net::SocketAddr, plc: std::net::SocketAddr) -> String {
    format!(
        r#"
[gateway]
name = "latency"
cycle_ms = 1
thermal_period_s = 1.0
status_listen = "127.0.0.1:0"
[safety]
max_correction_um = 100.0
max_change_um_per_cycle = 1.0
ramp_um_per_s = 1000.0
stale_hold_s = 3600.0
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
[[channel]]
name = "x_mm"
min = -1000.0
max = 1000.0
stale_after_s = 3600.0
[can]
backend = "socketcand"
host = "127.0.0.1"
port = {}
channel = "can0"
[canopen]
pdo_timeout_s = 3600.0
encoder = [ {{ channel = "x_mm", node_id = 1, counts_per_mm = 1000.0 }} ]
[sink.origin_shift]
transport = {{ kind = "tcp", address = "{plc}" }}
write_period_ms = 1
[sink.origin_shift.map]
[[sink.origin_shift.map.axis]]
axis = "x"
address = 0
kind = "int32"
lsb_um = 0.1
sign = 1
"#,
        hub.port()
    )
}

fn encoder_frame(x_mm: f64) -> Frame {
    let counts = (x_mm * 1000.0).round() as i32 as u32;
    Frame::standard(0x181, &counts.to_le_bytes()).unwrap()
}

/// The gateway running against the hub and the register server.
struct Rig {
    can: SocketcandBus,
    seen: watch::Receiver<Seen>,
    x_mm: f64,
    /// The encoder's next send, not before ([`SOURCE_PERIOD`] after the last).
    next_send: Instant,
    stop: Option<oneshot::Sender<()>>,
    gateway: tokio::task::JoinHandle<
        Result<retrocomp_gateway::run::RunSummary, retrocomp_gateway::error::GatewayError>,
    >,
    _hub: Hub,
}

impl Rig {
    async fn start() -> Rig {
        let hub = within("hub start", Hub::start_loopback()).await.unwrap();
        let (plc, seen) = register_server().await;
        let text = field(hub.local_addr(), plc);
        let cfg = FieldConfig::parse(&text, Path::new("latency.toml")).unwrap();
        let epoch = Instant::now();
        let rx = within("sources", spawn_sources(&cfg, epoch)).await.unwrap();
        let (stop, stop_rx) = oneshot::channel::<()>();
        let gateway = tokio::spawn(retrocomp_gateway::run::run(
            cfg,
            Box::new(Linear("linear".into())),
            rx,
            epoch,
            async move {
                let _ = stop_rx.await;
            },
            None,
        ));
        let can = within(
            "can client",
            SocketcandBus::connect(hub.local_addr(), "can0"),
        )
        .await
        .unwrap();
        let mut rig = Rig {
            can,
            seen,
            x_mm: 0.0,
            next_send: Instant::now(),
            stop: Some(stop),
            gateway,
            _hub: hub,
        };
        // The gateway is up once it writes; then let the compensation ramp in and settle.
        for _ in 0..200 {
            rig.one().await;
        }
        rig
    }

    /// One sample: send the next position, wait for the write that carries its correction.
    async fn one(&mut self) -> Duration {
        self.x_mm = if self.x_mm == 0.0 { 0.5 } else { 0.0 };
        let before = self.seen.borrow_and_update().words;
        let frame = encoder_frame(self.x_mm);
        tokio::time::sleep_until(self.next_send.into()).await;
        let t0 = Instant::now();
        self.next_send = t0 + SOURCE_PERIOD;
        within("CAN send", self.can.send(&frame)).await.unwrap();
        loop {
            within("register write", self.seen.changed()).await.unwrap();
            let s = *self.seen.borrow_and_update();
            if s.words != before {
                return s.at.saturating_duration_since(t0);
            }
        }
    }

    async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        let _ = within("gateway stop", self.gateway).await;
    }
}

/// Transport alone: hub hop (send → another client of the hub receives).
async fn can_hop_samples(n: usize) -> Vec<Duration> {
    let hub = within("hub start", Hub::start_loopback()).await.unwrap();
    let mut a = within("a", SocketcandBus::connect(hub.local_addr(), "can0"))
        .await
        .unwrap();
    let mut b = within("b", SocketcandBus::connect(hub.local_addr(), "can0"))
        .await
        .unwrap();
    let mut v = Vec::with_capacity(n);
    for k in 0..n {
        let t0 = Instant::now();
        within("hop send", a.send(&encoder_frame(k as f64 * 1e-3)))
            .await
            .unwrap();
        within("hop recv", b.recv()).await.unwrap();
        v.push(t0.elapsed());
    }
    v
}

/// Transport alone: one FC16 of two registers (client call → the server handles it).
async fn modbus_write_samples(n: usize) -> Vec<Duration> {
    let (addr, mut seen) = register_server().await;
    let mut ctx = within("modbus connect", tcp::connect_slave(addr, Slave(1)))
        .await
        .unwrap();
    let mut v = Vec::with_capacity(n);
    for k in 0..n {
        let t0 = Instant::now();
        within(
            "modbus write",
            ctx.write_multiple_registers(0, &[0, k as u16]),
        )
        .await
        .unwrap()
        .unwrap();
        let s = *seen.borrow_and_update();
        v.push(s.at.saturating_duration_since(t0));
    }
    v
}

fn summary(name: &str, mut v: Vec<Duration>) {
    v.sort_unstable();
    let pct = |p: f64| v[((v.len() - 1) as f64 * p) as usize].as_secs_f64() * 1e6;
    eprintln!(
        "{name}: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} samples",
        pct(0.5),
        pct(0.99),
        v.last().unwrap().as_secs_f64() * 1e6,
        v.len()
    );
}

fn frame_to_register_write(c: &mut Criterion) {
    let rt: Runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    summary(
        "transport: socketcand hub hop",
        rt.block_on(can_hop_samples(SAMPLES)),
    );
    summary(
        "transport: Modbus TCP FC16 (client call → server)",
        rt.block_on(modbus_write_samples(SAMPLES)),
    );
    let mut rig = rt.block_on(Rig::start());
    let mut v = Vec::with_capacity(SAMPLES);
    for _ in 0..SAMPLES {
        v.push(rt.block_on(rig.one()));
    }
    summary(
        "frame → register write (cycle 1 ms, write period 1 ms, encoder ≤ 500 Hz)",
        v,
    );
    let mut g = c.benchmark_group("gateway_latency");
    g.sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(8));
    g.bench_function("can_frame_to_modbus_write", |b| {
        b.iter_custom(|iters| {
            rt.block_on(async {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    total += rig.one().await;
                }
                total
            })
        });
    });
    g.finish();
    rt.block_on(rig.stop());
}

criterion_group!(benches, frame_to_register_write);
criterion_main!(benches);
