//! Sparkplug B telemetry against real peers: Mosquitto (started here on a free loopback port with a
//! generated config, persistence off; never the system service) and a third-party host in Python
//! (paho-mqtt + mqtt-spb-wrapper's compiled Eclipse sparkplug_b.proto, `tests/peers/spb_host.py`)
//! that decodes every payload. The broker is killed and restarted mid-run; every record the
//! publisher produced before, during and after arrives exactly once, in order, with seq and
//! bdSeq per the spec and NBIRTH/NDEATH at the right moments. Then the gateway runtime with its
//! telemetry pointed at a broker that accepts and never answers: the cycle keeps running.
//! Every wait ends on an event, with a deadline only a broken publisher reaches.

use crate::mosquitto;
use crate::peers;
use crate::scale_model;
use crate::snapshot;
use crate::spb_lines;

use scale_model::ScaleModel;
use std::collections::BTreeMap;
use std::path::Path;

use std::sync::Arc;
use std::time::{Duration, Instant};

use mosquitto::Broker;
use peers::{free_port, spawn_python};
use retrocomp_gateway::northbound::telemetry::{
    self, MqttConfig, PublisherInputs, TelemetryStatus,
};
use retrocomp_gateway::status::StatusSnapshot;
use serde_json::Value;
use snapshot::snapshot;
use spb_lines::{Host, PATIENCE};
use tokio::sync::watch;

/// `Gateway/cycles` of every NDATA (aliases resolved through the NBIRTH before it).
fn cycles_seen(msgs: &[Value]) -> Vec<u64> {
    let mut alias = None;
    let mut out = vec![];
    for m in msgs {
        let metrics = m["metrics"].as_array();
        match m["type"].as_str() {
            Some("NBIRTH") => {
                alias = metrics
                    .and_then(|ms| ms.iter().find(|x| x["name"] == "Gateway/cycles"))
                    .and_then(|x| x["alias"].as_u64());
            }
            Some("NDATA") => {
                let c = metrics
                    .and_then(|ms| ms.iter().find(|x| x["alias"].as_u64() == alias))
                    .and_then(|x| x["value"].as_u64());
                out.extend(c);
            }
            _ => {}
        }
    }
    out
}

fn count(msgs: &[Value], kind: &str) -> usize {
    msgs.iter().filter(|m| m["type"] == kind).count()
}

/// Wait (polling the status watch) until `pred` holds.
async fn status_until(
    rx: &mut watch::Receiver<TelemetryStatus>,
    what: &str,
    pred: impl Fn(&TelemetryStatus) -> bool,
) -> TelemetryStatus {
    let last = rx.borrow().clone();
    match tokio::time::timeout(PATIENCE, rx.wait_for(|s| pred(s))).await {
        Ok(st) => st.expect("publisher gone").clone(),
        Err(_) => panic!("publisher: not {what} within {PATIENCE:?} (at the start: {last:?})"),
    }
}

/// Feed snapshots k in `range`, paced so the sampler sees most of them (pacing only: nothing
/// asserted depends on it; the publisher's own record count is the reference).
async fn feed(
    tx: &watch::Sender<Option<Arc<StatusSnapshot>>>,
    range: std::ops::RangeInclusive<u64>,
) {
    for k in range {
        tx.send_replace(Some(Arc::new(snapshot(k))));
        tokio::time::sleep(Duration::from_millis(15)).await;
    }
}

