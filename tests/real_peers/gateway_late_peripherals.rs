//! A box that starts before its peripherals (issue 40.4, issue 33.5): the real `retrocomp run`
//! binary is started while the socketcand hub, the weighing pty and the controller (hil-sim's PLC on
//! Modbus TCP) are all absent. It must not exit: from its first status snapshot `/status`, `/metrics`
//! and `/api/faults` show the CAN source, the serial source and the origin-shift sink as
//! `disconnected` (the 503 "no cycle run yet" only until the first start-up snapshot, 0.2 s), each failure is logged as one readable chain
//! (no Debug struct, the cause once). Then the hub and hil-sim (PLC + pty) come up 5 s later and the
//! gateway compensates (every axis has a target, the sink writes, no link fault left) within 2 s of
//! the last of them appearing: the reopen backoff of the sources is capped at 1 s
//! (`gateway/sources.rs`) and the sink retries its first read every 50 ms.

use crate::configs;
use crate::gateway;
use crate::hil_sim;
use crate::peers;
use crate::run;

use std::process::Command;
use std::time::{Duration, Instant};

use gateway::{Gateway, has_fault, metric};
use retrocomp_bus::can::Hub;

/// How long the peripherals stay away after the gateway started.
const ABSENT_S: f64 = 5.0;
/// The bound: compensating within this long after the last peripheral appeared, s.
const BACK_WITHIN_S: f64 = 2.0;

const SINK: &str = "sink.origin_shift";

fn sink_disconnected(st: &serde_json::Value) -> bool {
    st["active_faults"]
        .as_array()
        .is_some_and(|f| f.iter().any(|f| f[0] == SINK && f[1] == "disconnected"))
}

/// Every axis has a model target, the sink wrote, and no link fault is left.
fn compensating(st: &serde_json::Value) -> bool {
    let axes = st["axes"].as_array().cloned().unwrap_or_default();
    !axes.is_empty()
        && axes.iter().all(|a| a["target_um"].is_number())
        && st["sink"]["writes_ok"].as_u64().is_some_and(|n| n > 0)
        && !has_fault(st, "can", "disconnected")
        && !has_fault(st, "serial.scale", "disconnected")
        && !sink_disconnected(st)
}

