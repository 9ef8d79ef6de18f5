//! The server mode's last step on the real `retrocomp run` binary against real pymodbus clients
//! (issue 33: "server mode serves 3275.7 µm with a 50 µm clamp", "server mode ignores SIGTERM"),
//! with the LinuxCNC sim kit's field config (`deploy/linuxcnc/sim/retrocomp-sim.toml`: clamp 50 µm
//! = 500 counts, cap 1 µm = 10 counts per update) on loopback ports:
//!
//! 1. one client writes positions/held/marker with FC16 at registers 10–16 (X/Y/Z positions in
//!    25 µm counts, X/Y/Z held, the marker 0x55AA), a second client sends FC06 to X's held
//!    register 13 = 0x7FFF (3276.7 µm held): every FC03 read of the
//!    correction register before and after is an exception or within 500 counts, and `/status`
//!    and `/metrics` show the `beyond_clamp` fault of `sink.origin_shift_server.x` with the held
//!    value;
//! 2. an mb2hal-like controller (reads the correction, applies it, writes back position, held and
//!    marker every 20 ms) brings the axis back; on SIGTERM the box serves a ramp to 0 within the cap
//!    until the controller reports holding 0, says so in its log, and exits;
//! 3. a PLC master reporting what it holds one axis at a time (marker, then one FC06 per held
//!    register) is not served until every axis is in, then from what it holds, within one cap.

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::gateway;
use crate::peers;

use gateway::{Gateway, PATIENCE};

/// Phase 1: seed, then a rogue FC06 of 0x7FFF to the held register from a second connection.
/// Prints `read <counts>` or `read exc` for every FC03 of register 0.
const ROGUE: &str = r#"
import sys, time
from pymodbus.client import ModbusTcpClient
port = int(sys.argv[1])
a = ModbusTcpClient("127.0.0.1", port=port); assert a.connect()
b = ModbusTcpClient("127.0.0.1", port=port); assert b.connect()
def read():
    r = a.read_holding_registers(0, count=1)
    if r.isError():
        print("read exc", flush=True); return None
    v = r.registers[0] - 65536 if r.registers[0] >= 32768 else r.registers[0]
    print(f"read {v}", flush=True); return v
r = a.write_registers(10, [6000, 4000, 4000, 0, 0, 0, 21930])
assert not r.isError(), r
deadline = time.time() + 60
while read() is None:
    assert time.time() < deadline, "never served"
    time.sleep(0.02)
for _ in range(10):
    read(); time.sleep(0.02)
r = b.write_register(13, 0x7FFF)
assert not r.isError(), r
print("rogue", flush=True)
for _ in range(40):
    read(); time.sleep(0.02)
"#;

/// Phase 2: the controller's cycle every 20 ms until the box is gone: read the correction (an
/// exception: keep what is applied), apply it, write position, held and marker (FC16 at 10).
const CONTROLLER: &str = r#"
import sys, time
from pymodbus.client import ModbusTcpClient
port = int(sys.argv[1])
a = ModbusTcpClient("127.0.0.1", port=port, retries=0); assert a.connect()
applied = [0, 0, 0]
while True:
    try:
        for k in range(3):
            r = a.read_holding_registers(k, count=1)
            if r.isError():
                if k == 0:
                    print("read exc", flush=True)
                continue
            v = r.registers[0]
            applied[k] = v - 65536 if v >= 32768 else v
            if k == 0:
                print(f"read {applied[0]}", flush=True)
        w = a.write_registers(10, [6000, 4000, 4000] + [v & 0xFFFF for v in applied] + [21930])
        if w.isError():
            print("write exc", flush=True)
    except Exception as e:
        print(f"gone {e}", flush=True)
        break
    if not a.connected:
        print("gone", flush=True)
        break
    time.sleep(0.02)
"#;

const MAX_COUNTS: i64 = 500;
const CAP_COUNTS: i64 = 10;

fn config(modbus_port: u16, status_port: u16) -> String {
    let root = env!("CARGO_MANIFEST_DIR");
    let base =
        std::fs::read_to_string(format!("{root}/deploy/linuxcnc/sim/retrocomp-sim.toml")).unwrap();
    let cfg = base
        .replace("127.0.0.1:1502", &format!("127.0.0.1:{modbus_port}"))
        .replace("127.0.0.1:9184", &format!("127.0.0.1:{status_port}"))
        .replace(
            "path = \"../../field/vmc-geometry.toml\"",
            &format!("path = \"{root}/deploy/field/vmc-geometry.toml\""),
        );
    assert!(
        cfg.contains(&format!("{root}/deploy/field/vmc-geometry.toml")),
        "{cfg}"
    );
    assert!(cfg.contains(&format!("127.0.0.1:{modbus_port}")), "{cfg}");
    cfg
}

