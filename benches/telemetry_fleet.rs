//! Fleet load benchmark (not criterion: a capacity search, not a latency estimate): N simulated
//! boxes publish Sparkplug B through the same publisher as `retrocomp run` (crates/gateway/src/northbound/telemetry) to one
//! Mosquitto on loopback, and one `retrocomp fleet` host (its MQTT client and view,
//! `retrocomp_fleet::FleetClient`, QoS 1) counts every NDATA per edge node and its seq gaps.
//! A box is lightweight (crates/fleet/src/load.rs): a task that updates a status snapshot at twice the telemetry rate (so
//! every sampler tick has a change to send) instead of a whole gateway.
//! For each (boxes, rate) step: after the window every publisher *finishes* (sends its queue until
//! the broker acknowledged all of it, then NDEATH), so "produced" is final; then the fleet must
//! have every record and every NDEATH (≤ 60 s). Reported: records produced, received, lost
//! (produced − received), dropped (counted by the publishers), left (still queued at the end),
//! seq gaps, nodes seen, the broker's CPU share and the drain time.
//!
//! Run: `cargo bench --profile test --bench telemetry_fleet -- 200x10 400x10 --seconds 15`
//! (needs mosquitto: scripts/setup-peers.sh).

use std::time::{Duration, Instant};

#[path = "../tests/peers/fleet_processes.rs"]
mod fleet_processes;

use fleet_processes::cpu_ticks;
use retrocomp_fleet::FleetClient;
use retrocomp_fleet::load::feed;
use retrocomp_gateway::northbound::telemetry::{self, MqttConfig, PublisherInputs};
use tokio::sync::watch;

const GROUP: &str = "fleet";

/// What the fleet host has seen so far: NDATA received, seq gaps, nodes, nodes offline.
#[derive(Clone, Copy, Default)]
struct Seen {
    ndata: u64,
    gaps: u64,
    nodes: usize,
    offline: usize,
}

/// The fleet host of `retrocomp fleet` (its MQTT client and view), reporting its totals.
fn spawn_fleet(port: u16) -> (watch::Receiver<Option<Seen>>, tokio::task::JoinHandle<()>) {
    let (tx, rx) = watch::channel(None);
    let task = tokio::spawn(async move {
        let mut fc = FleetClient::new(&format!("127.0.0.1:{port}"), Some(GROUP)).unwrap();
        let mut every = tokio::time::interval(Duration::from_millis(100));
        loop {
            tokio::select! {
                r = fc.poll() => if let Err(e) = r { eprintln!("fleet: {e}") },
                _ = every.tick() => {
                    if !fc.subscribed {
                        continue;
                    }
                    let n = fc.view.nodes.values();
                    let seen = Seen {
                        ndata: n.clone().map(|n| n.ndata).sum(),
                        gaps: n.clone().map(|n| n.seq_gaps).sum(),
                        nodes: n.clone().count(),
                        offline: n.filter(|n| !n.alive).count(),
                    };
                    tx.send_replace(Some(seen));
                }
            }
        }
    });
    (rx, task)
}

async fn step(port: u16, broker_pid: u32, boxes: usize, rate_hz: f64, seconds: f64) {
    let (mut seen, fleet) = spawn_fleet(port);
    let _ = seen.wait_for(Option::is_some).await;

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
                declared: Default::default(),
            },
        )
        .unwrap();
        feeders.push(feed(tx, rate_hz));
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
    // End of run: every publisher finishes (its sampler stops; the session sends what is queued
    // until the broker acknowledged all of it, then NDEATH), so its counters are final before
    // they are compared with what the fleet host received. Reading `records_total` while records
    // were still in the sampler → session hand-over was what made the first version of this
    // bench report a few "lost" records per run.
    let mut finishing = tokio::task::JoinSet::new();
    for p in pubs {
        finishing.spawn(p.finish(Duration::from_secs(60)));
    }
    let (mut produced, mut dropped, mut left) = (0, 0, 0);
    while let Some(st) = finishing.join_next().await {
        let st = st.unwrap();
        produced += st.records_total;
        dropped += st.dropped_total;
        left += st.queued;
    }
    // Then the fleet host must have every record and every NDEATH (≤ 60 s).
    let deadline = tokio::time::sleep(Duration::from_secs(60));
    tokio::pin!(deadline);
    tokio::select! {
        _ = seen.wait_for(|s| s.is_some_and(|s| s.ndata >= produced && s.offline == boxes)) => {}
        _ = &mut deadline => {}
    }
    let drain_s = t0.elapsed().as_secs_f64() - window_s;
    let s = seen.borrow().unwrap_or_default();
    println!(
        "{boxes:>6} {rate_hz:>7.1} {:>10.0} {produced:>10} {:>10} {:>8} {dropped:>8} {left:>6} {:>6} {:>6} {:>9.0}% {drain_s:>7.1}",
        produced as f64 / window_s,
        s.ndata,
        produced as i64 - s.ndata as i64,
        s.gaps,
        s.nodes,
        100.0 * cpu_s / window_s,
    );
    fleet.abort();
}

fn main() {
    let mut steps: Vec<(usize, f64)> = Vec::new();
    let mut seconds = 20.0;
    // Mosquitto's per-client queue bound; None: its default (1000).
    let mut max_queued: Option<u64> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--max-queued" {
            max_queued = args.next().and_then(|s| s.parse().ok());
        } else if a == "--seconds" {
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
        format!(
            "listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nlog_dest none\n{}",
            max_queued.map_or(String::new(), |n| format!("max_queued_messages {n}\n"))
        ),
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
    println!(
        "telemetry_fleet: one mosquitto (max_queued_messages {}), one fleet host, {seconds} s per step",
        max_queued.map_or("default".to_string(), |n| n.to_string())
    );
    println!(
        "{:>6} {:>7} {:>10} {:>10} {:>10} {:>8} {:>8} {:>6} {:>6} {:>6} {:>10} {:>7}",
        "boxes",
        "rate_Hz",
        "records/s",
        "produced",
        "received",
        "lost",
        "dropped",
        "left",
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
