//! Closed loop over loopback with faults injected mid-run: the gateway runtime (`gateway::run`) with
//! samples from a feeder task (standing in for the bus sources) and origin-shift writes to a fake PLC
//! (Modbus TCP on 127.0.0.1). Faults: PLC killed and restarted with its registers reset, encoder
//! silent, temperature stuck then NaN, undecodable samples, and the gateway itself restarted.
//! Asserted on the PLC's own write log: never a value beyond the clamp, never a change beyond the
//! dosing cap relative to what the PLC held, resumes without a jump, recovers when sources return.
//! Every wait is for an event (a register value, a /status field) with a bound that is never a
//! measurement, so nothing here times the gateway; the timing of the same faults (edges at their
//! instants, hold and ramp, the reconnect backoff, the writes back to the target) is asserted
//! exactly in virtual time by hil-sim/tests/sim/closed_loop_faults.rs (docs/hil-sim.md, "Real-peer
//! timing → virtual time").

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use retrocomp_bus::{ChannelTable, Health, Sample};
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::run::run;
use retrocomp_gateway::sinks::origin_shift::RegisterMap;
use retrocomp_gateway::{AxisErrors, ErrorModel, MachineState};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, oneshot};

use crate::plc;
use plc::{Plc, serve};

struct ThermalModel;
impl ErrorModel for ThermalModel {
    fn required_channels(&self) -> Vec<Arc<str>> {
        vec!["T_spindle_C".into()]
    }
    fn axis_errors(
        &mut self,
        s: &MachineState,
        out: &mut AxisErrors,
    ) -> Result<(), retrocomp_gateway::engine::ModelError> {
        let e = 2.0 * (s.input(0).expect("inputs usable when the model runs") - 20.0);
        out.push(retrocomp_model::Axis::X, "thermal".into(), e);
        Ok(())
    }
}

const CLAMP_UM: f64 = 30.0;
const CAP_UM: f64 = 0.5;

fn config(plc: std::net::SocketAddr) -> FieldConfig {
    let text = format!(
        r#"
[gateway]
name = "loop"
cycle_ms = 5
# The restart below must continue from a non-zero value the PLC holds: no ramp-out on stop.
on_stop = "hold"
thermal_period_s = 0.05
status_listen = "127.0.0.1:0"
[safety]
max_correction_um = {CLAMP_UM}
max_change_um_per_cycle = {CAP_UM}
ramp_um_per_s = 60.0
stale_hold_s = 0.15
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
[[channel]]
name = "x_mm"
min = -1.0
max = 500.0
stale_after_s = 0.05
[[channel]]
name = "T_spindle_C"
min = 5.0
max = 70.0
stale_after_s = 0.1
stuck_after_s = 0.15
[[channel]]
name = "T_bed_C"
min = 5.0
max = 70.0
stale_after_s = 0.1
[[recovery]]
target = "T_spindle_C"
neighbours = ["T_bed_C"]
coefficients = [0.0, 1.0]
fit_rms = 0.1
[sink.origin_shift]
transport = {{ kind = "tcp", address = "{plc}" }}
request_timeout_ms = 100
reconnect_min_ms = 20
reconnect_max_ms = 100
write_period_ms = 10
[sink.origin_shift.map]
[[sink.origin_shift.map.axis]]
axis = "x"
address = 100
kind = "int32"
lsb_um = 0.1
sign = 1
[sink.origin_shift.map.handshake]
strobe_address = 110
ack_address = 111
timeout_ms = 100
poll_ms = 2
"#
    );
    FieldConfig::parse(&text, std::path::Path::new("loop.toml")).unwrap()
}

// Feeder modes.
const NORMAL: u8 = 0;
const ENCODER_SILENT: u8 = 1;
const TEMP_STUCK: u8 = 2;
const TEMP_NAN: u8 = 3;
const GARBAGE: u8 = 4;
const HOT: u8 = 5; // 45 °C: the model asks for −50 µm, beyond the 30 µm clamp