/// `retrocomp run` on the kit's config (loopback ports), once its Modbus server listens.
fn start(dir: &std::path::Path) -> (Gateway, u16) {
    let (modbus_port, status_port) = (peers::free_port(), peers::free_port());
    let cfg_path = dir.join("sim.toml");
    let mut f = std::fs::File::create(&cfg_path).unwrap();
    f.write_all(config(modbus_port, status_port).as_bytes())
        .unwrap();
    let gw = Gateway::start_args(&["run", "--config"], &cfg_path, status_port, &[]);
    wait_until("the Modbus server listening", || {
        std::net::TcpStream::connect(("127.0.0.1", modbus_port)).is_ok()
    });
    (gw, modbus_port)
}

/// A pymodbus script as a child; its stdout lines collected as they come.
fn python(script: &str, port: u16) -> (std::process::Child, Arc<Mutex<Vec<String>>>) {
    let mut child = Command::new(peers::python())
        .args(["-c", script, &port.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the pymodbus client");
    let lines = Arc::new(Mutex::new(Vec::new()));
    let (out, sink) = (child.stdout.take().unwrap(), lines.clone());
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            sink.lock().unwrap().push(l);
        }
    });
    (child, lines)
}

/// The counts of the `read <n>` lines (exceptions skipped).
fn reads(lines: &[String]) -> Vec<i64> {
    lines
        .iter()
        .filter_map(|l| l.strip_prefix("read "))
        .filter_map(|v| v.parse().ok())
        .collect()
}

