//! A watchdog the controller can trust (issue 18 point 4), on the real `retrocomp run` binary against
//! `hil-sim serve`, whose PLC implements the heartbeat rule of docs/gateway.md (`[plc.watchdog]`):
//! the demo mill of `gateway_faults_hil` (CAN through a socketcand hub, the PLC on Modbus TCP with
//! the strobe/ack handshake), the gateway writing a heartbeat every 10 ms write period.
//!
//! 1. SIGKILL (box gone): the PLC trips after its timeout and ramps the correction to 0, never
//!    faster than its rate; a new gateway then starts from what the PLC holds.
//! 2. SIGSTOP (box frozen): the same; after SIGCONT the box re-reads the controller and continues
//!    from what the PLC now holds (the last-step guard: no step beyond the cap).
//! 3. SIGTERM (`on_stop = "ramp_out"`): the box ramps the correction out itself, within the cap per
//!    write, and exits 0; when the PLC then trips it already holds 0.
//!
//! The test only sequences the processes (waiting for events: the PLC's registers, hil-sim's printed
//! watchdog edges, the gateway's exit, each with a generous deadline); every assertion is on the
//! PLC's own record of what it applied (`plc_latches.csv`, stamped on the simulated clock).
//! No assertion is on wall time. The same sequence in virtual time, with exact instants (the trip
//! one timeout after the last heartbeat, the ramp scan by scan), is
//! `hil-sim/tests/sim/closed_loop_watchdog.rs`.

use crate::configs;
use crate::hil_sim;
use crate::run;

use std::net::SocketAddr;
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

use configs::{CAP_UM, LSB_UM};

const HEARTBEAT_REGISTER: u16 = 12;
/// The PLC's heartbeat timeout (50 write periods), s.
const TIMEOUT_S: f64 = 0.5;
/// The PLC's ramp-out rate, µm/s.
const RAMP_UM_PER_S: f64 = 20.0;
/// hil-sim's PLC scan (`sim_machine_toml`), s.
const SCAN_S: f64 = 0.004;
/// A correction the PLC must hold before each fault, so a missing ramp would show, µm.
const HOLDS_UM: f64 = 6.0;

fn sim_toml(hub_port: u16, pty: &Path, truth: &Path) -> String {
    configs::sim_machine_toml(5, truth)
        + &configs::sim_io_toml(hub_port, pty, None)
        + &format!(
            "\n[plc.watchdog]\nheartbeat_register = {HEARTBEAT_REGISTER}\ntimeout_s = {TIMEOUT_S}\nramp_um_per_s = {RAMP_UM_PER_S}\n"
        )
}

fn field_toml(hub_port: u16, plc: &str, pty: &Path) -> String {
    let text = configs::field_toml(hub_port, plc, pty);
    let (hold, ramp) = (
        "on_stop = \"hold\"\n",
        "on_stop = \"ramp_out\"\nstop_ramp_max_s = 10.0\n",
    );
    let map = "[sink.origin_shift.map]\n";
    assert!(text.contains(hold) && text.contains(map));
    text.replace(hold, ramp).replace(
        map,
        &format!(
            "{map}heartbeat_address = {HEARTBEAT_REGISTER}\nheartbeat_timeout_ms = {}\n",
            (TIMEOUT_S * 1e3) as u64
        ),
    )
}

