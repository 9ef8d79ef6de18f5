//! Modbus source failures are fault episodes. The real `retrocomp run` binary polls a pymodbus
//! device (tests/peers/pymodbus_flaky.py) that is not there at start (every poll fails), then comes
//! up, then answers every read with exception 02 (illegal data address), then recovers. Each episode
//! is a fault of the source `modbus.pt100` (`disconnected`, `exception`): logged once at start and
//! once at clear, shown in `/status` and `/metrics` while it lasts. The axis position comes from a
//! socketcand peer (tests/peers/socketcand_flaky.py) so the config is a complete one.

use crate::gateway;
use crate::peers;

use gateway::{Gateway, field_toml, has_fault, metric, source};

const SRC: &str = "modbus.pt100";

fn t_spindle(st: &serde_json::Value) -> &serde_json::Value {
    &st["channels"]["T_spindle_C"]
}

#[test]
fn failed_polls_and_exception_replies_are_fault_episodes() {
    let _turn = crate::turn::take(file!());
    let mut can_peer = peers::spawn_python("socketcand_flaky.py", &[]);
    let can_port: u16 = can_peer
        .line(20)
        .strip_prefix("PORT ")
        .and_then(|p| p.parse().ok())
        .expect("peer prints PORT <n>");
    can_peer.send("counts 100000");
    can_peer.expect("OK counts 100000", 20);
    let mb_port = peers::free_port();
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("field.toml");
    let status_port = peers::free_port();
    let sources = format!(
        r#"[can]
backend = "socketcand"
host = "127.0.0.1"
port = {can_port}
channel = "can0"
[[modbus.source]]
name = "pt100"
transport = "tcp"
host = "127.0.0.1"
port = {mb_port}
period_s = 0.05
timeout_s = 0.5
backoff_min_s = 0.1
backoff_max_s = 0.5
channel = [{{ channel = "T_spindle_C", kind = "input", address = 0, type = "int16", scale = 0.1 }}]
"#
    );
    std::fs::write(&cfg, field_toml(status_port, &sources)).unwrap();
    let mut gw = Gateway::start(&cfg, status_port, &[]);

    // No device yet: every poll fails. The fault can be in the status before the first failed
    // connect is counted (a loaded host): wait for both.
    let st = gw.wait_status("the Modbus source down", |s| {
        has_fault(s, SRC, "disconnected")
            && source(s, SRC)["modbus"]["connect_failures"].as_u64() > Some(0)
    });
    assert_eq!(source(&st, SRC)["connected"], false, "{st:#}");
    assert!(
        source(&st, SRC)["modbus"]["connect_failures"].as_u64() > Some(0),
        "{st:#}"
    );

    // The device comes up.
    let mut mb = peers::spawn_python("pymodbus_flaky.py", &[&mb_port.to_string()]);
    let st = gw.wait_status("21.5 °C from the device", |s| {
        t_spindle(s)["value"].as_f64() == Some(21.5) && t_spindle(s)["health"] == "ok"
    });
    assert!(!has_fault(&st, SRC, "disconnected"), "{st:#}");
    assert_eq!(source(&st, SRC)["connected"], true, "{st:#}");

    // Exception replies: the link is up, the device says no.
    mb.send("exceptions");
    mb.expect("OK exceptions", 20);
    let st = gw.wait_status("exception replies", |s| has_fault(s, SRC, "exception"));
    assert_eq!(source(&st, SRC)["connected"], true, "{st:#}");
    assert!(!has_fault(&st, SRC, "disconnected"), "{st:#}");
    let m = gw.get("/metrics").unwrap();
    let exceptions = metric(
        &m,
        "retrocomp_modbus_exceptions_total{source=\"modbus.pt100\"}",
    );
    assert!(exceptions.is_some_and(|n| n >= 1.0), "{m}");
    assert_eq!(
        metric(
            &m,
            "retrocomp_source_faults_active{source=\"modbus.pt100\"}"
        ),
        Some(1.0),
        "{m}"
    );

    mb.send("normal");
    mb.expect("OK normal", 20);
    let st = gw.wait_status("the exceptions over", |s| {
        !has_fault(s, SRC, "exception") && t_spindle(s)["health"] == "ok"
    });
    assert_eq!(t_spindle(&st)["value"].as_f64(), Some(21.5), "{st:#}");

    let exit = gw.stop();
    let log = gw.log().join("\n");
    assert!(exit.success(), "{exit:?}\n{log}");
    for kind in ["disconnected", "exception"] {
        let lines = |what: &str| {
            gw.log_lines(&[what, "source=\"modbus.pt100\"", &format!("kind=\"{kind}\"")])
                .len()
        };
        assert_eq!(lines("fault started"), 1, "{kind} start lines:\n{log}");
        assert_eq!(lines("fault cleared"), 1, "{kind} clear lines:\n{log}");
    }
}