fn metric<'a>(m: &'a Value, name: &str) -> Option<&'a Value> {
    m["metrics"]
        .as_array()?
        .iter()
        .find(|x| x["name"] == name)
        .map(|x| &x["value"])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn broker_killed_and_restarted_nothing_lost_in_order_with_births_and_death() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let broker = Broker::start(dir.path(), port);
    let mut host = Host {
        peer: spawn_python("spb_host.py", &[&port.to_string(), "shop", "scada"]),
        msgs: vec![],
    };
    let mut cfg = MqttConfig::new(&format!("127.0.0.1:{port}"), "shop", "box-7");
    cfg.primary_host_id = Some("scada".into());
    cfg.rate_hz = 50.0;
    cfg.reconnect_min_ms = 50;
    cfg.reconnect_max_ms = 400;
    cfg.queue.dir = Some(dir.path().join("queue"));
    cfg.check().unwrap();
    let (snap_tx, snap_rx) = watch::channel(None);
    let publisher = telemetry::spawn(
        cfg,
        PublisherInputs {
            status: snap_rx,
            model_identity: "test-model".into(),
            declared: Default::default(),
        },
    )
    .unwrap();
    let mut st = publisher.status.clone();

    // Before: link up, records flow.
    snap_tx.send_replace(Some(Arc::new(snapshot(1))));
    status_until(&mut st, "born", |s| s.connected).await;
    feed(&snap_tx, 2..=40).await;
    // The last snapshot always makes a record (it differs from the one before): wait for it.
    host.until("cycles 40", |m| cycles_seen(m).last() == Some(&40));
    let s = status_until(&mut st, "all acknowledged", |s| s.queued == 0).await;
    let before = s.records_total as usize;
    host.until("the records before the outage", |m| {
        count(m, "NDATA") >= before
    });
    assert_eq!(count(&host.msgs, "NDATA"), before, "each record once");
    assert!(before >= 5, "too few records to mean anything: {before}");

    // During: broker killed; records go to the on-disk queue.
    broker.kill();
    status_until(&mut st, "disconnected", |s| !s.connected).await;
    feed(&snap_tx, 41..=80).await;
    let s = status_until(&mut st, "queueing", |s| s.queued > 5).await;
    assert_eq!(s.dropped_total, 0);
    let files = std::fs::read_dir(dir.path().join("queue")).unwrap().count();
    assert!(
        files as u64 >= s.queued.min(5),
        "queue not on disk: {files} files, {s:?}"
    );

    // After: the same port again; the host reconnects and says online, the node re-births.
    let _broker = Broker::start(dir.path(), port);
    status_until(&mut st, "born again", |s| {
        s.connected && s.births_total >= 2
    })
    .await;
    feed(&snap_tx, 81..=120).await;
    host.until("cycles 120", |m| cycles_seen(m).last() == Some(&120));
    let s = status_until(&mut st, "all acknowledged", |s| s.queued == 0).await;
    let total = s.records_total as usize;
    host.until("every record", |m| count(m, "NDATA") >= total);

    // Rebirth on request: same bdSeq, seq back to 0.
    host.peer.send("REBIRTH box-7");
    host.until("the rebirth", |m| count(m, "NBIRTH") == 3);
    feed(&snap_tx, 121..=130).await;
    host.until("cycles 130", |m| cycles_seen(m).last() == Some(&130));
    let s = status_until(&mut st, "all acknowledged", |s| s.queued == 0).await;
    let total = s.records_total as usize;
    host.until("every record", |m| count(m, "NDATA") >= total);
    assert_eq!(s.dropped_total, 0);
    assert_eq!(s.acked_total, s.records_total);

    // Clean stop: NDEATH with the session's bdSeq.
    publisher.stop(Duration::from_secs(10)).await;
    host.until("NDEATH", |m| count(m, "NDEATH") == 1);

    // Exactly once, in order: every produced record arrived once; cycles strictly increase.
    let data = host.of("NDATA");
    assert_eq!(data.len(), total, "NDATA received vs records produced");
    assert!(data.iter().all(|m| m["wrapper_parsed"] == true));
    // NDATA go by alias: map aliases through the NBIRTH that precedes each.
    let mut alias_names: BTreeMap<u64, String> = BTreeMap::new();
    let (mut last_cycles, mut last_ts, mut last_seq) = (0u64, 0u64, None::<u64>);
    let mut bd_seqs = vec![];
    let mut historical = 0;
    for m in &host.msgs {
        match m["type"].as_str().unwrap() {
            "NBIRTH" => {
                alias_names.clear();
                for x in m["metrics"].as_array().unwrap() {
                    if let (Some(a), Some(n)) = (x["alias"].as_u64(), x["name"].as_str()) {
                        alias_names.insert(a, n.to_string());
                    }
                }
                assert_eq!(m["seq"], 0, "NBIRTH seq is 0: {m}");
                assert_eq!(metric(m, "Node Control/Rebirth"), Some(&Value::Bool(false)));
                assert_eq!(
                    metric(m, "Model/identity"),
                    Some(&Value::from("test-model"))
                );
                bd_seqs.push(metric(m, "bdSeq").and_then(Value::as_u64).unwrap());
                last_seq = Some(0);
            }
            "NDATA" => {
                let seq = m["seq"].as_u64().unwrap();
                assert_eq!(
                    Some(seq),
                    last_seq.map(|s| (s + 1) % 256),
                    "seq continues: {m}"
                );
                last_seq = Some(seq);
                let ts = m["timestamp"].as_u64().unwrap();
                assert!(
                    ts >= last_ts,
                    "payload timestamps monotonic: {ts} < {last_ts}"
                );
                last_ts = ts;
                let cycles = m["metrics"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .find(|x| {
                        x["alias"]
                            .as_u64()
                            .and_then(|a| alias_names.get(&a))
                            .map(String::as_str)
                            == Some("Gateway/cycles")
                    })
                    .and_then(|x| x["value"].as_u64())
                    .unwrap_or_else(|| panic!("NDATA without Gateway/cycles: {m}"));
                assert!(
                    cycles > last_cycles,
                    "in order, no duplicate: {cycles} after {last_cycles}"
                );
                last_cycles = cycles;
                if m["metrics"][0]["historical"] == true {
                    historical += 1;
                    // Queued before their session's NBIRTH: during the outage, or the very first
                    // record (taken before the first connection was up).
                    assert!(
                        cycles == 1 || (41..=80).contains(&cycles),
                        "only records queued before their NBIRTH are historical: {cycles}"
                    );
                }
            }
            "NDEATH" => {
                let bd = metric(m, "bdSeq").and_then(Value::as_u64).unwrap();
                assert_eq!(
                    Some(&bd),
                    bd_seqs.last(),
                    "NDEATH carries the session's bdSeq"
                );
                assert_eq!(m["seq"], Value::Null, "NDEATH carries no seq");
            }
            _ => {}
        }
    }
    assert_eq!(
        bd_seqs.len(),
        3,
        "NBIRTH at start, after the restart, on rebirth"
    );
    assert_eq!(bd_seqs[1], bd_seqs[0] + 1, "a new connection, a new bdSeq");
    assert_eq!(bd_seqs[2], bd_seqs[1], "a rebirth keeps the bdSeq");
    assert!(
        historical >= 5,
        "records queued during the outage are flagged historical: {historical}"
    );
    assert!(
        last_cycles >= 121,
        "the last records arrived: {last_cycles}"
    );
}

