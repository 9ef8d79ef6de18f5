//! The fleet host as a Sparkplug host, against a real Mosquitto (started here on a free loopback
//! port, persistence off) with the real `retrocomp fleet` binary:
//!
//! 1. Three boxes (edge node publishers fed changing status snapshots) are up and born BEFORE the
//!    fleet host starts, so it never sees their connect NBIRTH. From the moment its subscription is
//!    acknowledged (its "subscribed" line) the host shows all three online within 2 s (issue 35:
//!    from their NDATA; the bound covers the first NDATA, ≤ 100 ms at 10 Hz, and a 100 ms table
//!    tick; nothing in it depends on machine speed but loopback MQTT), asks each for a rebirth,
//!    and then knows each one's birth, bdSeq and per-axis applied correction — its `--json` lines
//!    stream one object per update.
//! 2. A rebirth storm (200 NCMD rebirth requests) at a box with `rebirth_min_interval_s = 1`:
//!    its NBIRTHs (seen by a plain MQTT subscriber) are at least 1 s apart by their timestamps, the
//!    storm is answered (a birth after it), and far fewer than 200 births go out.
//! 3. Boxes and the fleet host as separate OS processes over TLS (the path of
//!    benches/fleet_processes.rs at a tiny scale: 2 processes × 5 boxes, 10 Hz, 5 s, a TLS-only
//!    listener with a CA made by openssl): every record produced arrives, no seq gap, every
//!    NDEATH seen, the window's NDATA stamped for the latency; a plain MQTT CONNECT gets no CONNACK there.
//!
//! Every wait ends on an event with a deadline only a broken implementation reaches, except the
//! 2 s of the issue's requirement.

use crate::fleet_processes;
use crate::hil_sim;
use crate::mosquitto;
use crate::peers;
use crate::snapshot;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};

use mosquitto::Broker;
use peers::free_port;
use prost::Message as _;
use retrocomp_gateway::northbound::telemetry::sparkplug::Payload;
use retrocomp_gateway::northbound::telemetry::{self, MqttConfig, Publisher, PublisherInputs};
use retrocomp_gateway::status::StatusSnapshot;
use serde_json::Value;
use snapshot::snapshot;
use tokio::sync::watch;

const PATIENCE: Duration = Duration::from_secs(120);

/// A box: its publisher and the task feeding it a new snapshot every 20 ms.
pub(crate) struct Box_ {
    pub(crate) publisher: Publisher,
    pub(crate) feeder: tokio::task::JoinHandle<()>,
}

pub(crate) fn start_box(port: u16, group: &str, node: &str, rebirth_min_interval_s: f64) -> Box_ {
    let (tx, rx) = watch::channel::<Option<Arc<StatusSnapshot>>>(Some(Arc::new(snapshot(1))));
    let mut cfg = MqttConfig::new(&format!("127.0.0.1:{port}"), group, node);
    cfg.rebirth_min_interval_s = rebirth_min_interval_s;
    let publisher = telemetry::spawn(
        cfg,
        PublisherInputs {
            status: rx,
            model_identity: "m".into(),
            declared: Default::default(),
        },
    )
    .unwrap();
    let feeder = tokio::spawn(async move {
        for k in 2.. {
            tx.send_replace(Some(Arc::new(snapshot(k))));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    });
    Box_ { publisher, feeder }
}

pub(crate) async fn born(b: &Box_) {
    let mut rx = b.publisher.status.clone();
    tokio::time::timeout(
        PATIENCE,
        rx.wait_for(|s| s.connected && s.births_total >= 1),
    )
    .await
    .expect("box not born")
    .unwrap();
}

/// A line from one of the fleet child's streams, stamped when the test read it.
enum Line {
    Out(Instant, String),
    Err(Instant, String),
}

pub(crate) fn node<'a>(update: &'a Value, name: &str) -> Option<&'a Value> {
    update["nodes"]
        .as_array()?
        .iter()
        .find(|n| n["edge_node"] == name)
}