#[test]
fn a_gateway_started_before_its_hub_serial_line_and_controller_waits_for_them() {
    let _turn = crate::turn::take(file!());
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    let dir = run::run_dir("gateway_late_peripherals");
    let (hub_port, plc_port, status_port) =
        (peers::free_port(), peers::free_port(), peers::free_port());
    let pty = dir.join("weighing-pty");
    let truth = run::demo_truth_model();
    let field = dir.join("field.toml");
    let text = configs::field_toml(hub_port, &format!("127.0.0.1:{plc_port}"), &pty).replace(
        "status_listen = \"127.0.0.1:0\"",
        &format!("status_listen = \"127.0.0.1:{status_port}\""),
    );
    assert!(text.contains(&format!(":{status_port}\"")));
    std::fs::write(&field, text).unwrap();

    let mut cmd = Command::new(env!("CARGO_BIN_EXE_retrocomp"));
    cmd.arg("run")
        .arg("--config")
        .arg(&field)
        .arg("--model")
        .arg(&truth)
        .env("NO_COLOR", "1");
    let started = Instant::now();
    let mut gw = Gateway::spawn(cmd, status_port);

    // The status endpoint answers "no cycle run yet" only until the first start-up snapshot (published
    // every 0.2 s while the sink waits for the controller): a snapshot with the faults comes within
    // the first second of the endpoint's first answer (issue 33.5: "from the first second").
    let mut answered: Option<Instant> = None;
    let first = loop {
        if let Some(st) = gw.exited() {
            panic!(
                "the gateway exited at start ({st}):\n{}",
                gw.log().join("\n")
            );
        }
        if let Some(answer) = gw.get_any("/status") {
            let since = *answered.get_or_insert_with(Instant::now);
            if answer.0 == 200 {
                break answer;
            }
            assert!(
                since.elapsed() < Duration::from_secs(1),
                "still {answer:?} 1 s after the endpoint first answered:\n{}",
                gw.log().join("\n")
            );
        }
        assert!(
            started.elapsed() < gateway::PATIENCE,
            "no status endpoint:\n{}",
            gw.log().join("\n")
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let st: serde_json::Value = serde_json::from_str(&first.1).unwrap();
    // The sink's fault comes with its first failed read; the sources' with their first publish.
    let st = if sink_disconnected(&st) && has_fault(&st, "can", "disconnected") {
        st
    } else {
        gw.wait_status("the three link faults", |s| {
            sink_disconnected(s) && has_fault(s, "can", "disconnected")
        })
    };
    assert!(has_fault(&st, "can", "disconnected"), "{st:#}");
    assert!(has_fault(&st, "serial.scale", "disconnected"), "{st:#}");
    assert!(sink_disconnected(&st), "{st:#}");
    assert_eq!(st["sink"]["connected"], false, "{st:#}");
    assert_eq!(
        st["cycles"], 0,
        "no cycle before the controller answered: {st:#}"
    );
    let metrics = gw
        .get("/metrics")
        .expect("/metrics answers before the first cycle");
    assert!(
        metrics.contains("retrocomp_"),
        "no retrocomp series in /metrics:\n{metrics}"
    );
    assert_eq!(
        metric(&metrics, "retrocomp_source_connected{source=\"can\"}"),
        Some(0.0),
        "{metrics}"
    );
    assert_eq!(
        metric(&metrics, "retrocomp_sink_connected{sink=\"origin_shift\"}"),
        Some(0.0),
        "{metrics}"
    );
    assert_eq!(
        metric(
            &metrics,
            "retrocomp_sink_fault_active{source=\"sink.origin_shift\",kind=\"disconnected\"}"
        ),
        Some(1.0),
        "{metrics}"
    );
    let faults = gw.get("/api/faults").expect("/api/faults answers");
    assert!(
        faults.contains(SINK) && faults.contains("serial.scale"),
        "{faults}"
    );

    // Still running when the peripherals come.
    let due = started + Duration::from_secs_f64(ABSENT_S);
    std::thread::sleep(due.saturating_duration_since(Instant::now()));
    if let Some(st) = gw.exited() {
        panic!("the gateway gave up ({st}):\n{}", gw.log().join("\n"));
    }
    let log = gw.log();
    let can_line = log
        .iter()
        .find(|l| l.contains("opening CAN backend"))
        .unwrap_or_else(|| panic!("no CAN open failure logged:\n{}", log.join("\n")));
    assert!(
        can_line.contains(&format!("socketcand 127.0.0.1:{hub_port} channel can0"))
            && !can_line.contains("Socketcand {"),
        "{can_line}"
    );
    assert_eq!(can_line.matches("os error").count(), 1, "{can_line}");
    assert!(
        log.iter().any(|l| l.contains("serial source \"scale\"")),
        "no serial open failure logged:\n{}",
        log.join("\n")
    );

    // The hub, then hil-sim (its PLC on the configured port and the weighing pty).
    let _hub = Hub::start_on_thread(([127, 0, 0, 1], hub_port).into(), Some(20)).unwrap();
    let sim_cfg = dir.join("sim.toml");
    let sim_text = configs::sim_machine_toml(2, &truth)
        + &configs::sim_io_toml(hub_port, &pty, None)
            .replace("127.0.0.1:0", &format!("127.0.0.1:{plc_port}"));
    std::fs::write(&sim_cfg, sim_text).unwrap();
    let mut sim = run::Sim::spawn(&hil_sim, &sim_cfg, &dir.join("out"));
    sim.wait_for(&["hil-sim: modbus tcp on ", "hil-sim: weighing lines on "]);
    let appeared = Instant::now();
    let st = gw.wait_status("compensation after the peripherals came", compensating);
    let took_s = appeared.elapsed().as_secs_f64();
    let _ = sim.child.kill();
    let _ = sim.child.wait();
    assert!(
        took_s <= BACK_WITHIN_S,
        "compensating {took_s:.2} s after the last peripheral appeared (bound {BACK_WITHIN_S} s): {st:#}\n{}",
        gw.log().join("\n")
    );
    assert!(gw.exited().is_none(), "{}", gw.log().join("\n"));
}