fn wait_until(what: &str, mut pred: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !pred() {
        assert!(t0.elapsed() < PATIENCE, "{what} within {PATIENCE:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_rogue_held_write_is_never_served_and_sigterm_ramps_the_served_value_out() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (mut gw, modbus_port) = start(dir.path());

    // 1. The reported scenario.
    let (mut rogue, lines) = python(ROGUE, modbus_port);
    let status = rogue.wait().unwrap();
    let lines = lines.lock().unwrap().clone();
    assert!(status.success(), "pymodbus failed: {lines:?}");
    let at = lines.iter().position(|l| l == "rogue").unwrap();
    let (before, after) = (reads(&lines[..at]), reads(&lines[at..]));
    assert!(!before.is_empty(), "nothing was served before: {lines:?}");
    for v in before.iter().chain(&after) {
        assert!(
            v.abs() <= MAX_COUNTS,
            "served {v} counts, clamp {MAX_COUNTS}: {lines:?}"
        );
    }
    let st = gw.wait_status("the beyond_clamp fault of the served axis", |s| {
        s["sink"]["faults"].as_array().is_some_and(|f| {
            f.iter().any(|x| {
                x[0] == "sink.origin_shift_server.x" && x[1].as_str() == Some("beyond_clamp")
            })
        })
    });
    let held = st["sink"]["held_um"]["x"].as_f64().unwrap();
    assert!((held - 3276.7).abs() < 1e-6, "status shows {held} µm held");
    let metrics = gw.get("/metrics").unwrap();
    assert!(
        metrics.contains(
            "retrocomp_sink_fault_active{source=\"sink.origin_shift_server.x\",kind=\"beyond_clamp\"} 1"
        ),
        "{metrics}"
    );
    assert_eq!(
        gw.log_lines(&["origin-shift server fault", "kind=\"beyond_clamp\""])
            .len(),
        1,
        "one log line at the fault's start:\n{}",
        gw.log().join("\n")
    );

    // 2. The controller's own reports bring the axis back; SIGTERM ramps it out.
    let (mut controller, lines) = python(CONTROLLER, modbus_port);
    wait_until("the controller applying served values again", || {
        reads(&lines.lock().unwrap()).len() >= 20
    });
    gw.wait_status("the fault cleared", |s| {
        s["sink"]["faults"].as_array().is_some_and(|f| f.is_empty())
    });
    let exit = gw.stop();
    let _ = controller.wait();
    let lines = lines.lock().unwrap().clone();
    let applied = reads(&lines);
    for w in applied.windows(2) {
        assert!(
            (w[1] - w[0]).abs() <= CAP_COUNTS && w[1].abs() <= MAX_COUNTS,
            "step {} → {} counts (cap {CAP_COUNTS}): {lines:?}",
            w[0],
            w[1]
        );
    }
    assert_eq!(applied.last(), Some(&0), "{lines:?}");
    let log = gw.log().join("\n");
    assert!(
        !gw.log_lines(&["ramped out: the controller reports holding 0"])
            .is_empty(),
        "{log}"
    );
    assert!(exit.success(), "{exit}\n{log}");
}

/// A PLC's master block that reports what it holds one axis at a time (positions in one FC16,
/// the marker, then one FC06 per held register), the correction (2, −3, 4) µm = (20, −30, 40)
/// counts, beside a box that has just started. After each partial report it reads the
/// corrections (`partial exc` or `partial ok x y z`) while five update periods pass; after the
/// last, `read x y z` for every served FC03 of registers 0–2, then `done`. From Z's report on it
/// reports what it holds every 20 ms (one FC06 per axis), as a master does each cycle, so the box
/// never sees it silent (`controller_timeout_ms`), and it runs until the test kills it.
const ONE_AXIS_AT_A_TIME: &str = r#"
import sys, time
from pymodbus.client import ModbusTcpClient
port = int(sys.argv[1])
a = ModbusTcpClient("127.0.0.1", port=port, retries=0); assert a.connect()
def s16(v):
    return v - 65536 if v >= 32768 else v
def corrections(tag):
    r = a.read_holding_registers(0, count=3)
    if r.isError():
        print(f"{tag} exc", flush=True); return False
    print(f"{tag} ok " + " ".join(str(s16(v)) for v in r.registers), flush=True)
    return True
def partial():
    for _ in range(5):
        corrections("partial"); time.sleep(0.02)
for address, value in [(16, 21930), (13, 20), (14, -30 & 0xFFFF)]:
    if address == 16:
        assert not a.write_registers(10, [6000, 4000, 4000]).isError()
    assert not a.write_register(address, value).isError()
    partial()
assert not a.write_register(15, 40).isError()
def report():
    for address, value in [(13, 20), (14, -30 & 0xFFFF), (15, 40)]:
        assert not a.write_register(address, value).isError()
deadline = time.time() + 60
while not corrections("read"):
    assert time.time() < deadline, "never served"
    report(); time.sleep(0.02)
for _ in range(20):
    report(); corrections("read"); time.sleep(0.02)
print("done", flush=True)
while True:
    report(); time.sleep(0.02)
"#;

#[test]
fn a_controller_reporting_one_axis_at_a_time_is_resumed_from_what_it_holds() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (gw, modbus_port) = start(dir.path());
    let (mut plc, out) = python(ONE_AXIS_AT_A_TIME, modbus_port);
    wait_until("the PLC's master done reading", || {
        let done = out.lock().unwrap().iter().any(|l| l == "done");
        assert!(
            done || plc.try_wait().unwrap().is_none(),
            "pymodbus failed: {:?}",
            out.lock().unwrap()
        );
        done
    });
    let lines = out.lock().unwrap().clone();

    // Registers nobody has written are no report of 0: nothing is served before Z's.
    let partial: Vec<&String> = lines.iter().filter(|l| l.starts_with("partial")).collect();
    assert_eq!(partial.len(), 15, "{lines:?}");
    assert!(
        partial.iter().all(|l| *l == "partial exc"),
        "served before every axis was reported: {lines:?}"
    );
    // Then it resumes from what the controller holds, never beyond one cap of it.
    let held = [20, -30, 40];
    let served: Vec<Vec<i64>> = lines
        .iter()
        .filter_map(|l| l.strip_prefix("read ok "))
        .map(|v| v.split(' ').map(|w| w.parse().unwrap()).collect())
        .collect();
    assert!(served.len() >= 21, "{lines:?}");
    for v in &served {
        for (k, (s, h)) in v.iter().zip(held).enumerate() {
            assert!(
                (s - h).abs() <= CAP_COUNTS,
                "axis {k}: served {s} counts, the controller holds {h} (cap {CAP_COUNTS}): {lines:?}"
            );
        }
    }
    let st = gw.status().expect("/status");
    assert_eq!(st["sink"]["faults"], serde_json::json!([]), "{st}");
    for (axis, um) in [("x", 2.0), ("y", -3.0), ("z", 4.0)] {
        let h = st["sink"]["held_um"][axis].as_f64().unwrap();
        assert!((h - um).abs() < 1e-9, "status: {axis} holds {h} µm");
    }
    assert!(
        gw.log_lines(&["origin-shift server fault"]).is_empty(),
        "no fault episode: {}",
        gw.log().join("\n")
    );
    let _ = plc.kill();
    let _ = plc.wait();
}