/// Polls the PLC's shift registers (int32 hi-lo, x y z from 0) until one holds ≥ `um` in magnitude.
fn wait_plc_holds(rt: &tokio::runtime::Runtime, plc: SocketAddr, um: f64, what: &str) {
    use tokio_modbus::client::Reader;
    rt.block_on(async {
        let deadline = Instant::now() + Duration::from_secs(30);
        let mut ctx = tokio_modbus::client::tcp::connect(plc).await.unwrap();
        let mut last = Vec::new();
        while Instant::now() < deadline {
            if let Ok(Ok(w)) = ctx.read_holding_registers(0, 6).await {
                let v: Vec<f64> = w
                    .chunks(2)
                    .map(|p| f64::from((u32::from(p[0]) << 16 | u32::from(p[1])) as i32) * LSB_UM)
                    .collect();
                if v.iter().any(|x| x.abs() >= um) {
                    return;
                }
                last = v;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("{what}: the PLC never held {um} µm (last {last:?})");
    });
}

fn wait_exit(gw: &mut Child, within: Duration, log: &Path) -> std::process::ExitStatus {
    let t = Instant::now();
    while t.elapsed() < within {
        if let Some(st) = gw.try_wait().unwrap() {
            return st;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = gw.kill();
    panic!(
        "the gateway did not exit:\n{}",
        std::fs::read_to_string(log).unwrap_or_default()
    );
}

/// One row of plc_latches.csv.
#[derive(Debug, Clone)]
struct Event {
    t_s: f64,
    kind: String,
    um: [f64; 3],
}

fn parse_events(text: &str) -> Vec<Event> {
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("t_s,event,x_um,y_um,z_um"));
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 5, "{l}");
            let num = |i: usize| f[i].parse::<f64>().unwrap_or_else(|e| panic!("{l}: {e}"));
            Event {
                t_s: num(0),
                kind: f[1].to_string(),
                um: [num(2), num(3), num(4)],
            }
        })
        .collect()
}

