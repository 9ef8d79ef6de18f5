//! A CAN source comes back by itself. The real `retrocomp run` binary reads a CiA 406 encoder over a
//! socketcand server that hangs up, refuses connections for a while and comes back
//! (tests/peers/socketcand_flaky.py: Debian ships no socketcand package; the peer speaks the protocol
//! of linux-can/socketcand and checks every message with python-can's client parser), then reports
//! bus-off and a controller restart with socketcand's `< error CLASS t >` error frames.
//!
//! Checked, all by events (no timing window): samples flow again after the reconnect (a position
//! sent only after it shows in `/status`), the NMT start is sent again, the link loss and the
//! bus-off are each a fault logged once at start and once at clear, shown in `/status`
//! (`sources`, `active_faults`) and `/metrics` while they last.

use crate::gateway;
use crate::peers;

use gateway::{Gateway, field_toml, has_fault, metric, source};

fn z_mm(st: &serde_json::Value) -> Option<f64> {
    st["channels"]["z_mm"]["value"].as_f64()
}

fn fault_lines(gw: &Gateway, what: &str, kind: &str) -> usize {
    gw.log_lines(&[what, "source=\"can\"", &format!("kind=\"{kind}\"")])
        .len()
}

#[test]
fn socketcand_peer_hangs_up_and_comes_back_and_reports_bus_off() {
    let _turn = crate::turn::take(file!());
    let mut peer = peers::spawn_python("socketcand_flaky.py", &[]);
    let port: u16 = peer
        .line(20)
        .strip_prefix("PORT ")
        .and_then(|p| p.parse().ok())
        .expect("peer prints PORT <n>");
    peer.send("counts 100000");
    peer.expect("OK counts 100000", 20);
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("field.toml");
    let status_port = peers::free_port();
    let can = format!(
        "[can]\nbackend = \"socketcand\"\nhost = \"127.0.0.1\"\nport = {port}\nchannel = \"can0\"\n"
    );
    std::fs::write(&cfg, field_toml(status_port, &can)).unwrap();
    let mut gw = Gateway::start(&cfg, status_port, &[]);
    peer.expect("CONNECTED 1", 60);

    let st = gw.wait_status("z = 100 mm from the first connection", |s| {
        z_mm(s) == Some(100.0)
    });
    assert_eq!(source(&st, "can")["connected"], true, "{st:#}");
    assert!(!has_fault(&st, "can", "disconnected"));

    // The peer hangs up and refuses connections: the link is a fault, shown while it lasts.
    peer.send("hangup");
    peer.expect("HUNGUP", 20);
    let st = gw.wait_status("the CAN link down", |s| {
        source(s, "can")["connected"] == false
    });
    assert!(has_fault(&st, "can", "disconnected"), "{st:#}");
    let m = gw.get("/metrics").unwrap();
    assert_eq!(
        metric(&m, "retrocomp_source_connected{source=\"can\"}"),
        Some(0.0),
        "{m}"
    );

    // It comes back with a new position: the source reconnects by itself and the new value flows.
    peer.send("counts 200000");
    peer.expect("OK counts 200000", 20);
    peer.send("listen");
    peer.expect("LISTENING", 20);
    peer.expect("CONNECTED 2", 60);
    // The bring-up (NMT start node 1: `send 000 2 01 01`) is sent again on the new connection.
    let mut seen = Vec::new();
    loop {
        let l = peer.line(60);
        if l.starts_with("RX < send 000 2 01 01") {
            break;
        }
        seen.push(l);
        assert!(
            seen.len() < 100,
            "no NMT start after the reconnect: {seen:?}"
        );
    }
    let st = gw.wait_status("z = 200 mm after the reconnect", |s| {
        z_mm(s) == Some(200.0) && source(s, "can")["connected"] == true
    });
    assert_eq!(st["channels"]["z_mm"]["health"], "ok", "{st:#}");
    assert_eq!(source(&st, "can")["reconnects"], 1, "{st:#}");
    assert!(!has_fault(&st, "can", "disconnected"), "{st:#}");
    assert!(
        source(&st, "can")["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("closed") || e.contains("refused")),
        "{st:#}"
    );
    let m = gw.get("/metrics").unwrap();
    assert_eq!(
        metric(&m, "retrocomp_source_connected{source=\"can\"}"),
        Some(1.0),
        "{m}"
    );
    assert_eq!(
        metric(&m, "retrocomp_source_reconnects_total{source=\"can\"}"),
        Some(1.0),
        "{m}"
    );

    // Bus-off (socketcand forwards the kernel's error frame class 0x040) until a restart (0x100).
    peer.send("busoff");
    peer.expect("SENT busoff", 20);
    let st = gw.wait_status("bus-off", |s| source(s, "can")["can"]["state"] == "bus_off");
    assert!(has_fault(&st, "can", "bus_off"), "{st:#}");
    let m = gw.get("/metrics").unwrap();
    assert_eq!(
        metric(&m, "retrocomp_can_bus_state{source=\"can\"}"),
        Some(3.0),
        "{m}"
    );
    assert_eq!(
        metric(&m, "retrocomp_can_bus_off_total{source=\"can\"}"),
        Some(1.0),
        "{m}"
    );
    assert_eq!(
        metric(&m, "retrocomp_can_error_frames_total{source=\"can\"}"),
        Some(1.0),
        "{m}"
    );
    peer.send("counts 300000");
    peer.expect("OK counts 300000", 20);
    peer.send("restarted");
    peer.expect("SENT restarted", 20);
    let st = gw.wait_status("the bus back and z = 300 mm", |s| {
        source(s, "can")["can"]["state"] == "active" && z_mm(s) == Some(300.0)
    });
    assert!(!has_fault(&st, "can", "bus_off"), "{st:#}");
    // BusErrors holds 1 s after the last error frame, then clears (event: wait for it).
    gw.wait_status("the bus-errors episode over", |s| {
        !has_fault(s, "can", "bus_errors")
    });

    let exit = gw.stop();
    assert!(exit.success(), "{exit:?}\n{}", gw.log().join("\n"));
    let log = gw.log().join("\n");
    for kind in ["disconnected", "bus_off", "bus_errors"] {
        assert_eq!(
            fault_lines(&gw, "fault started", kind),
            1,
            "{kind} start lines:\n{log}"
        );
        assert_eq!(
            fault_lines(&gw, "fault cleared", kind),
            1,
            "{kind} clear lines:\n{log}"
        );
    }
    assert!(!log.contains("CAN source stopped"), "{log}");
}