/// Starts `retrocomp fleet --group <group> --json` against the broker on `port` and reads its
/// lines until every node in `names` is born and compensating. Returns how long after the
/// host's subscription all were alive, the last JSON update and the host process.
pub(crate) fn host_until_born(
    port: u16,
    group: &str,
    names: &[&str],
) -> (Duration, Value, std::process::Child) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["fleet", "--broker", &format!("127.0.0.1:{port}")])
        .args([
            "--group",
            group,
            "--json",
            "--every-s",
            "0.1",
            "--seconds",
            "300",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (tx, rx) = std_mpsc::channel();
    let (out, err) = (child.stdout.take().unwrap(), child.stderr.take().unwrap());
    let tx2 = tx.clone();
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send(Line::Out(Instant::now(), l));
        }
    });
    std::thread::spawn(move || {
        for l in BufReader::new(err).lines().map_while(Result::ok) {
            let _ = tx2.send(Line::Err(Instant::now(), l));
        }
    });

    let deadline = Instant::now() + PATIENCE;
    let next = || {
        rx.recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .expect("the fleet host went quiet")
    };
    let subscribed = loop {
        match next() {
            Line::Err(t, l) if l.contains("subscribed") => break t,
            Line::Err(_, l) => eprintln!("fleet: {l}"),
            // The two pipes are read by two threads: an early update (drawn before the
            // subscription, so without nodes) may be read first.
            Line::Out(_, l) => assert!(l.contains(r#""nodes":[]"#), "{l}"),
        }
    };
    let (mut online_after, mut born_after) = (None, None);
    let mut last = Value::Null;
    while born_after.is_none() {
        let (t, l) = match next() {
            Line::Out(t, l) => (t, l),
            Line::Err(_, l) => {
                eprintln!("fleet: {l}");
                continue;
            }
        };
        let u: Value = serde_json::from_str(&l).unwrap_or_else(|e| panic!("{e}: {l}"));
        assert!(
            u["drawn_at"].as_str().is_some_and(|s| s.ends_with('Z')),
            "{u}"
        );
        let all =
            |pred: &dyn Fn(&Value) -> bool| names.iter().all(|n| node(&u, n).is_some_and(pred));
        if online_after.is_none() && all(&|n| n["alive"] == true) {
            online_after = Some(t.saturating_duration_since(subscribed));
        }
        if all(&|n| n["born"] == true && n["verdict"] == "compensating") {
            born_after = Some(t.saturating_duration_since(subscribed));
        }
        last = u;
    }
    let online_after = online_after.expect("born implies alive");
    eprintln!(
        "all {} online {online_after:?} and born {born_after:?} after the SUBACK",
        names.len()
    );
    (online_after, last, child)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fleet_started_after_three_boxes_shows_them_online_within_2_s_and_gets_their_births() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    let names = ["mill-1", "mill-2", "mill-3"];
    let boxes: Vec<Box_> = names
        .iter()
        .map(|n| start_box(port, "hall", n, 1.0))
        .collect();
    for b in &boxes {
        born(b).await;
    }

    let (online_after, last, mut child) = host_until_born(port, "hall", &names);
    assert!(
        online_after <= Duration::from_secs(2),
        "all 3 online only {online_after:?} after the subscription"
    );
    for n in names {
        let n = node(&last, n).unwrap();
        assert!(n["rebirths_requested"].as_u64() >= Some(1), "{n}");
        assert!(n["births"].as_u64() >= Some(1), "{n}");
        assert!(n["bd_seq"].is_u64(), "{n}");
        assert!(n["applied_um"]["x"].is_f64(), "the axis correction: {n}");
        assert!(n["last_seen_ms"].as_u64() > Some(0), "{n}");
    }
    let _ = child.kill();
    let _ = child.wait();
    for b in boxes {
        b.feeder.abort();
        b.publisher.stop(Duration::from_secs(5)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rebirth_storm_yields_at_most_one_nbirth_per_interval() {
    let _turn = crate::turn::take(file!());
    use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    // The watcher subscribes first, so it sees the connect NBIRTH too.
    let (watcher, mut events) =
        AsyncClient::new(MqttOptions::new("storm-watch", "127.0.0.1", port), 512);
    watcher
        .subscribe("spBv1.0/storm/NBIRTH/+", QoS::AtMostOnce)
        .await
        .unwrap();
    let births = Arc::new(std::sync::Mutex::new(Vec::<u64>::new()));
    let (suback_tx, suback_rx) = tokio::sync::oneshot::channel();
    let seen = births.clone();
    let pump = tokio::spawn(async move {
        let mut suback_tx = Some(suback_tx);
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::SubAck(_))) => {
                    if let Some(s) = suback_tx.take() {
                        let _ = s.send(());
                    }
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let ts = Payload::decode(p.payload.as_ref())
                        .unwrap()
                        .timestamp
                        .unwrap();
                    seen.lock().unwrap().push(ts);
                }
                Ok(_) => {}
                Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        }
    });
    tokio::time::timeout(PATIENCE, suback_rx)
        .await
        .unwrap()
        .unwrap();
    let b = start_box(port, "storm", "mill-s", 1.0);
    born(&b).await;

    let ncmd = "spBv1.0/storm/NCMD/mill-s";
    let storm_start = Instant::now();
    let mut last_request_ms = 0;
    for i in 0..200u64 {
        // Taken before the request goes: whatever birth answers it is stamped no earlier.
        last_request_ms = telemetry::now_ms();
        let req = retrocomp_fleet::rebirth_request(i);
        watcher
            .publish(ncmd, QoS::AtMostOnce, false, req)
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let storm_s = storm_start.elapsed().as_secs_f64();
    // The storm is answered: a birth stamped after its last request went.
    let deadline = Instant::now() + PATIENCE;
    while births
        .lock()
        .unwrap()
        .last()
        .is_none_or(|&t| t < last_request_ms)
    {
        assert!(Instant::now() < deadline, "the storm was never answered");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let ts = births.lock().unwrap().clone();
    eprintln!(
        "{} NBIRTHs for 200 requests in {storm_s:.2} s: {ts:?}",
        ts.len()
    );
    for w in ts.windows(2) {
        // The box limits on its monotonic clock and stamps with the wall clock, each truncated
        // to the ms: 2 ms of rounding between the two.
        assert!(w[1] - w[0] >= 998, "NBIRTHs less than 1 s apart: {ts:?}");
    }
    // The connect birth, one per second of storm, and the one answering its end.
    assert!(ts.len() as f64 <= 2.0 + storm_s.ceil(), "{ts:?}");
    pump.abort();
    b.feeder.abort();
    b.publisher.stop(Duration::from_secs(5)).await;
}

#[test]
fn boxes_as_separate_processes_over_tls_lose_nothing() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let (broker, ca) = Broker::start_tls(dir.path(), port, "");
    // The listener speaks only TLS: a plain MQTT CONNECT is not answered with a CONNACK (0x20).
    let mut plain = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    plain.set_read_timeout(Some(PATIENCE)).unwrap();
    std::io::Write::write_all(
        &mut plain,
        &[0x10, 12, 0, 4, b'M', b'Q', b'T', b'T', 4, 2, 0, 60, 0, 0],
    )
    .unwrap();
    let mut first = [0u8; 1];
    let n = std::io::Read::read(&mut plain, &mut first).unwrap_or(0);
    assert!(n == 0 || first[0] != 0x20, "a plain CONNECT was accepted");

    let load = fleet_processes::Load {
        procs: 2,
        boxes_per_proc: 5,
        rate_hz: 10.0,
        seconds: 5.0,
        group: "fleet-tls".into(),
        boxes_nice: 0,
    };
    let exe = hil_sim::fleet_load_next_to_retrocomp();
    let o = fleet_processes::run(
        &exe,
        &format!("127.0.0.1:{port}"),
        broker.pid(),
        Some(&ca),
        &load,
    );
    assert_eq!((o.sent.boxes, o.connected), (10, 10));
    // Each box samples at least its first tick.
    assert!(o.sent.produced >= 10, "{o:?}");
    assert_eq!(
        (o.lost(), o.sent.dropped, o.sent.left, o.seen.gaps),
        (0, 0, 0, 0),
        "{o:?}"
    );
    assert_eq!((o.seen.nodes, o.seen.offline), (10, 10), "{o:?}");
    // The latency counts the NDATA sampled after every box was connected (the window).
    assert!(o.latency().n > 0 && o.latency().n <= o.seen.ndata, "{o:?}");
}
