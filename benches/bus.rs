//! Bus benchmarks (issue 4, item 8):
//! - `pdo_decode`: CiA 406 position TPDOs → samples through `CanopenSource` (target ≥ 1 M frames/s);
//! - `hub_loopback`: frames from one socketcand client through the hub to another on loopback
//!   (target ≥ 50 k frames/s);
//! - `modbus_tcp_poll16`: one poll of 16 int16 temperatures from the Rust register server on loopback;
//!   criterion reports mean/median, and the bench also prints median and p99 of 2000 polls.
//!
//! Run: `cargo bench --bench bus`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use retrocomp_bus::ChannelTable;
use retrocomp_bus::can::{CanBus, Frame, Hub, SocketcandBus};
use retrocomp_bus::canopen::{CanopenConfig, CanopenSource, CountingDirection, EncoderChannel};
use retrocomp_bus::modbus::{
    DataType, ModbusPoller, ModbusSourceConfig, Parity, RegisterBank, RegisterChannel,
    RegisterTable, TcpServer, TransportKind, WordOrder,
};
use std::hint::black_box;
use std::time::{Duration, Instant};

fn encoder(name: &str, node: u8) -> EncoderChannel {
    EncoderChannel {
        channel: name.into(),
        node_id: node,
        tpdo: 1,
        byte_offset: 0,
        counts_per_mm: 1000.0,
        direction: CountingDirection::Positive,
        offset_mm: 0.0,
        total_range_counts: Some(1 << 25),
        cyclic_ms: None,
        min_mm: None,
        max_mm: None,
    }
}

fn pdo_decode(c: &mut Criterion) {
    let encs = vec![encoder("x_mm", 1), encoder("y_mm", 2), encoder("z_mm", 3)];
    let frames: Vec<Frame> = (0..3000)
        .map(|i| encs[i % 3].encode_position(i as f64 * 0.013).unwrap())
        .collect();
    let mut src = CanopenSource::new(
        CanopenConfig {
            encoder: encs,
            ..CanopenConfig::default()
        },
        &mut ChannelTable::default(),
    );
    let mut out = Vec::with_capacity(frames.len());
    let mut g = c.benchmark_group("pdo_decode");
    g.throughput(Throughput::Elements(frames.len() as u64));
    g.bench_function("cia406_3_axes", |b| {
        b.iter(|| {
            out.clear();
            for (i, f) in frames.iter().enumerate() {
                src.handle_frame(black_box(f), i as f64 * 1e-4, &mut out);
            }
            black_box(out.len())
        });
    });
    g.finish();
}

fn hub_loopback(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (_hub, mut tx, mut rx) = rt.block_on(async {
        let hub = Hub::start_loopback().await.unwrap();
        let tx = SocketcandBus::connect(hub.local_addr(), "can0")
            .await
            .unwrap();
        let rx = SocketcandBus::connect(hub.local_addr(), "can0")
            .await
            .unwrap();
        (hub, tx, rx)
    });
    const N: usize = 5000;
    let frames: Vec<Frame> = (0..N)
        .map(|i| Frame::standard(0x181, &(i as u32).to_le_bytes()).unwrap())
        .collect();
    let mut g = c.benchmark_group("hub_loopback");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(20);
    g.bench_function("socketcand_5000_frames", |b| {
        b.iter(|| {
            rt.block_on(async {
                // Send in bursts of 100 frames per write (a busy bus delivers frames back to back),
                // receiving concurrently so no queue overflows.
                let send = async {
                    for chunk in frames.chunks(100) {
                        tx.send_all(chunk).await.unwrap();
                    }
                };
                let recv = async {
                    for _ in 0..N {
                        black_box(rx.recv().await.unwrap());
                    }
                };
                tokio::join!(send, recv);
            });
        });
    });
    g.finish();
    // Per-frame sends (one write each), for comparison.
    let mut g = c.benchmark_group("hub_loopback");
    g.throughput(Throughput::Elements(1000));
    g.sample_size(10);
    g.bench_function("socketcand_1000_single_sends", |b| {
        b.iter(|| {
            rt.block_on(async {
                let send = async {
                    for f in &frames[..1000] {
                        tx.send(f).await.unwrap();
                    }
                };
                let recv = async {
                    for _ in 0..1000 {
                        black_box(rx.recv().await.unwrap());
                    }
                };
                tokio::join!(send, recv);
            });
        });
    });
    g.finish();
}

fn modbus_poll(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (_srv, mut poller) = rt.block_on(async {
        let bank = RegisterBank::new();
        bank.set_input(0, &(0..16).map(|i| 200 + i).collect::<Vec<u16>>());
        let srv = TcpServer::start("127.0.0.1:0".parse().unwrap(), bank)
            .await
            .unwrap();
        let cfg = ModbusSourceConfig {
            name: "pt100".into(),
            transport: TransportKind::Tcp,
            host: Some("127.0.0.1".into()),
            port: srv.local_addr().port(),
            device: None,
            baud: 9600,
            parity: Parity::None,
            unit_id: 1,
            period_s: 1.0,
            timeout_s: 1.0,
            backoff_min_s: 0.1,
            backoff_max_s: 1.0,
            max_gap: 0,
            channel: (0..16)
                .map(|i| RegisterChannel {
                    channel: format!("T{i}_C"),
                    kind: RegisterTable::Input,
                    address: i,
                    data_type: DataType::Int16,
                    word_order: WordOrder::HighFirst,
                    scale: 0.1,
                    offset: 0.0,
                    min: None,
                    max: None,
                })
                .collect(),
        };
        (srv, ModbusPoller::new(cfg, &mut ChannelTable::default()))
    });
    let mut out = Vec::with_capacity(16);
    c.bench_function("modbus_tcp_poll16", |b| {
        b.iter(|| {
            rt.block_on(async {
                out.clear();
                poller.poll_once(0.0, &mut out).await;
            });
            assert_eq!(out.len(), 16);
        });
    });
    // Latency distribution (criterion reports central estimates, not tails).
    let mut d: Vec<Duration> = (0..2000)
        .map(|_| {
            let t = Instant::now();
            rt.block_on(async {
                out.clear();
                poller.poll_once(0.0, &mut out).await;
            });
            t.elapsed()
        })
        .collect();
    d.sort();
    println!(
        "modbus_tcp_poll16 latency over 2000 polls: median {:?}, p99 {:?}, max {:?}",
        d[d.len() / 2],
        d[d.len() * 99 / 100],
        d[d.len() - 1]
    );
    assert_eq!(poller.counters().timeouts, 0);
}

criterion_group!(benches, pdo_decode, hub_loopback, modbus_poll);
criterion_main!(benches);
