//! Supervision of the real `retrocomp run` binary for systemd, with a socketcand peer
//! (tests/peers/socketcand_flaky.py) feeding its CAN source:
//! - a source task that panics ends the process with status 70 and an ERROR line; one that returns
//!   stops it with status 1 (injected by hil-sim's `faulty_box`, which runs the gateway through the
//!   same library call as `retrocomp run`: every real source failure is retried, and the product
//!   binary has no test hook);
//! - the systemd notify protocol, read from a unix datagram socket the test owns (`NOTIFY_SOCKET`):
//!   `READY=1` once the cycle runs, then `WATCHDOG=1`, and no more pings once the cycle hangs (test
//!   `faulty_box --fault hang-after:N`: the model evaluation blocks forever).
//!
//! systemd itself is not in this container (no PID 1 systemd, no `systemd-run`): the unit file's
//! `Type=notify` / `WatchdogSec=` are exercised through the protocol they use.

use crate::gateway;
use crate::hil_sim;
use crate::peers;

use std::os::unix::net::UnixDatagram;
use std::process::Command;
use std::time::{Duration, Instant};

use gateway::{Gateway, PATIENCE, field_toml};

/// `faulty_box --config <cfg> --fault <fault>` with `envs`, watched as a gateway.
fn faulty(cfg: &std::path::Path, status_port: u16, fault: &str, envs: &[(&str, &str)]) -> Gateway {
    let mut cmd = Command::new(hil_sim::faulty_box_next_to_retrocomp());
    cmd.args(["--config", cfg.to_str().unwrap(), "--fault", fault]);
    for (k, v) in envs {
        cmd.env(k, v);
    }
    Gateway::spawn(cmd, status_port)
}

/// A socketcand peer sending z = 100 mm, and a field config reading it.
fn setup(dir: &std::path::Path) -> (peers::Peer, std::path::PathBuf, u16) {
    let mut peer = peers::spawn_python("socketcand_flaky.py", &[]);
    let port: u16 = peer
        .line(20)
        .strip_prefix("PORT ")
        .and_then(|p| p.parse().ok())
        .expect("peer prints PORT <n>");
    peer.send("counts 100000");
    peer.expect("OK counts 100000", 20);
    let cfg = dir.join("field.toml");
    let status_port = peers::free_port();
    let can = format!(
        "[can]\nbackend = \"socketcand\"\nhost = \"127.0.0.1\"\nport = {port}\nchannel = \"can0\"\n"
    );
    std::fs::write(&cfg, field_toml(status_port, &can)).unwrap();
    (peer, cfg, status_port)
}

#[test]
fn a_panicking_source_task_ends_the_process_with_status_70() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (_peer, cfg, status_port) = setup(dir.path());
    let mut gw = faulty(&cfg, status_port, "source-panic", &[]);
    let exit = gw.wait_exit();
    let log = gw.log().join("\n");
    assert_eq!(exit.code(), Some(70), "{exit:?}\n{log}");
    assert_eq!(
        gw.log_lines(&["ERROR", "a gateway task panicked"]).len(),
        1,
        "{log}"
    );
}

#[test]
fn a_source_task_that_returns_stops_the_process_with_an_error() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (_peer, cfg, status_port) = setup(dir.path());
    let mut gw = faulty(&cfg, status_port, "source-return", &[]);
    let exit = gw.wait_exit();
    let log = gw.log().join("\n");
    assert_eq!(exit.code(), Some(1), "{exit:?}\n{log}");
    assert!(
        !gw.log_lines(&["ERROR", "a gateway task ended", "task=\"can\""])
            .is_empty(),
        "{log}"
    );
    assert!(log.contains("error: task `can` ended"), "{log}");
}

/// Next notify datagram, as its `KEY=VALUE` lines; None after `wait`.
fn recv_notify(sock: &UnixDatagram, wait: Duration) -> Option<Vec<String>> {
    sock.set_read_timeout(Some(wait)).unwrap();
    let mut buf = [0u8; 4096];
    let n = sock.recv(&mut buf).ok()?;
    Some(
        String::from_utf8_lossy(&buf[..n])
            .lines()
            .map(str::to_string)
            .collect(),
    )
}

#[test]
fn ready_then_watchdog_pings_and_no_pings_once_the_cycle_hangs() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (_peer, cfg, status_port) = setup(dir.path());
    let sock_path = dir.path().join("notify.sock");
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    let sock_str = sock_path.to_str().unwrap();
    // WATCHDOG_USEC = 0.2 s: the gateway looks at its cycle counter every 0.1 s.
    let gw = faulty(
        &cfg,
        status_port,
        "hang-after:200",
        &[("NOTIFY_SOCKET", sock_str), ("WATCHDOG_USEC", "200000")],
    );
    let mut got = Vec::new();
    let t0 = Instant::now();
    // READY=1 first, then pings while the cycle runs (the hang comes after 200 model evaluations).
    while !got.iter().any(|m: &String| m == "WATCHDOG=1") {
        assert!(
            t0.elapsed() < PATIENCE,
            "no READY/WATCHDOG: {got:?}\n{}",
            gw.log().join("\n")
        );
        if let Some(msg) = recv_notify(&sock, Duration::from_secs(1)) {
            got.extend(msg);
        }
    }
    assert_eq!(got.first().map(String::as_str), Some("READY=1"), "{got:?}");
    assert_eq!(got.iter().filter(|m| *m == "READY=1").count(), 1, "{got:?}");
    // The cycle hangs: the hook says so in the log.
    let t0 = Instant::now();
    while gw.log_lines(&["faulty_box", "blocks forever"]).is_empty() {
        assert!(
            t0.elapsed() < PATIENCE,
            "the hang hook never ran:\n{}",
            gw.log().join("\n")
        );
        while recv_notify(&sock, Duration::from_millis(10)).is_some() {}
    }
    // From now on at most one more ping (a look taken just before the hang) in 20 look periods;
    // a watchdog that pinged regardless of progress would send about 20.
    let mut after = Vec::new();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(2) {
        if let Some(msg) = recv_notify(&sock, Duration::from_millis(200)) {
            after.extend(msg);
        }
    }
    let pings = after.iter().filter(|m| *m == "WATCHDOG=1").count();
    assert!(pings <= 1, "{pings} pings after the cycle hung: {after:?}");
    // The process is alive (only the cycle hangs): systemd's WatchdogSec is what ends it.
    assert!(
        gw.get("/metrics").is_some(),
        "the status endpoint still answers"
    );
}
