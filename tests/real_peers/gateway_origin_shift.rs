//! Origin-shift client against a Modbus TCP server on 127.0.0.1 (tokio-modbus server, in-process):
//! reads the current values at start, writes both words of each int32 in ONE FC16, runs the
//! strobe/ack handshake and read-back, reports an ack timeout, survives the server being killed and
//! restarted (timeout + reconnect with backoff), and never writes outside the allow-list.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use retrocomp_gateway::sinks::origin_shift::{
    ClientConfig, OriginShiftClient, Outcome, RegisterMap, Transport,
};
use retrocomp_model::Axis;
use tokio::net::TcpListener;

use crate::plc;
use plc::{Plc, STROBE, serve};

fn map() -> RegisterMap {
    toml::from_str(
        r#"
        [[axis]]
        axis = "x"
        address = 100
        kind = "int32"
        word_order = "low_first"
        lsb_um = 0.1
        sign = 1
        [[axis]]
        axis = "z"
        address = 102
        kind = "int32"
        lsb_um = 0.1
        sign = 1
        [handshake]
        strobe_address = 110
        ack_address = 111
        timeout_ms = 150
        poll_ms = 5
        "#,
    )
    .unwrap()
}

fn client(addr: SocketAddr) -> OriginShiftClient {
    OriginShiftClient::new(
        ClientConfig {
            transport: Transport::Tcp {
                address: addr.to_string(),
            },
            unit_id: 1,
            request_timeout_ms: 200,
            reconnect_min_ms: 50,
            reconnect_max_ms: 400,
        },
        map(),
    )
    .unwrap()
}

fn allowed(m: &RegisterMap, writes: &[(u16, Vec<u16>)]) -> bool {
    writes
        .iter()
        .all(|(a, w)| m.check_write(*a, w.len()).is_ok())
}

#[tokio::test]
async fn reads_current_writes_one_fc16_handshakes_and_verifies() {
    let _turn = crate::turn::take(file!());
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let plc = Arc::new(Mutex::new(Plc {
        auto_ack: true,
        ..Default::default()
    }));
    // The controller already holds x = +12.3 µm (123 counts, CDAB) from before a restart.
    plc.lock().unwrap().regs.extend([(100, 123), (101, 0)]);
    let task = tokio::spawn(serve(listener, plc.clone()));

    let mut c = client(addr);
    let current = c.read_current().await.unwrap();
    assert_eq!(current[0].0, "x");
    assert!((current[0].1 - 12.3).abs() < 1e-9, "read {current:?}");
    assert_eq!(current[1], ("z".to_string(), 0.0));

    let out = c.write(&[(Axis::X, 12.1), (Axis::Z, -3.0)]).await.unwrap();
    assert_eq!(out, Outcome::Ok);
    let p = plc.lock().unwrap();
    // x: 121 = 0x0079 low first; z: −30 = 0xFFFF_FFE2 high first; one FC16 for all four words.
    assert_eq!(p.writes[0], (100, vec![0x0079, 0x0000, 0xFFFF, 0xFFE2]));
    assert_eq!(p.writes[1], (STROBE, vec![1]));
    assert_eq!(p.writes.len(), 2);
    assert!(allowed(&map(), &p.writes));
    drop(p);
    task.abort();
}

#[tokio::test]
async fn ack_timeout_is_reported() {
    let _turn = crate::turn::take(file!());
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let plc = Arc::new(Mutex::new(Plc {
        auto_ack: false,
        ..Default::default()
    }));
    let task = tokio::spawn(serve(listener, plc.clone()));
    let mut c = client(addr);
    let t0 = tokio::time::Instant::now();
    let out = c.write(&[(Axis::X, 1.0)]).await.unwrap();
    assert_eq!(
        out,
        Outcome::AckTimeout {
            strobe: 1,
            last_ack: Some(0)
        }
    );
    let waited = t0.elapsed();
    assert!(
        waited >= Duration::from_millis(150) && waited < Duration::from_secs(2),
        "{waited:?}"
    );
    task.abort();
}

#[tokio::test]
async fn server_killed_and_restarted_client_reconnects() {
    let _turn = crate::turn::take(file!());
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let plc = Arc::new(Mutex::new(Plc {
        auto_ack: true,
        ..Default::default()
    }));
    let task = tokio::spawn(serve(listener, plc.clone()));
    let mut c = client(addr);
    assert_eq!(c.write(&[(Axis::X, 1.0)]).await.unwrap(), Outcome::Ok);

    task.abort();
    let _ = task.await;
    // Dead server: the write fails fast with a reason instead of hanging.
    let t0 = tokio::time::Instant::now();
    let r = c.write(&[(Axis::X, 2.0)]).await;
    assert!(t0.elapsed() < Duration::from_secs(1));
    match r {
        Ok(Outcome::RequestFailed { .. }) | Err(_) => {}
        other => panic!("expected a failure while the server is down, got {other:?}"),
    }
    assert!(!c.is_connected());

    // Restart on the same port; the client comes back by itself after its backoff.
    let listener = TcpListener::bind(addr).await.unwrap();
    let task = tokio::spawn(serve(listener, plc.clone()));
    let mut ok = false;
    for _ in 0..40 {
        if let Ok(Outcome::Ok) = c.write(&[(Axis::X, 3.0)]).await {
            ok = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    assert!(ok, "client did not recover after the server restart");
    assert_eq!(c.connects, 2);
    let p = plc.lock().unwrap();
    assert_eq!(p.regs[&100], 30, "x = 3.0 µm at 0.1 µm");
    assert!(allowed(&map(), &p.writes));
    drop(p);
    task.abort();
}
