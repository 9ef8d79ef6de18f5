//! Sparkplug's rebirth across Mosquitto's bridge, on the brokers of `fleet_bridge.rs` (C central,
//! H hall, H bridging NBIRTH/NDATA/NDEATH out and NCMD/STATE in): a host on C that starts after
//! H's boxes were born gets their births by asking for them.

use crate::fleet_bridge::{Brokers, PATIENCE, wait_until};

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Sparkplug's rebirth across the bridge: boxes born on H before any host listens (their
/// NBIRTHs crossed to C — a watcher there saw them — and are not retained), then `retrocomp
/// fleet` on C. The host sees only NDATA and asks each box for a rebirth (NCMD, C → bridge `in` → H);
/// the NBIRTHs come back (H → bridge `out` → C). Asserted on H (a watcher subscribed there):
/// every box got an NCMD after the host started and published an NBIRTH after that NCMD (a birth
/// of its own before the request, e.g. after a reconnect, is reported, not counted); and on the
/// host: every box born and compensating.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_host_on_the_central_broker_gets_the_hall_boxes_births_by_rebirth_over_the_bridge() {
    let _turn = crate::turn::take(file!());
    use crate::telemetry_fleet_host::{born, host_until_born, node, start_box};
    let b = tokio::task::block_in_place(Brokers::start);
    let seen_on_h = watch(b.ports.1, "hall", "watch-h").await;
    let seen_on_c = watch(b.ports.0, "hall", "watch-c").await;
    let names = ["hall-mill-1", "hall-mill-2", "hall-mill-3"];
    let boxes: Vec<_> = names
        .iter()
        .map(|n| start_box(b.ports.1, "hall", n, 1.0))
        .collect();
    for x in &boxes {
        born(x).await;
    }
    // The bridge forwards one message at a time: wait until the births have crossed to C (so
    // the host, subscribing later, cannot get them) before the host starts.
    let crossed = |seen: &Arc<Mutex<Vec<(Instant, String)>>>| {
        let seen = seen.lock().unwrap();
        names.iter().all(|n| {
            seen.iter()
                .any(|(_, t)| t == &format!("spBv1.0/hall/NBIRTH/{n}"))
        })
    };
    tokio::task::block_in_place(|| {
        wait_until("the births never crossed the bridge", || {
            crossed(&seen_on_c)
        });
    });
    let host_started = Instant::now();
    let (online_after, last, mut host) =
        tokio::task::block_in_place(|| host_until_born(b.ports.0, "hall", &names));
    let _ = host.kill();
    let _ = host.wait();
    let seen = seen_on_h.lock().unwrap().clone();
    for name in names {
        let n = node(&last, name).unwrap();
        assert!(n["births"].as_u64() >= Some(1), "{n}");
        // The first message of `kind` for this box on H at or after `from`.
        let first_from = |kind: &str, from: Instant| {
            seen.iter()
                .filter(|(t, topic)| *t >= from && topic == &format!("spBv1.0/hall/{kind}/{name}"))
                .map(|(t, _)| *t)
                .min()
        };
        let ncmd = first_from("NCMD", host_started)
            .unwrap_or_else(|| panic!("{name}: no NCMD reached H: {seen:?}"));
        // The birth that answers the request: a box may also be born on its own meanwhile (a
        // reconnect on a loaded machine), which is Sparkplug-legal and not what is tested here.
        first_from("NBIRTH", ncmd)
            .unwrap_or_else(|| panic!("{name}: no NBIRTH on H after the host's NCMD: {seen:?}"));
        let unsolicited = seen
            .iter()
            .filter(|(t, topic)| {
                *t >= host_started && *t < ncmd && topic == &format!("spBv1.0/hall/NBIRTH/{name}")
            })
            .count();
        if unsolicited > 0 {
            eprintln!("{name}: {unsolicited} NBIRTH(s) between the host's start and its NCMD");
        }
    }
    eprintln!("over the bridge: all online {online_after:?} after the host's subscription");
    for x in boxes {
        x.feeder.abort();
        x.publisher.stop(Duration::from_secs(5)).await;
    }
}

/// Every NCMD and NBIRTH of `group` on the broker at `port`, with when it arrived; subscribed
/// when this returns.
async fn watch(port: u16, group: &str, id: &str) -> Arc<Mutex<Vec<(Instant, String)>>> {
    use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};
    let (c, mut events) = AsyncClient::new(MqttOptions::new(id, "127.0.0.1", port), 512);
    for kind in ["NCMD", "NBIRTH"] {
        c.subscribe(format!("spBv1.0/{group}/{kind}/+"), QoS::AtMostOnce)
            .await
            .unwrap();
    }
    let seen = Arc::new(Mutex::new(Vec::new()));
    let (subscribed_tx, subscribed) = tokio::sync::oneshot::channel();
    let log = seen.clone();
    tokio::spawn(async move {
        let _client = c;
        let (mut subacks, mut tx) = (0, Some(subscribed_tx));
        loop {
            match events.poll().await {
                Ok(Event::Incoming(Packet::SubAck(_))) => {
                    subacks += 1;
                    if subacks == 2
                        && let Some(tx) = tx.take()
                    {
                        let _ = tx.send(());
                    }
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    log.lock().unwrap().push((Instant::now(), p.topic.clone()));
                }
                Ok(_) => {}
                Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        }
    });
    tokio::time::timeout(PATIENCE, subscribed)
        .await
        .expect("the watcher was never subscribed")
        .unwrap();
    seen
}
