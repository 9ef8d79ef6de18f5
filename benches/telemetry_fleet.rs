//! Fleet load benchmark (not criterion: a capacity search, not a latency estimate): N simulated
//! boxes publish Sparkplug B through the same publisher as `retrocomp run` (src/telemetry) to one
//! Mosquitto on loopback, and one subscriber (rumqttc, QoS 1) counts every NDATA per edge node and
//! checks its seq. A box is lightweight: a task that updates a status snapshot at twice the
//! telemetry rate (so every sampler tick has a change to send) instead of a whole gateway.
//! For each (boxes, rate) step it reports records produced (the publishers' own counters),
//! received, lost (produced − received after a drain), seq gaps, and the broker's CPU share.
//!
//! Run: `cargo bench --bench telemetry_fleet` (release; add `-- 50x10 200x10 400x10` for other
//! steps, `--seconds S` for the window). Needs mosquitto (scripts/setup-peers.sh).

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use retrocomp::gateway::status::{AxisStatus, StatusSnapshot};
use retrocomp::gateway::{Direction, Mode};
use retrocomp::telemetry::sparkplug::Payload;
use retrocomp::telemetry::{self, MqttConfig, PublisherInputs};
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
use tokio::sync::watch;

const GROUP: &str = "fleet";

fn snapshot(k: u64) -> StatusSnapshot {
    let axes = ["x", "y", "z"]
        .iter()
        .map(|a| AxisStatus {
            axis: a.to_string(),
            position_mm: Some(k as f64 * 0.5),
            direction: Direction::Forward,
            weight_forward: 1.0,
            target_um: Some(-(k as f64 % 50.0)),
            applied_um: -(k as f64 % 50.0),
            mode: Mode::Tracking,
            terms_um: BTreeMap::from([
                ("geometric".to_string(), -(k as f64 % 30.0)),
                ("thermal".to_string(), -(k as f64 % 20.0)),
            ]),
            clamp_hits: 0,
            cap_hits: 0,
        })
        .collect();
    StatusSnapshot {
        t_s: k as f64 * 0.001,
        cycles: k,
        enabled: true,
        axes,
        channels: BTreeMap::new(),
        active_faults: vec![],
        model_error: None,
        sink: None,
        sources: vec![],
        model: None,
        telemetry: None,
    }
}

/// Per edge node: NDATA received, seq gaps seen.
#[derive(Default)]
struct Seen {
    ndata: u64,
    gaps: u64,
    last_seq: Option<u64>,
}

fn cpu_ticks(pid: u32) -> u64 {
    // utime + stime of /proc/<pid>/stat (fields 14, 15), clock ticks.
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1;
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
        })
        .unwrap_or(0)
}