fn max_abs(um: &[f64; 3]) -> f64 {
    um.iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

#[test]
fn the_plc_removes_the_correction_when_the_box_dies_or_freezes_and_sigterm_ramps_it_out() {
    let _turn = crate::turn::take(file!());
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    let dir = run::run_dir("gateway_watchdog_hil");
    let dir = dir.as_path();
    let out = dir.join("out");
    let (rt, hub) = run::loopback_hub();
    let truth = run::demo_truth_model();
    let sim_cfg = dir.join("sim.toml");
    let pty_link = dir.join("weighing-pty");
    std::fs::write(
        &sim_cfg,
        sim_toml(hub.local_addr().port(), &pty_link, &truth),
    )
    .unwrap();
    let mut sim = run::Sim::spawn(&hil_sim, &sim_cfg, &out);
    let [plc, pty] = <[String; 2]>::try_from(
        sim.wait_for(&["hil-sim: modbus tcp on ", "hil-sim: weighing lines on "]),
    )
    .unwrap();
    let plc_addr: SocketAddr = plc.parse().unwrap();
    let field = dir.join("field.toml");
    std::fs::write(
        &field,
        field_toml(hub.local_addr().port(), &plc, Path::new(&pty)),
    )
    .unwrap();
    let edge = |what: &str| format!("hil-sim: plc watchdog {what} at t = ");

    // 1. SIGKILL: the PLC trips and ramps to 0 by itself.
    let (mut gw, log_a) = run::start_gateway(dir, "gateway_a.log", &field, &truth);
    wait_plc_holds(&rt, plc_addr, HOLDS_UM, "before SIGKILL");
    sim.drain();
    run::signal(&gw, "-KILL");
    gw.wait().unwrap();
    sim.wait_for(&[&edge("trip")]);
    sim.wait_for(&[&edge("at_zero")]);

    // 2. SIGSTOP / SIGCONT on a new gateway (which starts from the PLC's 0).
    let (mut gw, log_b) = run::start_gateway(dir, "gateway_b.log", &field, &truth);
    wait_plc_holds(&rt, plc_addr, HOLDS_UM, "after the restart");
    sim.drain();
    run::signal(&gw, "-STOP");
    sim.wait_for(&[&edge("trip")]);
    sim.wait_for(&[&edge("at_zero")]);
    run::signal(&gw, "-CONT");
    sim.wait_for(&[&edge("rearm")]);
    wait_plc_holds(&rt, plc_addr, HOLDS_UM, "after SIGCONT");
    assert!(
        gw.try_wait().unwrap().is_none(),
        "the gateway died after SIGCONT:\n{}",
        std::fs::read_to_string(&log_b).unwrap_or_default()
    );

    // 3. SIGTERM: the box ramps out, exits 0; the PLC trips holding 0.
    sim.drain();
    run::signal(&gw, "-TERM");
    let st = wait_exit(&mut gw, Duration::from_secs(20), &log_b);
    let log_text = std::fs::read_to_string(&log_b).unwrap();
    assert!(st.success(), "exit {st} after SIGTERM:\n{log_text}");
    assert!(
        log_text.contains("ramped out: the controller holds 0"),
        "{log_text}"
    );
    let [trip] = <[String; 1]>::try_from(sim.wait_for(&[&edge("trip")])).unwrap();
    assert!(trip.ends_with("applied [0, 0, 0] µm"), "{trip}");

    // The program ends by itself (M30).
    let deadline = Instant::now() + Duration::from_secs(60);
    let st = loop {
        if let Some(st) = sim.child.try_wait().unwrap() {
            break st;
        }
        if Instant::now() > deadline {
            let _ = sim.child.kill();
            panic!("hil-sim did not finish:\n{}", sim.log_text());
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(st.success(), "hil-sim failed: {st}\n{}", sim.log_text());
    drop(hub);
    let _ = log_a;

    // ---- The PLC's own record of every value it applied.
    let events = parse_events(&std::fs::read_to_string(out.join("plc_latches.csv")).unwrap());
    let trips: Vec<usize> = (0..events.len())
        .filter(|&i| events[i].kind == "trip")
        .collect();
    assert!(
        trips.len() >= 3,
        "trips at {:?}",
        trips.iter().map(|&i| events[i].t_s).collect::<Vec<_>>()
    );
    let mut prev: Option<&Event> = None;
    let mut tripped = false;
    for e in &events {
        if let Some(p) = prev {
            for k in 0..3 {
                let step = (e.um[k] - p.um[k]).abs();
                match e.kind.as_str() {
                    // The box's writes: within the cap of what the PLC applied before (+1 LSB).
                    "latch" => assert!(
                        !tripped && step <= CAP_UM + LSB_UM + 1e-9,
                        "a box step {p:?} → {e:?}"
                    ),
                    // The watchdog: towards 0, never faster than its rate (+1 count, +1 scan).
                    "ramp" => {
                        assert!(tripped, "{e:?}");
                        assert!(
                            e.um[k].abs() <= p.um[k].abs() + 1e-9,
                            "away from 0: {p:?} → {e:?}"
                        );
                        let allowed = RAMP_UM_PER_S * (e.t_s - p.t_s + SCAN_S) + LSB_UM + 1e-9;
                        assert!(
                            step <= allowed,
                            "ramp faster than {RAMP_UM_PER_S} µm/s: {p:?} → {e:?}"
                        );
                    }
                    _ => assert_eq!(step, 0.0, "{p:?} → {e:?}"),
                }
            }
        }
        match e.kind.as_str() {
            "trip" => tripped = true,
            "rearm" => tripped = false,
            _ => {}
        }
        prev = Some(e);
    }
    // Kill and stop: each tripped while holding a correction and ramped it to 0 before the box came
    // back; the box then continued from there (it held ≥ HOLDS_UM again).
    let episodes: Vec<(f64, f64)> = trips
        .iter()
        .filter_map(|&i| {
            let held = max_abs(&events[i].um);
            let rest = &events[i + 1..];
            let end = rest
                .iter()
                .position(|e| e.kind == "rearm")
                .unwrap_or(rest.len());
            let zero = rest[..end].iter().any(|e| e.kind == "at_zero");
            let back = rest[end..]
                .iter()
                .take_while(|e| e.kind != "trip")
                .any(|e| max_abs(&e.um) >= HOLDS_UM - LSB_UM);
            (held >= HOLDS_UM - CAP_UM && zero && back).then_some((events[i].t_s, held))
        })
        .collect();
    assert!(
        episodes.len() >= 2,
        "expected the SIGKILL and SIGSTOP trips, each ramped to 0 and resumed from: {episodes:?}"
    );
    // SIGTERM: the last trip found the PLC at 0 already (the box ramped out), and it stayed there.
    let last = &events[*trips.last().unwrap()];
    assert_eq!(last.um, [0.0; 3], "{last:?}");
    assert!(
        events[*trips.last().unwrap()..]
            .iter()
            .all(|e| e.kind != "rearm" && e.kind != "latch")
    );
    // The box's ramp-out: from ≥ HOLDS_UM down to 0 in latches only (the cap asserted above).
    let before_last: Vec<&Event> = events[..*trips.last().unwrap()]
        .iter()
        .rev()
        .take_while(|e| e.kind == "latch")
        .collect();
    assert!(
        before_last
            .iter()
            .any(|e| max_abs(&e.um) >= HOLDS_UM - LSB_UM),
        "the box did not ramp out from the correction it held: {before_last:?}"
    );
}
