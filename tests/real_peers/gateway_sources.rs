//! The gateway's Modbus and serial sources, end to end through the real `retrocomp run` binary:
//! temperatures from an in-process Modbus TCP server (crates/bus/src/modbus/server.rs, on 127.0.0.1), axis
//! positions (ND 522 DRO lines) and the spindle force (generic `F=…N` lines) from two socat ptys;
//! `retrocomp status --json` shows them Ok and the model (deploy/field/vmc-machine.toml) computing;
//! then the serial writer goes silent and the Modbus server goes down → those channels turn Stale,
//! and a force pty that vanishes and returns is reopened (the channel is Ok again).
//! Also: every shipped field config (deploy/field/) loads with its model, and every channel its model
//! needs is delivered by one of its sources.
//! The waits are bounds (10–20 s), not measurements. These sources (Modbus TCP, ND 522 lines, a
//! pty that vanishes) are not in the virtual-time harness, so this stays the test of their shells
//! (docs/hil-sim.md, "Real-peer timing → virtual time").
//! Peer: socat (`scripts/setup-peers.sh`).

use crate::peers;
use crate::process;

use std::collections::BTreeSet;
use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use retrocomp_bus::modbus::{RegisterBank, TcpServer};
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::ErrorModel;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_model::MachineModel;

fn status(port: u16) -> Option<serde_json::Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["status", "--json", "--addr", &format!("127.0.0.1:{port}")])
        .output()
        .unwrap();
    out.status
        .success()
        .then(|| serde_json::from_slice(&out.stdout).unwrap())
}

fn health(s: &serde_json::Value, ch: &str) -> String {
    s["channels"][ch]["health"]
        .as_str()
        .unwrap_or("")
        .to_string()
}

