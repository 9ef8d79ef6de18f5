//! The listener policy (`retrocomp_bus::listen`) under a flood, on every server of the box: the Modbus
//! TCP server, the HTTP endpoint, OPC UA and the socketcand hub run in one child process whose
//! descriptor limit is 1024 (soft = hard, as `LimitNOFILE=1024` or `prlimit --nofile=1024:1024`).
//! A controller (tokio-modbus client, 127.0.0.1) writes and reads the Modbus server all along;
//! against each listener in turn 2000 idle connections are opened from another host address
//! (127.0.0.2, a rogue peer) and held. Asserted (the numbers): the controller's round
//! trips never pause more than 0.5 s, the child logs fewer than 100 lines during all four floods,
//! a peer not flooding is served during the flood, and the flooding address is served again
//! within 1 s after its connections close.
//!
//! The child is this test binary (`real_peers`) run again with `RETROCOMP_LISTENER_FLOOD_CHILD=1`; everything is
//! on loopback with ephemeral ports.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};

use crate::process::{child_runtime, set_nofile, spawn_child};

const CHILD_ENV: &str = "RETROCOMP_LISTENER_FLOOD_CHILD";
const NOFILE: u64 = 1024;
const CLIENTS: usize = 2000;
const ROGUE: [u8; 4] = [127, 0, 0, 2];
const MAX_GAP: Duration = Duration::from_millis(500);
const RECOVERY: Duration = Duration::from_secs(1);

/// Child: the four servers on loopback with their default policies; prints their addresses and
/// serves until stdin closes.
fn child() {
    let rt = child_runtime();
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let (modbus, http, ua, hub, _status_tx) = rt.block_on(async {
        let bank = retrocomp_bus::modbus::RegisterBank::new();
        bank.set_holding(0, &[1, 2]);
        bank.allow_writes(10, 3);
        let modbus = retrocomp_bus::modbus::TcpServer::start(any, bank)
            .await
            .unwrap();
        // Kept to the end: the endpoint's history task ends when the sender goes.
        let (tx, rx) = tokio::sync::watch::channel(None);
        let (http, _task) = retrocomp_gateway::northbound::http::serve(
            any,
            rx.clone(),
            Default::default(),
            Default::default(),
        )
        .await
        .unwrap();
        let section: retrocomp_gateway::northbound::opcua::OpcUaSection =
            toml::from_str("listen = \"127.0.0.1:0\"").unwrap();
        let ua = retrocomp_gateway::northbound::opcua::start(&section, "flood", rx, None)
            .await
            .unwrap();
        let hub = retrocomp_bus::can::Hub::start_loopback().await.unwrap();
        (modbus, http, ua, hub, tx)
    });
    println!(
        "LISTEN {} {} {} {}",
        modbus.local_addr(),
        http,
        ua.bound,
        hub.local_addr()
    );
    let _ = std::io::stdout().flush();
    let mut sink = String::new();
    let _ = std::io::stdin().read_to_string(&mut sink);
    drop((modbus, ua, hub));
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Modbus,
    Http,
    OpcUa,
    Hub,
}

/// One well-behaved exchange from `source` (an application answer, not a refusal); bounded 2 s.
async fn served(kind: Kind, addr: SocketAddr, source: [u8; 4]) -> bool {
    let fut = async {
        let s = TcpSocket::new_v4().ok()?;
        s.bind(SocketAddr::from((source, 0))).ok()?;
        let mut c: TcpStream = s.connect(addr).await.ok()?;
        let mut buf = vec![0u8; 4096];
        match kind {
            Kind::Modbus => {
                c.write_all(&[0, 1, 0, 0, 0, 6, 1, 3, 0, 0, 0, 2])
                    .await
                    .ok()?;
                c.read_exact(&mut buf[..13]).await.ok()?;
                Some(buf[7] == 3 && buf[9..13] == [0, 1, 0, 2])
            }
            Kind::Http => {
                c.write_all(b"GET /status HTTP/1.1\r\nHost: x\r\n\r\n")
                    .await
                    .ok()?;
                let mut text = Vec::new();
                c.read_to_end(&mut text).await.ok()?;
                Some(String::from_utf8_lossy(&text).contains("no cycle run yet"))
            }
            Kind::OpcUa => {
                let url = format!("opc.tcp://{addr}/");
                let mut hello = b"HELF".to_vec();
                hello.extend_from_slice(&(32 + url.len() as u32).to_le_bytes());
                for v in [0u32, 65536, 65536, 0, 0] {
                    hello.extend_from_slice(&v.to_le_bytes());
                }
                hello.extend_from_slice(&(url.len() as i32).to_le_bytes());
                hello.extend_from_slice(url.as_bytes());
                c.write_all(&hello).await.ok()?;
                c.read_exact(&mut buf[..4]).await.ok()?;
                Some(&buf[..4] == b"ACKF")
            }
            Kind::Hub => {
                let n = c.read(&mut buf).await.ok()?;
                Some(String::from_utf8_lossy(&buf[..n]).contains("< hi >"))
            }
        }
    };
    matches!(
        tokio::time::timeout(Duration::from_secs(2), fut).await,
        Ok(Some(true))
    )
}

