//! The real `retrocomp run` binary over real loopback transports: CANopen encoder TPDOs through the
//! socketcand hub (crates/bus/src), the Studer S-36 model (seed 004), origin-shift writes to a fake PLC over
//! Modbus TCP, `retrocomp status --json` against its HTTP endpoint, and a clean stop on SIGTERM.

use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use retrocomp_bus::can::{CanBus, Hub, SocketcandBus};
use tokio::net::TcpListener;

use crate::plc;
use crate::process;
use crate::studer_can;
use plc::{Plc, serve};
use studer_can::encoder;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_binary_end_to_end_over_loopback() {
    let _turn = crate::turn::take(file!());
    let hub = Hub::start_loopback().await.unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let plc_addr = listener.local_addr().unwrap();
    let plc = Arc::new(Mutex::new(Plc::default()));
    let plc_task = tokio::spawn(serve(listener, plc.clone()));
    let status_port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = dir.path().join("field.toml");
    std::fs::write(
        &cfg_path,
        format!(
            r#"
[gateway]
name = "studer-loop"
cycle_ms = 5
status_listen = "127.0.0.1:{status_port}"
[safety]
max_correction_um = 60.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 200.0
stale_hold_s = 0.5
{machine}[sink.origin_shift]
transport = {{ kind = "tcp", address = "{plc_addr}" }}
write_period_ms = 10
[sink.origin_shift.map]
[[sink.origin_shift.map.axis]]
axis = "z"
address = 0
kind = "int32"
lsb_um = 0.1
sign = 1
[[sink.origin_shift.map.axis]]
axis = "x"
address = 2
kind = "int32"
lsb_um = 0.1
sign = 1
"#,
            machine = studer_can::machine_on_can(hub.local_addr().port())
        ),
    )
    .unwrap();

    let mut child = process::start_run(&[], &cfg_path);

    // The "machine": encoders 1 (z) and 2 (x) send their TPDO1 every 2 ms; z drives 400 → 510 mm.
    let mut can = SocketcandBus::connect(hub.local_addr(), "can0")
        .await
        .unwrap();
    let (ez, ex) = (encoder("z_mm", 1), encoder("x_mm", 2));
    let t0 = std::time::Instant::now();
    let mut status = serde_json::Value::Null;
    while t0.elapsed() < Duration::from_secs(20) {
        let z = (400.0 + 200.0 * t0.elapsed().as_secs_f64()).min(510.0);
        can.send(&ez.encode_position(z).unwrap()).await.unwrap();
        can.send(&ex.encode_position(50.0).unwrap()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(2)).await;
        if z >= 510.0 && t0.elapsed().as_millis() % 100 < 3 {
            let out = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
                .args([
                    "status",
                    "--json",
                    "--addr",
                    &format!("127.0.0.1:{status_port}"),
                ])
                .output()
                .unwrap();
            if out.status.success() {
                status = serde_json::from_slice(&out.stdout).unwrap();
                let z_axis = &status["axes"][0];
                if z_axis["mode"] == "tracking"
                    && (z_axis["position_mm"].as_f64().unwrap_or(0.0) - 510.0).abs() < 1e-6
                {
                    break;
                }
            }
        }
    }
    let z_axis = &status["axes"][0];
    assert_eq!(z_axis["axis"], "z", "status: {status}");
    assert_eq!(z_axis["mode"], "tracking", "status: {status}");
    // Table 6.1: EZZ forward at 510 mm = −0.0096 mm → correction +9.6 µm.
    let ezz = z_axis["terms_um"]
        .as_object()
        .unwrap()
        .iter()
        .find(|(k, _)| k.contains("EZZ"))
        .map(|(_, v)| v.as_f64().unwrap());
    assert!(
        ezz.is_some_and(|v| (v - 9.6).abs() < 1e-6),
        "EZZ term: {status}"
    );
    let applied = z_axis["applied_um"].as_f64().unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let words = {
        let p = plc.lock().unwrap();
        [*p.regs.get(&0).unwrap_or(&0), *p.regs.get(&1).unwrap_or(&0)]
    };
    let held_um = f64::from((u32::from(words[0]) << 16 | u32::from(words[1])) as i32) * 0.1;
    assert!(
        (held_um - applied).abs() <= 0.1,
        "PLC holds {held_um} µm, gateway applied {applied} µm"
    );

    // Clean stop on SIGTERM.
    let err = process::stop_with_sigterm(&mut child);
    assert!(err.contains("stopped after"), "{err}");
    plc_task.abort();
}
