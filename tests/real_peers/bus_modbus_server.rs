//! The Modbus register server over real TCP on loopback, read and written by the tokio-modbus client
//! and by mbpoll (a third-party client); and as an RTU slave on a socat pty, read by the poller and by
//! mbpoll in RTU mode.

use crate::peers;

use retrocomp_bus::modbus::{
    DataType, ModbusPoller, ModbusSourceConfig, Parity, RegisterBank, RegisterChannel,
    RegisterTable, TcpServer, TransportKind, WordOrder, spawn_rtu,
};
use retrocomp_bus::{ChannelTable, Health};
use std::time::Duration;
use tokio::time::timeout;
use tokio_modbus::prelude::*;

const T: Duration = Duration::from_secs(5);

async fn server() -> (RegisterBank, TcpServer) {
    let bank = RegisterBank::new();
    bank.set_input(0, &[235, 241, 0xFF38]);
    bank.allow_writes(200, 2);
    let srv = TcpServer::start("127.0.0.1:0".parse().unwrap(), bank.clone())
        .await
        .unwrap();
    (bank, srv)
}

#[tokio::test]
async fn tokio_modbus_client_reads_writes_and_gets_exceptions_as_values() {
    let _turn = crate::turn::take(file!());
    let (bank, srv) = server().await;
    let mut ctx = tcp::connect_slave(srv.local_addr(), Slave(1))
        .await
        .unwrap();
    let r = timeout(T, ctx.read_input_registers(0, 3)).await.unwrap();
    assert_eq!(r.unwrap(), Ok(vec![235, 241, 0xFF38]));
    let r = timeout(T, ctx.read_input_registers(2, 2)).await.unwrap();
    assert_eq!(r.unwrap(), Err(ExceptionCode::IllegalDataAddress));
    let mut changed = bank.subscribe_writes();
    let r = timeout(T, ctx.write_multiple_registers(200, &[0x0001, 0x86A0]))
        .await
        .unwrap();
    assert_eq!(r.unwrap(), Ok(()));
    timeout(T, changed.changed()).await.unwrap().unwrap();
    assert_eq!(bank.holding(200, 2), Some(vec![0x0001, 0x86A0]));
    let r = timeout(T, ctx.write_single_register(0, 1)).await.unwrap();
    assert_eq!(
        r.unwrap(),
        Err(ExceptionCode::IllegalDataAddress),
        "not in the allow-list"
    );
}