async fn step(port: u16, broker_pid: u32, boxes: usize, rate_hz: f64, seconds: f64) {
    let seen: Arc<Mutex<HashMap<String, Seen>>> = Arc::default();
    // The subscriber (a stand-in for `retrocomp fleet` / a SCADA host).
    let mut o = MqttOptions::new(format!("fleet-sub-{boxes}-{rate_hz}"), "127.0.0.1", port);
    o.set_keep_alive(Duration::from_secs(30));
    o.set_max_packet_size(1 << 20, 1 << 20);
    let (sub, mut el) = AsyncClient::new(o, 1024);
    sub.subscribe(format!("spBv1.0/{GROUP}/+/+"), QoS::AtLeastOnce)
        .await
        .unwrap();
    let sink = seen.clone();
    let (subscribed_tx, subscribed_rx) = tokio::sync::oneshot::channel();
    let sub_task = tokio::spawn(async move {
        let mut subscribed = Some(subscribed_tx);
        loop {
            match el.poll().await {
                Ok(Event::Incoming(Packet::SubAck(_))) => {
                    if let Some(tx) = subscribed.take() {
                        let _ = tx.send(());
                    }
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let mut parts = p.topic.split('/').skip(2);
                    let (Some(kind), Some(node)) = (parts.next(), parts.next()) else {
                        continue;
                    };
                    let seq = <Payload as prost::Message>::decode(p.payload.as_ref())
                        .ok()
                        .and_then(|pl| pl.seq);
                    let mut m = sink.lock().unwrap();
                    let s = m.entry(node.to_string()).or_default();
                    match kind {
                        "NBIRTH" => s.last_seq = seq,
                        "NDATA" => {
                            s.ndata += 1;
                            if let (Some(l), Some(q)) = (s.last_seq, seq)
                                && q != (l + 1) % 256
                            {
                                s.gaps += 1;
                            }
                            s.last_seq = seq;
                        }
                        _ => {}
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    eprintln!("subscriber: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            }
        }
    });
    let _ = subscribed_rx.await;

    let mut pubs = Vec::new();
    let mut feeders = Vec::new();
    for i in 0..boxes {
        let (tx, rx) = watch::channel(None);
        let mut cfg = MqttConfig::new(&format!("127.0.0.1:{port}"), GROUP, &format!("box-{i:04}"));
        cfg.rate_hz = rate_hz;
        let p = telemetry::spawn(
            cfg,
            PublisherInputs {
                status: rx,
                model_identity: "bench".into(),
            },
        )
        .unwrap();
        let period = Duration::from_secs_f64(0.5 / rate_hz);
        feeders.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            let mut k = 0;
            loop {
                tick.tick().await;
                k += 1;
                tx.send_replace(Some(Arc::new(snapshot(k))));
            }
        }));
        pubs.push(p);
    }
    let cpu0 = cpu_ticks(broker_pid);
    let t0 = Instant::now();
    tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
    for f in &feeders {
        f.abort();
    }
    let window_s = t0.elapsed().as_secs_f64();
    let cpu_s = (cpu_ticks(broker_pid) - cpu0) as f64 / 100.0;
    // Each sampler takes the last snapshot at its next tick: let that happen (a late last
    // record would otherwise count as lost), then drain until every queue is empty and the
    // subscriber has caught up (≤ 60 s).
    tokio::time::sleep(Duration::from_secs_f64(3.0 / rate_hz)).await;
    let produced = |pubs: &[telemetry::Publisher]| -> u64 {
        pubs.iter().map(|p| p.status.borrow().records_total).sum()
    };
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let queued: u64 = pubs.iter().map(|p| p.status.borrow().queued).sum();
        let received: u64 = seen.lock().unwrap().values().map(|s| s.ndata).sum();
        if (queued == 0 && received >= produced(&pubs)) || Instant::now() > deadline {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let drain_s = t0.elapsed().as_secs_f64() - window_s;
    let produced = produced(&pubs);
    let dropped: u64 = pubs.iter().map(|p| p.status.borrow().dropped_total).sum();
    let (received, gaps, nodes) = {
        let m = seen.lock().unwrap();
        (
            m.values().map(|s| s.ndata).sum::<u64>(),
            m.values().map(|s| s.gaps).sum::<u64>(),
            m.len(),
        )
    };
    println!(
        "{boxes:>6} {rate_hz:>7.1} {:>10.0} {produced:>10} {received:>10} {:>8} {dropped:>8} {gaps:>6} {nodes:>6} {:>9.0}% {drain_s:>7.1}",
        produced as f64 / window_s,
        produced.saturating_sub(received),
        100.0 * cpu_s / window_s,
    );
    for p in pubs {
        p.stop(Duration::from_secs(2)).await;
    }
    sub_task.abort();
}

fn main() {
    let mut steps: Vec<(usize, f64)> = Vec::new();
    let mut seconds = 20.0;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--seconds" {
            seconds = args
                .next()
                .and_then(|s| s.parse().ok())
                .expect("--seconds S");
        } else if let Some((b, r)) = a.split_once('x')
            && let (Ok(b), Ok(r)) = (b.parse(), r.parse())
        {
            steps.push((b, r));
        }
        // Other arguments (`--bench` from cargo) are ignored.
    }
    if steps.is_empty() {
        steps = vec![
            (50, 10.0),
            (100, 10.0),
            (200, 10.0),
            (400, 10.0),
            (200, 20.0),
        ];
    }
    let dir = tempfile::tempdir().unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let conf = dir.path().join("mosquitto.conf");
    std::fs::write(
        &conf,
        format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nlog_dest none\nmax_queued_messages 100000\n"),
    )
    .unwrap();
    let exe = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
        .into_iter()
        .find(|p| std::path::Path::new(p).is_file())
        .expect("mosquitto is not installed: run scripts/setup-peers.sh");
    let mut broker = std::process::Command::new(exe)
        .arg("-c")
        .arg(&conf)
        .spawn()
        .expect("start mosquitto");
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        std::thread::sleep(Duration::from_millis(20));
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    println!("telemetry_fleet: one mosquitto, one subscriber, {seconds} s per step");
    println!(
        "{:>6} {:>7} {:>10} {:>10} {:>10} {:>8} {:>8} {:>6} {:>6} {:>10} {:>7}",
        "boxes",
        "rate_Hz",
        "records/s",
        "produced",
        "received",
        "lost",
        "dropped",
        "gaps",
        "nodes",
        "broker_cpu",
        "drain_s"
    );
    for (boxes, rate) in steps {
        rt.block_on(step(port, broker.id(), boxes, rate, seconds));
    }
    let _ = broker.kill();
    let _ = broker.wait();
}
