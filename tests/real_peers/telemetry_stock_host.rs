//! A running box judged by a Sparkplug host we did not write: mqtt-spb-wrapper's host-application
//! class (`MqttSpbEntityScada`, `tests/peers/spb_stock_host.py`) against a real Mosquitto started
//! here, and the gateway runtime (`run::run`) publishing to it. A channel starts delivering only
//! after the first birth (as sensors do at start). Judged: one NBIRTH per session (bdSeq), before
//! and after a broker kill and restart; every numeric metric's birth carries `engUnit` (the
//! clamp as `engLow`/`engHigh` of the applied correction, the channel's min/max as its range);
//! "no value" is `is_null`; the birth does not carry the link-down fault of its own link; states
//! are from the documented enumerations; the host's own data table follows the NDATA.
//! Every wait ends on an event, with a deadline only a broken publisher reaches.

use crate::base_field;
use crate::mosquitto;
use crate::peers;
use crate::scale_model;
use crate::snapshot;
use crate::spb_lines;

use scale_model::ScaleModel;
use std::path::Path;
use std::time::{Duration, Instant};

use base_field::BASE;
use mosquitto::Broker;
use peers::{free_port, spawn_python};
use retrocomp_gateway::northbound::telemetry::{HEALTH_STATES, MODE_STATES};
use serde_json::Value;
use spb_lines::{Host, PATIENCE, of};

fn metric<'a>(msg: &'a Value, name: &str) -> Option<&'a Value> {
    msg["metrics"]
        .as_array()?
        .iter()
        .find(|m| m["name"] == name)
}

/// NDATA after the last NBIRTH in which `name` has a value satisfying `pred`.
fn data_since_birth_with(msgs: &[Value], name: &str, pred: impl Fn(&Value) -> bool) -> usize {
    let from = msgs.iter().rposition(|m| m["type"] == "NBIRTH");
    from.map_or(0, |i| {
        msgs[i..]
            .iter()
            .filter(|m| m["type"] == "NDATA")
            .filter(|m| metric(m, name).is_some_and(|x| pred(&x["value"])))
            .count()
    })
}

/// The shared field-file head (axis x on `x_mm`, clamp 50 µm) plus two channels and telemetry.
fn field_config(port: u16) -> String {
    format!(
        r#"{BASE}
[[channel]]
name = "x_mm"
min = -1.0
max = 500.0
stale_after_s = 0.5
[[channel]]
name = "T_spindle_C"
min = -10.0
max = 80.0
stale_after_s = 5.0
[telemetry.mqtt]
broker = "127.0.0.1:{port}"
group_id = "shop"
edge_node_id = "mill-7"
primary_host_id = "stock-judge"
rate_hz = 10.0
reconnect_min_ms = 100
reconnect_max_ms = 500
"#
    )
}