#[tokio::test]
async fn mbpoll_reads_the_server() {
    let _turn = crate::turn::take(file!());
    let (_bank, srv) = server().await;
    let port = srv.local_addr().port().to_string();
    // mbpoll is blocking: run it on a thread so the server keeps running on this runtime.
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new("mbpoll")
            // -t 3: input registers (16-bit int, mbpoll prints them unsigned); -r 1 = address 0; -1 once.
            .args([
                "-m",
                "tcp",
                "-p",
                &port,
                "-a",
                "1",
                "-t",
                "3",
                "-r",
                "1",
                "-c",
                "3",
                "-1",
                "127.0.0.1",
            ])
            .output()
    })
    .await
    .unwrap()
    .unwrap_or_else(|e| panic!("mbpoll not runnable ({e}): run scripts/setup-peers.sh"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "mbpoll failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // mbpoll prints `[1]: 235` … with 1-based reference numbers; int16 is its default type.
    for (reg, v) in [(1, "235"), (2, "241"), (3, "65336")] {
        let line = format!("[{reg}]: \t{v}");
        let alt = format!("[{reg}]:\t{v}");
        assert!(
            stdout.contains(&line) || stdout.contains(&alt),
            "missing {line:?} in:\n{stdout}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtu_server_on_a_pty_answers_the_poller_and_mbpoll() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (_socat, a, b) = peers::socat_pair(dir.path());
    let bank = RegisterBank::new();
    // float32 CDAB 23.456 at holding 4..5 (0x41BBA5E3 word-swapped; mbpoll reads CDAB unless -B)
    bank.set_holding(4, &[0xA5E3, 0x41BB]);
    let serial =
        tokio_serial::SerialStream::open(&tokio_serial::new(a.to_string_lossy(), 19200)).unwrap();
    let srv = spawn_rtu(serial, bank, 7);
    let cfg = ModbusSourceConfig {
        name: "rtu".into(),
        transport: TransportKind::Rtu,
        host: None,
        port: 502,
        device: Some(b.to_string_lossy().into_owned()),
        baud: 19200,
        parity: Parity::None,
        unit_id: 7,
        period_s: 0.1,
        timeout_s: 1.0,
        backoff_min_s: 0.05,
        backoff_max_s: 0.5,
        max_gap: 0,
        channel: vec![RegisterChannel {
            channel: "T_oil_C".into(),
            kind: RegisterTable::Holding,
            address: 4,
            data_type: DataType::Float32,
            word_order: WordOrder::LowFirst,
            scale: 1.0,
            offset: 0.0,
            min: None,
            max: None,
        }],
    };
    let mut p = ModbusPoller::new(cfg.clone(), &mut ChannelTable::default());
    let mut out = Vec::new();
    p.poll_once(0.0, &mut out).await;
    assert_eq!(out[0].health, Health::Ok, "{out:?} {p:?}");
    assert!((out[0].value - 23.456).abs() < 1e-5);
    // Another slave id on the same line: our server stays silent, the poller times out (stale).
    // (The port is opened exclusively, so the first poller must close it first.)
    drop(p);
    let mut other = ModbusPoller::new(
        ModbusSourceConfig {
            unit_id: 8,
            timeout_s: 0.3,
            ..cfg
        },
        &mut ChannelTable::default(),
    );
    out.clear();
    other.poll_once(0.0, &mut out).await;
    assert_eq!(out[0].health, Health::Stale);
    assert_eq!(other.counters().timeouts, 1, "{other:?}");
    drop(other);
    let dev = b.to_string_lossy().into_owned();
    let o = tokio::task::spawn_blocking(move || {
        std::process::Command::new(peers::tool("mbpoll"))
            .args([
                "-m", "rtu", "-b", "19200", "-P", "none", "-a", "7", "-t", "4:float", "-r", "5",
                "-c", "1", "-1", &dev,
            ])
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && stdout.contains("23.456"),
        "mbpoll rtu:\n{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    srv.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtu_poller_keeps_the_inter_frame_silence() {
    let _turn = crate::turn::take(file!());
    // 1200 Bd: t3.5 = 3.5 × 11 / 1200 = 32 ms. A pty ignores the baud rate and answers in well under
    // a millisecond, so three reads of one poll take ≥ 2 × t3.5 only if the poller waits (#180).
    let dir = tempfile::tempdir().unwrap();
    let (_socat, a, b) = peers::socat_pair(dir.path());
    let bank = RegisterBank::new();
    for addr in [0u16, 100, 200] {
        bank.set_input(addr, &[addr + 1]);
    }
    let serial =
        tokio_serial::SerialStream::open(&tokio_serial::new(a.to_string_lossy(), 1200)).unwrap();
    let srv = spawn_rtu(serial, bank, 1);
    let channel = [0u16, 100, 200]
        .iter()
        .map(|&address| RegisterChannel {
            channel: format!("T{address}_C"),
            kind: RegisterTable::Input,
            address,
            data_type: DataType::Uint16,
            word_order: WordOrder::HighFirst,
            scale: 1.0,
            offset: 0.0,
            min: None,
            max: None,
        })
        .collect();
    let mut p = ModbusPoller::new(
        ModbusSourceConfig {
            name: "slow".into(),
            transport: TransportKind::Rtu,
            host: None,
            port: 502,
            device: Some(b.to_string_lossy().into_owned()),
            baud: 1200,
            parity: Parity::None,
            unit_id: 1,
            period_s: 1.0,
            timeout_s: 2.0,
            backoff_min_s: 0.05,
            backoff_max_s: 0.5,
            max_gap: 0,
            channel,
        },
        &mut ChannelTable::default(),
    );
    assert_eq!(p.schedule.core.plan.len(), 3, "three separate reads");
    let mut out = Vec::new();
    p.poll_once(0.0, &mut out).await; // first poll: connect and warm up
    assert!(out.iter().all(|s| s.health == Health::Ok), "{out:?}");
    out.clear();
    let t0 = std::time::Instant::now();
    p.poll_once(1.0, &mut out).await;
    let took = t0.elapsed();
    let values: Vec<f64> = out.iter().map(|s| s.value).collect();
    assert_eq!(values, vec![1.0, 101.0, 201.0]);
    // Three frames after a previous one: three gaps of t3.5.
    assert!(
        took >= Duration::from_millis(3 * 32),
        "no silence kept: {took:?}"
    );
    srv.abort();
}