/// Poll `status --json` until `pred` holds (≤ `secs` s); returns the last status.
fn wait_for(port: u16, secs: u64, pred: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let t0 = std::time::Instant::now();
    let mut last = serde_json::Value::Null;
    while t0.elapsed() < Duration::from_secs(secs) {
        if let Some(s) = status(port) {
            if pred(&s) {
                return s;
            }
            last = s;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    last
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_binary_reads_modbus_temperatures_and_serial_lines_then_sees_them_go_stale() {
    let _turn = crate::turn::take(file!());
    // Temperatures: PT100 module image, int16 in 0.1 °C (input registers 0..2).
    let bank = RegisterBank::new();
    bank.set_input(0, &[235, 210, 205]);
    let server = TcpServer::start("127.0.0.1:0".parse().unwrap(), bank.clone())
        .await
        .unwrap();
    let mb_port = server.local_addr().port();

    let dir = tempfile::tempdir().unwrap();
    for d in ["dro", "f"] {
        std::fs::create_dir(dir.path().join(d)).unwrap();
    }
    let (socat_dro, dro_a, dro_b) = peers::socat_pair(&dir.path().join("dro"));
    let (socat_f, f_a, f_b) = peers::socat_pair(&dir.path().join("f"));
    let status_port = peers::free_port();
    let root = env!("CARGO_MANIFEST_DIR");
    let cfg_path = dir.path().join("field.toml");
    std::fs::write(
        &cfg_path,
        format!(
            r#"
[gateway]
name = "sources-loop"
cycle_ms = 5
thermal_period_s = 0.2
status_listen = "127.0.0.1:{status_port}"
[safety]
max_correction_um = 100.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 200.0
stale_hold_s = 0.5
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[model]
path = "{root}/deploy/field/vmc-machine.toml"
[[axis]]
name = "x"
position_channel = "x_mm"
[[axis]]
name = "y"
position_channel = "y_mm"
[[axis]]
name = "z"
position_channel = "z_mm"
[[modbus.source]]
name = "pt100"
transport = "tcp"
host = "127.0.0.1"
port = {mb_port}
period_s = 0.05
timeout_s = 0.2
backoff_min_s = 0.1
backoff_max_s = 0.5
channel = [
  {{ channel = "T_spindle_C", kind = "input", address = 0, type = "int16", scale = 0.1 }},
  {{ channel = "T_table_C", kind = "input", address = 1, type = "int16", scale = 0.1 }},
  {{ channel = "T_column_C", kind = "input", address = 2, type = "int16", scale = 0.1 }},
]
[[serial.source]]
name = "dro"
device = "{dro_b}"
format = {{ kind = "nd522" }}
period_s = 0.05
timeout_s = 0.3
channel = [ {{ name = "x_mm", key = "X" }}, {{ name = "y_mm", key = "Y" }}, {{ name = "z_mm", key = "Z" }} ]
[[serial.source]]
name = "force"
device = "{f_b}"
format = {{ kind = "generic", unit = "N" }}
period_s = 0.05
timeout_s = 0.3
channel = [ {{ name = "F_spindle_N" }} ]
[[channel]]
name = "T_spindle_C"
min = 5.0
max = 80.0
stale_after_s = 2.0
[[channel]]
name = "F_spindle_N"
min = -5000.0
max = 5000.0
stale_after_s = 0.3
[[channel]]
name = "x_mm"
min = -1.0
max = 801.0
stale_after_s = 0.3
"#,
            dro_b = dro_b.display(),
            f_b = f_b.display(),
        ),
    )
    .unwrap();

    let mut child = process::start_run(&["--dry-run"], &cfg_path);

    // The machine's serial side: DRO block and force line every 20 ms until told to stop.
    let talking = Arc::new(AtomicBool::new(true));
    let writer = {
        let talking = talking.clone();
        std::thread::spawn(move || {
            let mut dro = std::fs::OpenOptions::new()
                .write(true)
                .open(&dro_a)
                .unwrap();
            let mut f = std::fs::OpenOptions::new().write(true).open(&f_a).unwrap();
            while talking.load(Ordering::Relaxed) {
                dro.write_all(b"X=+100.000\r\nY=+200.000\r\nZ=+300.000\r\n")
                    .unwrap();
                f.write_all(b"F=1200.0N\r\n").unwrap();
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };

    let ok = |s: &serde_json::Value| {
        [
            "T_spindle_C",
            "T_table_C",
            "T_column_C",
            "F_spindle_N",
            "x_mm",
            "z_mm",
        ]
        .iter()
        .all(|c| health(s, c) == "ok")
            && s["axes"][2]["mode"] == "tracking"
    };
    let s = wait_for(status_port, 20, ok);
    assert!(ok(&s), "sources not all Ok / model not tracking: {s}");
    let value = |s: &serde_json::Value, c: &str| s["channels"][c]["value"].as_f64().unwrap();
    assert!((value(&s, "T_spindle_C") - 23.5).abs() < 1e-9, "{s}");
    assert!((value(&s, "T_column_C") - 20.5).abs() < 1e-9, "{s}");
    assert!((value(&s, "F_spindle_N") - 1200.0).abs() < 1e-9, "{s}");
    assert!((value(&s, "z_mm") - 300.0).abs() < 1e-9, "{s}");
    assert_eq!(s["model_error"], serde_json::Value::Null, "{s}");
    // The thermal term reached the model: spindle 3.5 K over 20 °C, −6 µm/K on EZZ → the Z axis
    // carries a spindle-growth term (its size depends on the sensor lag, so only its presence and
    // sign are checked: growth is negative error → positive correction).
    let z_terms = s["axes"][2]["terms_um"].as_object().unwrap();
    let growth = z_terms
        .iter()
        .find(|(k, _)| k.contains("spindle_growth"))
        .map(|(_, v)| v.as_f64().unwrap());
    assert!(
        growth.is_some_and(|v| v > 0.0),
        "z terms: {z_terms:?}; status {s}"
    );

    // Serial writer goes silent → DRO and force channels Stale; Modbus still Ok.
    talking.store(false, Ordering::Relaxed);
    writer.join().unwrap();
    let serial_stale =
        |s: &serde_json::Value| health(s, "F_spindle_N") == "stale" && health(s, "x_mm") == "stale";
    let s = wait_for(status_port, 10, serial_stale);
    assert!(serial_stale(&s), "serial channels not stale: {s}");
    assert_eq!(health(&s, "T_spindle_C"), "ok", "{s}");
    // Last good value is kept.
    assert!((value(&s, "F_spindle_N") - 1200.0).abs() < 1e-9, "{s}");

    // The force line's pty vanishes (USB adapter unplugged: socat killed, links gone) and comes
    // back: the source reopens the device and F_spindle_N is Ok again.
    drop(socat_f);
    std::thread::sleep(Duration::from_millis(300));
    let (socat_f, f_a2, f_b2) = peers::socat_pair(&dir.path().join("f"));
    assert_eq!(f_b2, f_b);
    let talking = Arc::new(AtomicBool::new(true));
    let writer = {
        let talking = talking.clone();
        std::thread::spawn(move || {
            let mut f = std::fs::OpenOptions::new().write(true).open(&f_a2).unwrap();
            while talking.load(Ordering::Relaxed) {
                f.write_all(b"F=-800.0N\r\n").unwrap();
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };
    let back = |s: &serde_json::Value| {
        health(s, "F_spindle_N") == "ok" && s["channels"]["F_spindle_N"]["value"] == -800.0
    };
    let s = wait_for(status_port, 20, back);
    talking.store(false, Ordering::Relaxed);
    writer.join().unwrap();
    assert!(
        back(&s),
        "force source did not come back after the pty returned: {s}"
    );

    // The Modbus server goes down → temperatures Stale.
    drop(server);
    let t_stale = |s: &serde_json::Value| health(s, "T_spindle_C") == "stale";
    let s = wait_for(status_port, 10, t_stale);
    assert!(
        t_stale(&s),
        "T_spindle_C not stale after the server stopped: {s}"
    );

    // Clean stop on SIGTERM.
    process::stop_with_sigterm(&mut child);
    drop((socat_dro, socat_f));
}

/// Channels delivered by the configured sources (CANopen, Modbus, serial).
fn sourced_channels(cfg: &FieldConfig) -> BTreeSet<String> {
    let mut s = BTreeSet::new();
    if let Some(co) = &cfg.canopen {
        s.extend(co.encoder.iter().map(|e| e.channel.clone()));
        s.extend(co.analog.iter().map(|a| a.channel.clone()));
    }
    for m in cfg.modbus.iter().flat_map(|m| &m.source) {
        s.extend(m.channel.iter().map(|c| c.channel.clone()));
    }
    for r in cfg.serial.iter().flat_map(|r| &r.source) {
        s.extend(r.channel.iter().map(|c| c.name.clone()));
    }
    s
}

#[test]
fn every_shipped_field_config_loads_with_its_model_and_sources_what_the_model_needs() {
    let _turn = crate::turn::take(file!());
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/field");
    let mut checked = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        // Field configs have a [gateway]; the model files beside them do not.
        if path.extension().is_none_or(|e| e != "toml") || !text.contains("\n[gateway]") {
            continue;
        }
        let cfg = FieldConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let model_rel = &cfg.model.as_ref().expect("[model] path").path;
        let model_path = dir.join(model_rel);
        let model = MachineModel::from_toml_path(&model_path)
            .unwrap_or_else(|e| panic!("{}: model {}: {e}", path.display(), model_path.display()));
        let adapter = MachineModelAdapter::new(model);
        let sourced = sourced_channels(&cfg);
        for c in adapter.required_channels() {
            assert!(
                sourced.iter().any(|s| *c == **s),
                "{}: the model needs {c} but no source delivers it (sources: {sourced:?})",
                path.display()
            );
        }
        for a in &cfg.axes {
            assert!(
                sourced.contains(&a.position_channel),
                "{}: axis {} position {} is not delivered by any source",
                path.display(),
                a.name,
                a.position_channel
            );
        }
        checked += 1;
    }
    assert_eq!(checked, 3, "expected the three shipped field configs");
}