/// The birth's numbers carry units; ranges where the box knows them; text states are from the
/// enumerations; the link it is sent over is not reported down.
fn check_birth(b: &Value) {
    for m in b["metrics"].as_array().unwrap() {
        let numeric = [4, 7, 8, 10].contains(&m["datatype"].as_u64().unwrap());
        // bdSeq is Sparkplug's session number, not a measurement.
        if numeric && m["name"] != "bdSeq" {
            assert!(
                m["properties"]["engUnit"].is_string(),
                "numeric metric without engUnit: {m}"
            );
        }
    }
    let applied = metric(b, "Axis/x/applied_um").unwrap();
    assert_eq!(applied["properties"]["engUnit"], "µm", "{applied}");
    assert_eq!(
        applied["properties"]["engLow"], -50.0,
        "the clamp: {applied}"
    );
    assert_eq!(
        applied["properties"]["engHigh"], 50.0,
        "the clamp: {applied}"
    );
    let t = metric(b, "Channel/T_spindle_C/value").expect("declared before its first reading");
    assert_eq!(t["properties"]["engUnit"], "°C", "{t}");
    assert_eq!(
        (&t["properties"]["engLow"], &t["properties"]["engHigh"]),
        (&Value::from(-10.0), &Value::from(80.0))
    );
    let term = metric(b, "Axis/x/term/scale_um").expect("the model's term is declared");
    assert_eq!(term["properties"]["engUnit"], "µm");
    assert_eq!(
        metric(b, "Gateway/t_s").unwrap()["properties"]["engUnit"],
        "s"
    );
    let faults = metric(b, "Gateway/faults").unwrap()["value"]
        .as_str()
        .unwrap_or("")
        .to_string();
    assert!(
        !faults.contains("telemetry.mqtt"),
        "the birth says its own link is down: {faults}"
    );
    for m in b["metrics"].as_array().unwrap() {
        let name = m["name"].as_str().unwrap_or("");
        let allowed: &[&str] = if name.ends_with("/health") {
            &HEALTH_STATES
        } else if name.ends_with("/mode") {
            &MODE_STATES
        } else {
            continue;
        };
        assert!(
            m["null"] == true || allowed.contains(&m["value"].as_str().unwrap()),
            "{m} not in {allowed:?}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stock_host_reads_one_birth_per_session_with_units_through_a_broker_restart() {
    let _turn = crate::turn::take(file!());
    use retrocomp_bus::{Health, Sample};
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let broker = Broker::start(dir.path(), port);
    let mut host = Host::new(spawn_python(
        "spb_stock_host.py",
        &[&port.to_string(), "shop"],
    ));

    let cfg =
        retrocomp_gateway::config::FieldConfig::parse(&field_config(port), Path::new("stock.toml"))
            .unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(4096);
    let (temp_on_tx, temp_on) = tokio::sync::watch::channel(false);
    let epoch = Instant::now();
    // The ids the gateway's engine gives these names (the field file's table).
    let channels = cfg.channel_table();
    let x_mm = channels.get("x_mm").expect("x_mm in the field file");
    let t_spindle = channels
        .get("T_spindle_C")
        .expect("T_spindle_C in the field file");
    let feeder = tokio::spawn(async move {
        loop {
            let t = epoch.elapsed().as_secs_f64();
            let mut s = vec![Sample {
                channel: x_mm,
                t_s: t,
                value: 100.0 + 50.0 * (t * 0.5).sin(),
                health: Health::Ok,
            }];
            if *temp_on.borrow() {
                s.push(Sample {
                    channel: t_spindle,
                    t_s: t,
                    value: 21.5,
                    health: Health::Ok,
                });
            }
            for s in s {
                if tx.send(s).await.is_err() {
                    return;
                }
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    });
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let gw = tokio::spawn(retrocomp_gateway::run::run(
        cfg,
        Box::new(ScaleModel {
            um_per_mm: 1e-2,
            declared: true,
        }),
        rx,
        epoch,
        async {
            let _ = stop_rx.await;
        },
        None,
    ));

    // Session 1: the birth, then the temperature channel comes alive (a new reading, no rebirth).
    let h = tokio::task::spawn_blocking(move || {
        host.until("NBIRTH", |m| !of(m, "NBIRTH").is_empty());
        host
    });
    let mut host = h.await.unwrap();
    let first = of(&host.msgs, "NBIRTH")[0].clone();
    check_birth(&first);
    assert_eq!(
        metric(&first, "Channel/T_spindle_C/value").unwrap()["null"],
        true,
        "no reading yet: null, not NaN: {first}"
    );
    temp_on_tx.send(true).unwrap();
    let mut host = tokio::task::spawn_blocking(move || {
        host.until("temperature data", |m| {
            data_since_birth_with(m, "Channel/T_spindle_C/value", |v| v == 21.5) >= 1
        });
        host
    })
    .await
    .unwrap();
    let last = host
        .msgs
        .iter()
        .rev()
        .find(|m| m["type"] == "NDATA")
        .unwrap();
    assert_eq!(
        last["table"]["Channel/T_spindle_C/value"], 21.5,
        "the host's own table follows the data: {last}"
    );
    assert!(last["table"]["Gateway/cycles"].as_u64() > Some(0), "{last}");
    assert_eq!(of(&host.msgs, "NBIRTH").len(), 1, "one NBIRTH in session 1");

    // Broker outage: killed, restarted on the same port; the box reconnects with a new bdSeq.
    broker.kill();
    let _broker = Broker::start(dir.path(), port);
    let mut host = tokio::task::spawn_blocking(move || {
        host.until("the second session's data", |m| {
            of(m, "NBIRTH").len() >= 2 && data_since_birth_with(m, "Gateway/cycles", |_| true) >= 10
        });
        host
    })
    .await
    .unwrap();
    let births = of(&host.msgs, "NBIRTH");
    assert_eq!(births.len(), 2, "one NBIRTH per session");
    check_birth(births[1]);
    let bd = |b: &Value| metric(b, "bdSeq").unwrap()["value"].as_u64().unwrap();
    assert_eq!(bd(births[1]), bd(births[0]) + 1, "a new session");
    assert_eq!(
        metric(births[1], "Channel/T_spindle_C/value").unwrap()["value"],
        21.5
    );

    // A clean stop: NDEATH with that bdSeq, still no other birth.
    let _ = stop_tx.send(());
    tokio::time::timeout(PATIENCE, gw)
        .await
        .expect("the gateway stops")
        .unwrap()
        .unwrap();
    feeder.abort();
    let host = tokio::task::spawn_blocking(move || {
        host.until("NDEATH", |m| !of(m, "NDEATH").is_empty());
        host
    })
    .await
    .unwrap();
    let death = of(&host.msgs, "NDEATH")[0];
    assert_eq!(
        metric(death, "bdSeq").unwrap()["value"].as_u64(),
        Some(bd(of(&host.msgs, "NBIRTH")[1]))
    );
    assert_eq!(of(&host.msgs, "NBIRTH").len(), 2);
}

/// A model switch that adds a term: one rebirth announces it (aliases announced before keep their
/// number), not a rebirth per snapshot; the stock host follows the new term's data.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_term_costs_exactly_one_rebirth() {
    let _turn = crate::turn::take(file!());
    use retrocomp_gateway::northbound::telemetry::{
        self, Declaration, DeclaredAxis, MqttConfig, PublisherInputs,
    };
    use std::sync::Arc;
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    let mut host = Host::new(spawn_python(
        "spb_stock_host.py",
        &[&port.to_string(), "shop"],
    ));
    let mut cfg = MqttConfig::new(&format!("127.0.0.1:{port}"), "shop", "box-9");
    cfg.primary_host_id = Some("stock-judge".into());
    cfg.rate_hz = 50.0;
    cfg.check().unwrap();
    let (tx, rx) = tokio::sync::watch::channel(None);
    let publisher = telemetry::spawn(
        cfg,
        PublisherInputs {
            status: rx,
            model_identity: "m".into(),
            declared: Declaration {
                axes: vec![DeclaredAxis {
                    name: "x".into(),
                    clamp_um: 50.0,
                }],
                terms: vec!["thermal".into()],
                ..Default::default()
            },
        },
    )
    .unwrap();
    let feed = |k: u64, extra: bool| {
        let mut s = snapshot::snapshot(k);
        if extra {
            s.axes[0].terms_um.insert("load".into(), 0.25 * k as f64);
        }
        tx.send_replace(Some(Arc::new(s)));
    };
    for k in 1..=20 {
        feed(k, false);
        tokio::time::sleep(Duration::from_millis(15)).await;
    }
    let mut host = tokio::task::spawn_blocking(move || {
        host.until("the first session", |m| {
            data_since_birth_with(m, "Gateway/cycles", |v| v == 20) >= 1
        });
        host
    })
    .await
    .unwrap();
    // The switch: every snapshot from now on carries the new term.
    for k in 21..=60 {
        feed(k, true);
        tokio::time::sleep(Duration::from_millis(15)).await;
    }
    let host = tokio::task::spawn_blocking(move || {
        host.until("the new term's data", |m| {
            data_since_birth_with(m, "Axis/x/term/load_um", |v| v == 15.0) >= 1
        });
        host
    })
    .await
    .unwrap();
    publisher.stop(Duration::from_secs(5)).await;
    let births = of(&host.msgs, "NBIRTH");
    assert_eq!(births.len(), 2, "one birth, one rebirth for the new term");
    let alias = |b: &Value, n: &str| metric(b, n).unwrap()["alias"].clone();
    assert!(metric(births[0], "Axis/x/term/load_um").is_none());
    assert_eq!(
        alias(births[0], "Axis/x/applied_um"),
        alias(births[1], "Axis/x/applied_um"),
        "announced aliases keep their number"
    );
    let load = metric(births[1], "Axis/x/term/load_um").unwrap();
    assert_eq!(load["properties"]["engUnit"], "µm", "{load}");
}