/// The controller: FC16 then FC03 on one connection, as fast as answered, until `stop`; returns
/// the longest pause between two completed round trips and how many there were.
fn controller(addr: SocketAddr, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<(Duration, u64)> {
    std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async move {
            use tokio_modbus::prelude::*;
            let mut ctx = client::tcp::connect(addr).await.unwrap();
            let (mut last, mut worst, mut n) = (Instant::now(), Duration::ZERO, 0u64);
            while !stop.load(Ordering::Relaxed) {
                let v = (n % 1000) as u16;
                let w = tokio::time::timeout(
                    Duration::from_secs(10),
                    ctx.write_multiple_registers(10, &[v, 0, 21930]),
                )
                .await;
                assert!(matches!(w, Ok(Ok(Ok(())))), "controller write: {w:?}");
                let r = tokio::time::timeout(
                    Duration::from_secs(10),
                    ctx.read_holding_registers(10, 3),
                )
                .await;
                match r {
                    Ok(Ok(Ok(words))) => assert_eq!(words, [v, 0, 21930]),
                    other => panic!("controller read: {other:?}"),
                }
                let now = Instant::now();
                worst = worst.max(now - last);
                last = now;
                n += 1;
                // A controller polls; it does not spin (mb2hal: a few ms per transaction).
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            (worst, n)
        })
    })
}

/// Open `CLIENTS` idle connections to `addr` from the rogue address; those the server closes at
/// once (refused) are kept too: what counts is that every one was accepted by the kernel.
async fn flood(addr: SocketAddr) -> Vec<TcpStream> {
    let mut held = Vec::with_capacity(CLIENTS);
    for _ in 0..CLIENTS {
        let s = TcpSocket::new_v4().unwrap();
        s.bind(SocketAddr::from((ROGUE, 0))).unwrap();
        if let Ok(Ok(c)) = tokio::time::timeout(Duration::from_secs(5), s.connect(addr)).await {
            held.push(c);
        }
    }
    held
}

#[test]
fn every_listener_survives_2000_idle_connections_under_nofile_1024() {
    if std::env::var_os(CHILD_ENV).is_some() {
        return child();
    }
    let _turn = crate::turn::take(file!());
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes only the struct we pass.
    assert_eq!(unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) }, 0);
    assert!(
        lim.rlim_max >= 2 * CLIENTS as u64 + 200,
        "hard RLIMIT_NOFILE {} too low for the flooding side (need {})",
        lim.rlim_max,
        2 * CLIENTS + 200
    );
    set_nofile(lim.rlim_max, lim.rlim_max).unwrap();

    let log_path = std::env::temp_dir().join(format!("listener_flood_{}.log", std::process::id()));
    let log = std::fs::File::create(&log_path).unwrap();
    let mut child = spawn_child(
        "listener_flood::every_listener_survives_2000_idle_connections_under_nofile_1024",
        &[(CHILD_ENV, "1"), ("RUST_LOG", "info")],
        NOFILE,
        log,
    );
    let stdin = child.stdin.take().unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    let addrs: Vec<SocketAddr> = loop {
        line.clear();
        assert!(
            out.read_line(&mut line).unwrap() > 0,
            "child exited; log {log_path:?}"
        );
        if let Some(rest) = line.trim().strip_prefix("LISTEN ") {
            break rest.split(' ').map(|a| a.parse().unwrap()).collect();
        }
    };
    let kinds = [Kind::Modbus, Kind::Http, Kind::OpcUa, Kind::Hub];

    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let lines_before = std::fs::read_to_string(&log_path).unwrap().lines().count();
    let stop = Arc::new(AtomicBool::new(false));
    let link = controller(addrs[0], Arc::clone(&stop));
    let mut report = Vec::new();
    rt.block_on(async {
        for (&kind, &addr) in kinds.iter().zip(&addrs) {
            assert!(
                served(kind, addr, ROGUE).await,
                "{kind:?} not serving before the flood"
            );
            let held = flood(addr).await;
            assert!(
                held.len() > NOFILE as usize,
                "{kind:?}: only {} connections landed",
                held.len()
            );
            // A peer that is not flooding is served while the flood is held.
            assert!(
                served(kind, addr, [127, 0, 0, 1]).await,
                "{kind:?}: another peer locked out during the flood"
            );
            let child_fds = std::fs::read_dir(format!("/proc/{}/fd", child.id()))
                .unwrap()
                .count();
            drop(held);
            // Recovery: the flooding address itself is served again (bounded: 100 tries).
            let t0 = Instant::now();
            let mut back = None;
            for _ in 0..100 {
                if served(kind, addr, ROGUE).await {
                    back = Some(t0.elapsed());
                    break;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            let back =
                back.unwrap_or_else(|| panic!("{kind:?} never served again after the flood"));
            report.push(format!(
                "{kind:?}: child fds during flood {child_fds}, served again after {back:?}"
            ));
            assert!(
                back <= RECOVERY,
                "{kind:?} served again only after {back:?}"
            );
        }
    });
    stop.store(true, Ordering::Relaxed);
    let (worst, trips) = link.join().unwrap();
    let log = std::fs::read_to_string(&log_path).unwrap();
    let flood_lines = log.lines().count() - lines_before;
    drop(stdin);
    let _ = child.wait();
    let _ = std::fs::remove_file(&log_path);
    eprintln!(
        "{}\ncontroller: {trips} round trips, longest pause {worst:?}; {flood_lines} log lines during the floods",
        report.join("\n")
    );
    assert!(
        trips > 10,
        "the controller link made only {trips} round trips"
    );
    assert!(worst <= MAX_GAP, "the controller link paused {worst:?}");
    assert!(
        flood_lines < 100,
        "{flood_lines} log lines during the floods:\n{log}"
    );
    assert!(!log.contains("panicked"), "{log}");
}