fn feeder(
    tx: mpsc::Sender<Sample>,
    mode: Arc<AtomicU8>,
    t0: std::time::Instant,
    channels: &ChannelTable,
) -> tokio::task::JoinHandle<()> {
    // The ids the gateway's engine gives these names (the field file's table).
    let id = |name: &str| channels.get(name).expect("a channel of the field file");
    let (t_bed, t_spindle, x_mm) = (id("T_bed_C"), id("T_spindle_C"), id("x_mm"));
    tokio::spawn(async move {
        let mut k = 0u64;
        loop {
            tokio::time::sleep(Duration::from_millis(2)).await;
            k += 1;
            let t = t0.elapsed().as_secs_f64();
            let m = mode.load(Ordering::Relaxed);
            let x = 100.0 + 50.0 * (t * 0.5).sin();
            let temp = match m {
                TEMP_STUCK => 30.0,
                HOT => 45.0 + 1e-4 * (k % 7) as f64,
                _ => 30.0 + 1e-4 * (k % 7) as f64, // ADC noise: never bit-identical for long
            };
            let mut batch = vec![
                Sample {
                    channel: t_bed,
                    t_s: t,
                    value: 30.0 + 1e-4 * (k % 5) as f64,
                    health: Health::Ok,
                },
                Sample {
                    channel: t_spindle,
                    t_s: t,
                    value: if m == TEMP_NAN { f64::NAN } else { temp },
                    health: Health::Ok,
                },
            ];
            if m != ENCODER_SILENT {
                batch.push(Sample {
                    channel: x_mm,
                    t_s: t,
                    value: x,
                    health: Health::Ok,
                });
            }
            if m == GARBAGE {
                batch.push(Sample {
                    channel: x_mm,
                    t_s: t,
                    value: 0.0,
                    health: Health::DecodeError,
                });
            }
            for s in batch {
                if tx.send(s).await.is_err() {
                    return;
                }
            }
        }
    })
}

fn reg_value(map: &RegisterMap, words: &[u16]) -> f64 {
    map.decode("x", words).unwrap()
}

/// How long a wait for a condition may take before the test gives up: a generous bound for a
/// loaded 2-core machine, never a measurement (every wait returns as soon as its condition holds,
/// and the assertion after it is on the value, not on how long it took).
const GENEROUS: Duration = Duration::from_secs(30);

