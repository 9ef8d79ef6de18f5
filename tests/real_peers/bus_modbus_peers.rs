//! Modbus polling against pymodbus 3.16.1 (a third-party server) over TCP and over RTU on a socat pty
//! pair, plus timeout / reconnect behaviour against Rust-side servers.
//! Map served: tests/peers/pymodbus_pt100.py.

use crate::peers;

use retrocomp_bus::modbus::{
    DataType, ModbusPoller, ModbusSourceConfig, Parity, RegisterBank, RegisterChannel,
    RegisterTable, TcpServer, TransportKind, WordOrder,
};
use retrocomp_bus::{ChannelTable, Health};
use std::time::{Duration, Instant};

fn chan(
    name: &str,
    kind: RegisterTable,
    address: u16,
    t: DataType,
    wo: WordOrder,
    scale: f64,
) -> RegisterChannel {
    RegisterChannel {
        channel: name.into(),
        kind,
        address,
        data_type: t,
        word_order: wo,
        scale,
        offset: 0.0,
        min: None,
        max: None,
    }
}

fn pt100_channels() -> Vec<RegisterChannel> {
    use DataType::*;
    use RegisterTable::*;
    use WordOrder::*;
    let mut v: Vec<_> = (0..4)
        .map(|i| chan(&format!("T{i}_C"), Input, i, Int16, HighFirst, 0.1))
        .collect();
    v.push(chan("T_f32_C", Holding, 0, Float32, HighFirst, 1.0));
    v.push(chan("T_cdab_C", Holding, 10, Float32, LowFirst, 1.0));
    v.push(chan("F_load_N", Holding, 20, Int32, LowFirst, 0.01));
    // Not mapped by the peer: the exception must come back as a value.
    v.push(chan("T_missing_C", Holding, 500, Int16, HighFirst, 1.0));
    v
}

fn config(transport: TransportKind) -> ModbusSourceConfig {
    ModbusSourceConfig {
        name: "pt100".into(),
        transport,
        host: Some("127.0.0.1".into()),
        port: 502,
        device: None,
        baud: 19200,
        parity: Parity::None,
        unit_id: 1,
        period_s: 0.1,
        timeout_s: 1.0,
        backoff_min_s: 0.05,
        backoff_max_s: 0.5,
        max_gap: 0,
        channel: pt100_channels(),
    }
}

/// Poll until every channel has been answered (connect may take a few tries while the peer starts).
async fn poll_until_answered(p: &mut ModbusPoller) -> Vec<retrocomp_bus::Sample> {
    let deadline = Instant::now() + Duration::from_secs(15);
    loop {
        let mut out = Vec::new();
        p.poll_once(0.0, &mut out).await;
        if out.iter().all(|s| s.health != Health::Stale) {
            return out;
        }
        assert!(
            Instant::now() < deadline,
            "peer never answered: {out:?} {p:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn check_pt100(out: &[retrocomp_bus::Sample], table: &ChannelTable) {
    let get = |n: &str| {
        out.iter()
            .find(|s| table.name(s.channel) == n)
            .unwrap_or_else(|| panic!("no {n}"))
    };
    for (n, v) in [
        ("T0_C", 21.5),
        ("T1_C", 22.3),
        ("T2_C", 19.8),
        ("T3_C", -4.5),
        ("T_cdab_C", -1.25),
        ("F_load_N", -1000.0),
    ] {
        let s = get(n);
        assert_eq!(s.health, Health::Ok, "{s:?}");
        assert!((s.value - v).abs() < 1e-9, "{n}: {} != {v}", s.value);
    }
    assert!((get("T_f32_C").value - 23.456).abs() < 1e-5);
    let m = get("T_missing_C");
    assert_eq!(m.health, Health::DecodeError, "exception is a value: {m:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_pymodbus_pt100_over_tcp() {
    let _turn = crate::turn::take(file!());
    let port = peers::free_port();
    let _peer = peers::spawn_python("pymodbus_pt100.py", &["tcp", &port.to_string()]);
    let mut cfg = config(TransportKind::Tcp);
    cfg.port = port;
    let mut table = ChannelTable::default();
    let mut p = ModbusPoller::new(cfg, &mut table);
    let out = poll_until_answered(&mut p).await;
    check_pt100(&out, &table);
    assert!(p.counters().exceptions >= 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reads_pymodbus_pt100_over_rtu_on_socat_pty() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (_socat, a, b) = peers::socat_pair(dir.path());
    let _peer = peers::spawn_python("pymodbus_pt100.py", &["rtu", a.to_str().unwrap(), "19200"]);
    let mut cfg = config(TransportKind::Rtu);
    cfg.device = Some(b.to_string_lossy().into_owned());
    let mut table = ChannelTable::default();
    let mut p = ModbusPoller::new(cfg, &mut table);
    let out = poll_until_answered(&mut p).await;
    check_pt100(&out, &table);
}

#[tokio::test]
async fn silent_server_times_out_then_reconnects_when_back() {
    let _turn = crate::turn::take(file!());
    // A TCP peer that accepts and never answers: tokio-modbus alone would hang forever (#113).
    let silent = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = silent.local_addr().unwrap();
    let hold = tokio::spawn(async move {
        let mut conns = Vec::new();
        while let Ok((s, _)) = silent.accept().await {
            conns.push(s);
        }
    });
    let mut cfg = config(TransportKind::Tcp);
    cfg.port = addr.port();
    cfg.timeout_s = 0.2;
    cfg.channel.truncate(1);
    let mut p = ModbusPoller::new(cfg, &mut ChannelTable::default());
    let t0 = Instant::now();
    let mut out = Vec::new();
    p.poll_once(1.0, &mut out).await;
    assert!(
        t0.elapsed() < Duration::from_secs(2),
        "request timeout not applied"
    );
    assert_eq!(out[0].health, Health::Stale);
    assert_eq!(p.counters().timeouts, 1);
    assert!(!p.is_connected(), "context dropped after a timeout");
    hold.abort();
    let _ = hold.await;

    // A real server comes up on the same port: the poller reconnects after its backoff.
    let bank = RegisterBank::new();
    bank.set_input(0, &[215]);
    let _srv = TcpServer::start(addr, bank).await.unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        out.clear();
        p.poll_once(2.0, &mut out).await;
        if out[0].health == Health::Ok {
            break;
        }
        assert!(Instant::now() < deadline, "never reconnected: {p:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!((out[0].value - 21.5).abs() < 1e-12);
    assert!(p.counters().connects >= 2);
}