/// `/status`, or None while the gateway answers 503 "no cycle run yet" (its first cycle may come
/// late on a loaded machine: a CI run with both cores busy saw it); any other answer fails.
async fn status(addr: &str) -> Option<Value> {
    let (code, body) =
        retrocomp_gateway::northbound::http::get(addr, "/status", Duration::from_secs(10))
            .await
            .unwrap();
    if code == 503 && body.contains("no cycle run yet") {
        return None;
    }
    assert_eq!(code, 200, "{body}");
    Some(serde_json::from_str(&body).unwrap())
}

/// Poll `/status` (every 50 ms) until `pred` holds.
async fn status_where(addr: &str, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + PATIENCE;
    loop {
        let js = status(addr).await;
        if let Some(js) = js.as_ref().filter(|js| js["cycles"].is_u64() && pred(js)) {
            return js.clone();
        }
        assert!(
            Instant::now() < deadline,
            "gateway: not {what} within {PATIENCE:?}: {js:?}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_that_never_answers_does_not_hold_up_the_cycle() {
    let _turn = crate::turn::take(file!());
    use retrocomp_bus::{Health, Sample};
    // Accepts connections and never reads or answers (a hung broker, a black-holed network).
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let _held = tokio::spawn(async move {
        let mut keep = vec![];
        while let Ok((s, _)) = listener.accept().await {
            keep.push(s);
        }
    });
    let text = format!(
        r#"
[gateway]
name = "dead-broker"
cycle_ms = 5
status_listen = "127.0.0.1:0"
[safety]
max_correction_um = 50.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 100.0
stale_hold_s = 0.5
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
[[channel]]
name = "x_mm"
min = -1.0
max = 500.0
stale_after_s = 0.5
[telemetry.mqtt]
broker = "127.0.0.1:{port}"
group_id = "shop"
edge_node_id = "dead"
rate_hz = 50.0
reconnect_min_ms = 50
reconnect_max_ms = 200
[telemetry.mqtt.queue]
max_records = 50
drop_policy = "drop_oldest"
"#
    );
    let cfg = retrocomp_gateway::config::FieldConfig::parse(&text, Path::new("dead.toml")).unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(4096);
    let epoch = Instant::now();
    // The ids the gateway's engine gives these names (the field file's table).
    let channels = cfg.channel_table();
    let x_mm = channels.get("x_mm").expect("x_mm in the field file");
    let feeder = tokio::spawn(async move {
        loop {
            let t = epoch.elapsed().as_secs_f64();
            let s = Sample {
                channel: x_mm,
                t_s: t,
                value: 100.0 + 50.0 * (t * 0.5).sin(),
                health: Health::Ok,
            };
            if tx.send(s).await.is_err() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    });
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let (addr_tx, addr_rx) = tokio::sync::oneshot::channel();
    let gw = tokio::spawn(retrocomp_gateway::run::run(
        cfg,
        Box::new(ScaleModel {
            um_per_mm: 1e-3,
            declared: false,
        }),
        rx,
        epoch,
        async {
            let _ = stop_rx.await;
        },
        Some(addr_tx),
    ));
    let addr = addr_rx.await.unwrap().to_string();

    // The queue fills (50 records) and the drop policy starts counting; the link never comes up.
    let js = status_where(&addr, "dropping telemetry", |js| {
        js["telemetry"]["dropped_total"].as_u64() > Some(0)
    })
    .await;
    assert_eq!(js["telemetry"]["connected"], false);
    assert_eq!(js["telemetry"]["queued"], 50, "bounded: {js}");
    assert!(
        js["active_faults"]
            .as_array()
            .unwrap()
            .iter()
            .any(|f| f[0] == "telemetry.mqtt" && f[1] == "disconnected"),
        "the link fault is in the status: {js}"
    );
    // The cycle goes on meanwhile: 500 more cycles, and the correction follows the model.
    let c0 = js["cycles"].as_u64().unwrap();
    let js = status_where(&addr, "cycling", |js| {
        js["cycles"].as_u64() > Some(c0 + 500)
    })
    .await;
    assert_eq!(js["axes"][0]["mode"], "tracking", "{js}");
    let (_, metrics) =
        retrocomp_gateway::northbound::http::get(&addr, "/metrics", Duration::from_secs(10))
            .await
            .unwrap();
    assert!(
        metrics.contains("retrocomp_telemetry_connected 0"),
        "{metrics}"
    );
    assert!(
        metrics.contains("retrocomp_telemetry_dropped_total "),
        "{metrics}"
    );

    let _ = stop_tx.send(());
    let summary = tokio::time::timeout(PATIENCE, gw)
        .await
        .expect("the gateway stops although the broker never answers")
        .unwrap()
        .unwrap();
    assert!(summary.cycles > c0 + 500);
    feeder.abort();
}

async fn fleet_until(
    f: &mut retrocomp_fleet::FleetClient,
    what: &str,
    pred: impl Fn(&retrocomp_fleet::FleetClient) -> bool,
) {
    let deadline = Instant::now() + PATIENCE;
    while !pred(f) {
        assert!(
            Instant::now() < deadline,
            "fleet: no {what} within {PATIENCE:?}"
        );
        let _ = tokio::time::timeout(PATIENCE, f.poll()).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fleet_shows_boxes_compensating_degraded_and_offline_by_death_and_will() {
    let _turn = crate::turn::take(file!());
    use retrocomp_fleet::FleetClient;
    use retrocomp_fleet::Verdict;
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    let mut fleet = FleetClient::new(&format!("127.0.0.1:{port}"), Some("hall")).unwrap();
    let deadline = Instant::now() + PATIENCE;
    while !fleet.subscribed {
        assert!(Instant::now() < deadline, "fleet: not subscribed");
        let _ = tokio::time::timeout(PATIENCE, fleet.poll()).await;
    }
    let start = |node: &str, faulty: bool| {
        let mut snap = snapshot(1);
        if faulty {
            snap.active_faults
                .push(("can".into(), retrocomp_gateway::FaultKind::Stale, 0.5));
        }
        let (tx, rx) = watch::channel(Some(Arc::new(snap)));
        let p = telemetry::spawn(
            MqttConfig::new(&format!("127.0.0.1:{port}"), "hall", node),
            PublisherInputs {
                status: rx,
                model_identity: "m".into(),
                declared: Default::default(),
            },
        )
        .unwrap();
        (tx, p)
    };
    let (_ta, a) = start("mill-a", false);
    let (_tb, b) = start("mill-b", true);
    let verdict = |f: &FleetClient, n: &str| {
        f.view
            .nodes
            .get(&("hall".to_string(), n.to_string()))
            .map(|x| x.verdict())
    };
    fleet_until(&mut fleet, "mill-a compensating, mill-b degraded", |f| {
        verdict(f, "mill-a") == Some(Verdict::Compensating)
            && verdict(f, "mill-b") == Some(Verdict::Degraded)
    })
    .await;
    let b_node = &fleet.view.nodes[&("hall".to_string(), "mill-b".to_string())];
    assert_eq!(
        b_node.births, 1,
        "the NBIRTH already carried the fault: no rebirth needed"
    );
    assert_eq!(verdict(&fleet, "mill-a"), Some(Verdict::Compensating));
    assert_eq!(
        verdict(&fleet, "mill-b"),
        Some(Verdict::Degraded),
        "an active fault"
    );
    // A clean stop (NDEATH published by the box) and a box that vanishes (the broker publishes
    // its will): both offline.
    a.stop(Duration::from_secs(10)).await;
    drop(b);
    fleet_until(&mut fleet, "both offline", |f| {
        verdict(f, "mill-a") == Some(Verdict::Offline)
            && verdict(f, "mill-b") == Some(Verdict::Offline)
    })
    .await;
    assert!(fleet.view.table(0).contains("offline"));
}

#[test]
fn telemetry_config_errors_name_file_line_and_key() {
    let _turn = crate::turn::take(file!());
    use retrocomp_gateway::config::FieldConfig;
    let base = r#"[gateway]
name = "t"
cycle_ms = 5
[safety]
max_correction_um = 50.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 10.0
stale_hold_s = 1.0
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
[telemetry.mqtt]
group_id = "shop"
edge_node_id = "mill-1"
"#;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("field.toml");
    let err = |extra: &str| {
        let text = format!("{base}{extra}");
        std::fs::write(&path, &text).unwrap();
        FieldConfig::load(&path).unwrap_err().to_string()
    };
    // Line 18 is the first line after `base` (17 lines).
    let e = err("broker = \"no-port\"\n");
    assert!(
        e.contains("field.toml:18")
            && e.contains("telemetry.mqtt.broker")
            && e.contains("host:port"),
        "{e}"
    );
    let e = err("broker = \"127.0.0.1:1883\"\nrate_hz = 0.0\n");
    assert!(
        e.contains(":19") && e.contains("telemetry.mqtt.rate_hz"),
        "{e}"
    );
    let e =
        err("broker = \"127.0.0.1:1883\"\nusername = \"box\"\npassword_file = \"missing.pw\"\n");
    assert!(
        e.contains(":20") && e.contains("telemetry.mqtt.password_file") && e.contains("missing.pw"),
        "{e}"
    );
    let e = err("broker = \"127.0.0.1:1883\"\n[telemetry.mqtt.tls]\nca_file = \"ca.pem\"\n");
    assert!(
        e.contains("telemetry.mqtt.tls.ca_file") && e.contains("cannot read"),
        "{e}"
    );
    let e = err("broker = \"127.0.0.1:1883\"\nqos = 1\n");
    assert!(e.contains("qos"), "unknown keys are refused: {e}");
    // A good one: the password file is found relative to the config file.
    std::fs::write(dir.path().join("pw"), "secret\n").unwrap();
    std::fs::write(
        &path,
        format!("{base}broker = \"127.0.0.1:1883\"\nusername = \"box\"\npassword_file = \"pw\"\n[telemetry.mqtt.queue]\ndir = \"q\"\ndrop_policy = \"drop_newest\"\n"),
    )
    .unwrap();
    let cfg = FieldConfig::load(&path).unwrap();
    let m = cfg.telemetry.unwrap().mqtt.unwrap();
    assert_eq!(m.password_file.unwrap(), dir.path().join("pw"));
    assert_eq!(m.queue.dir.unwrap(), dir.path().join("q"));
}