async fn wait_until(
    plc: &Arc<Mutex<Plc>>,
    map: &RegisterMap,
    pred: impl Fn(f64) -> bool,
    max: Duration,
) -> f64 {
    let t0 = std::time::Instant::now();
    loop {
        let v = {
            let p = plc.lock().unwrap();
            reg_value(
                map,
                &[
                    *p.regs.get(&100).unwrap_or(&0),
                    *p.regs.get(&101).unwrap_or(&0),
                ],
            )
        };
        if pred(v) || t0.elapsed() > max {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// GETs /status until `pred` holds on its body (at most [`GENEROUS`]: a bound, not a measurement),
/// and returns the last body for the caller's assertion.
async fn poll_status(addr: &str, pred: impl Fn(&str) -> bool) -> String {
    let t0 = std::time::Instant::now();
    loop {
        let (_, body) =
            retrocomp_gateway::northbound::http::get(addr, "/status", Duration::from_secs(2))
                .await
                .unwrap();
        if pred(&body) || t0.elapsed() > GENEROUS {
            return body;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gateway_survives_faults_and_never_jumps() {
    let _turn = crate::turn::take(file!());
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let plc_addr = listener.local_addr().unwrap();
    let plc = Arc::new(Mutex::new(Plc {
        auto_ack: true,
        ..Default::default()
    }));
    let mut plc_task = tokio::spawn(serve(listener, plc.clone()));
    let cfg = config(plc_addr);
    let map = cfg.sink.origin_shift.as_ref().unwrap().map.clone();
    let mode = Arc::new(AtomicU8::new(NORMAL));

    // --- gateway run 1 ---
    let (tx, rx) = mpsc::channel(4096);
    let epoch = std::time::Instant::now();
    let feed = feeder(tx, mode.clone(), epoch, &cfg.channel_table());
    let (stop_tx, stop_rx) = oneshot::channel::<()>();
    let (addr_tx, addr_rx) = oneshot::channel();
    let gw = tokio::spawn(run(
        cfg.clone(),
        Box::new(ThermalModel),
        rx,
        epoch,
        async {
            let _ = stop_rx.await;
        },
        Some(addr_tx),
    ));
    let status_addr = addr_rx.await.unwrap().to_string();

    // Normal: 30 °C → error 20 µm → correction −20 µm, reached by ramping.
    let v = wait_until(&plc, &map, |v| (v + 20.0).abs() < 0.11, GENEROUS).await;
    assert!((v + 20.0).abs() < 0.11, "did not reach −20 µm: {v}");

    // Status endpoint, read-only, on loopback.
    let (code, body) =
        retrocomp_gateway::northbound::http::get(&status_addr, "/status", Duration::from_secs(2))
            .await
            .unwrap();
    assert_eq!(code, 200);
    let js: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert!(
        (js["axes"][0]["terms_um"]["thermal"].as_f64().unwrap() + 20.0).abs() < 0.01,
        "{body}"
    );
    let (code, metrics) =
        retrocomp_gateway::northbound::http::get(&status_addr, "/metrics", Duration::from_secs(2))
            .await
            .unwrap();
    assert_eq!(code, 200);
    assert!(
        metrics.contains("retrocomp_correction_applied_meters{axis=\"x\"}"),
        "{metrics}"
    );

    // Too hot: the model asks for −50 µm; the clamp holds −30.
    mode.store(HOT, Ordering::Relaxed);
    let v = wait_until(&plc, &map, |v| (v + CLAMP_UM).abs() < 0.11, GENEROUS).await;
    assert!((v + CLAMP_UM).abs() < 0.11, "clamped at −30: {v}");
    mode.store(NORMAL, Ordering::Relaxed);
    wait_until(&plc, &map, |v| (v + 20.0).abs() < 0.11, GENEROUS).await;

    // PLC killed, then restarted with its registers reset to 0 (controller power-cycled).
    plc_task.abort();
    let _ = plc_task.await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    plc.lock().unwrap().regs.clear();
    let listener = TcpListener::bind(plc_addr).await.unwrap();
    plc_task = tokio::spawn(serve(listener, plc.clone()));
    let v = wait_until(&plc, &map, |v| (v + 20.0).abs() < 0.11, GENEROUS).await;
    assert!((v + 20.0).abs() < 0.11, "recovered after PLC restart: {v}");

    // Encoder silent: hold, then ramp to zero; then back.
    mode.store(ENCODER_SILENT, Ordering::Relaxed);
    let v = wait_until(&plc, &map, |v| v.abs() < 0.11, GENEROUS).await;
    assert!(
        v.abs() < 0.11,
        "ramped to zero while the encoder is silent: {v}"
    );
    mode.store(NORMAL, Ordering::Relaxed);
    wait_until(&plc, &map, |v| (v + 20.0).abs() < 0.11, GENEROUS).await;

    // Temperature stuck, then NaN: replaced by the neighbour estimate (T_bed_C), output unchanged.
    // Each phase waits for the gateway to report it (event-driven), not for a fixed time.
    let spindle = |body: &str, fault: &str| {
        let js: serde_json::Value = serde_json::from_str(body).unwrap();
        let c = &js["channels"]["T_spindle_C"];
        c["substituted"] == serde_json::Value::Bool(true)
            && c["faults"]
                .as_array()
                .is_some_and(|f| f.iter().any(|k| k == fault))
    };
    mode.store(TEMP_STUCK, Ordering::Relaxed);
    let body = poll_status(&status_addr, |b| spindle(b, "stuck")).await;
    assert!(spindle(&body, "stuck"), "stuck and substituted: {body}");
    let v = wait_until(&plc, &map, |_| true, Duration::ZERO).await;
    assert!(
        (v + 20.0).abs() < 0.11,
        "substitution (stuck) keeps −20: {v}"
    );
    mode.store(TEMP_NAN, Ordering::Relaxed);
    let body = poll_status(&status_addr, |b| spindle(b, "not_finite")).await;
    assert!(spindle(&body, "not_finite"), "NaN and substituted: {body}");
    let v = wait_until(&plc, &map, |_| true, Duration::ZERO).await;
    assert!((v + 20.0).abs() < 0.11, "substitution (NaN) keeps −20: {v}");

    // Garbage on the position line is rejected without disturbing the output: the status shows the
    // decode fault on x_mm while the PLC still holds −20 µm, and the fault clears once it stops.
    mode.store(GARBAGE, Ordering::Relaxed);
    let x_decode_fault = |body: &str| {
        let js: serde_json::Value = serde_json::from_str(body).unwrap();
        js["channels"]["x_mm"]["faults"]
            .as_array()
            .is_some_and(|f| f.iter().any(|k| k == "decode"))
    };
    let body = poll_status(&status_addr, |b| x_decode_fault(b)).await;
    assert!(
        x_decode_fault(&body),
        "garbage never seen as a decode fault: {body}"
    );
    let v = wait_until(&plc, &map, |_| true, Duration::ZERO).await;
    assert!((v + 20.0).abs() < 0.11, "garbage disturbed the output: {v}");
    mode.store(NORMAL, Ordering::Relaxed);
    let body = poll_status(&status_addr, |b| !x_decode_fault(b)).await;
    assert!(!x_decode_fault(&body), "decode fault never cleared: {body}");

    // --- gateway restarted: continues from what the PLC holds ---
    let _ = stop_tx.send(());
    let summary = gw.await.unwrap().unwrap();
    assert!(
        summary.cycles > 100 && summary.writes_ok > 50,
        "{summary:?}"
    );
    feed.abort();
    let held = wait_until(&plc, &map, |_| true, Duration::ZERO).await;
    let n_before = plc.lock().unwrap().history.len();
    let (tx, rx) = mpsc::channel(4096);
    let epoch = std::time::Instant::now();
    let feed = feeder(tx, mode.clone(), epoch, &cfg.channel_table());
    let (stop_tx, stop_rx) = oneshot::channel::<()>();
    let gw = tokio::spawn(run(
        cfg.clone(),
        Box::new(ThermalModel),
        rx,
        epoch,
        async {
            let _ = stop_rx.await;
        },
        None,
    ));
    // Until the restarted gateway's first value write reached the PLC (event-driven).
    let t0 = std::time::Instant::now();
    while !plc.lock().unwrap().history[n_before..]
        .iter()
        .any(|(a, _, _)| *a == 100)
        && t0.elapsed() < GENEROUS
    {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let _ = stop_tx.send(());
    gw.await.unwrap().unwrap();
    feed.abort();
    plc_task.abort();

    // --- invariants on everything the PLC received ---
    let p = plc.lock().unwrap();
    let first_after_restart = p.history[n_before..]
        .iter()
        .find(|(a, _, _)| *a == 100)
        .map(|(_, _, w)| reg_value(&map, w));
    assert!(
        first_after_restart.is_some_and(|v| (v - held).abs() <= CAP_UM + 0.1),
        "gateway restart must continue from {held}, first write {first_after_restart:?}"
    );
    let mut n = 0;
    for (addr, before, after) in &p.history {
        assert!(
            map.check_write(*addr, after.len()).is_ok(),
            "write outside the allow-list at {addr}"
        );
        if *addr != 100 {
            continue;
        }
        n += 1;
        let (b, a) = (reg_value(&map, before), reg_value(&map, after));
        assert!(a.abs() <= CLAMP_UM + 1e-9, "wrote {a} beyond the clamp");
        assert!(
            (a - b).abs() <= CAP_UM + 0.1 + 1e-9,
            "jump {b} → {a} beyond the cap"
        );
    }
    assert!(n > 100, "only {n} writes");
}
