//! Closed loop against hil-sim with faults injected mid-run (issue 5 item 7). The real `hil-sim serve`
//! (real time, hidden geometry + thermal + cutting-force physics of the demo mill) and the real
//! `retrocomp run` binary (a child process, so "gateway restarted" is a real SIGKILL and SIGTERM),
//! connected over loopback only: CAN through a socketcand hub (CiA 406 encoders, CiA 404
//! temperatures), Modbus TCP into the PLC's origin-shift window, the cutting force as weighing lines on
//! a pty. hil-sim scripts the faults from its config (simulated seconds ≈ wall seconds):
//!
//! | window (s)  | fault                                                                   |
//! |-------------|-------------------------------------------------------------------------|
//! | 5.0–7.0     | `modbus_down`: listener and live connections gone, back on the same port |
//! | 9.0–10.5    | `can_node_silent` node 1: the X encoder sends nothing                    |
//! | 12.0–14.0   | `T_spindle_C` stuck, then 14.0–15.5 NaN (0x7FFF on CAN)                  |
//! | 17.5–20.0   | `serial_garbage`: junk bytes, broken lines, 90 kN readings on the pty    |
//! | 22.0        | the gateway is SIGKILLed and restarted at once                           |
//! | 25.5        | the gateway is stopped with SIGTERM and restarted                        |
//!
//! This is the real-peer smoke test of the shells and transports (CAN over socketcand, Modbus TCP,
//! the weighing pty, process kill/stop/restart). Asserted on hil-sim's own log of every client write
//! (`plc_writes.csv`), its recording and the gateway's logs: hil-sim injected every fault; the
//! gateway process survives every fault; no register value beyond the clamp (Y's per-axis clamp of
//! 5 µm binds); no change between consecutive register values beyond the dosing cap (+1 LSB of
//! rounding); nothing written while the PLC is down, writes resume; each new connection continues
//! from what the PLC held; the correction is within `TOL_UM` of the ideal one (−(uncompensated
//! error), clamped, from the simulator's truth) before the faults and at the end, and comes back
//! within it between faults; the encoder silence shows; while the spindle sensor is NaN its
//! neighbour's estimate keeps the thermal term; the gateway logs each fault once when it starts and
//! once when it clears, and every fault clears.
//!
//! The timing (fault edges at their instants, hold and ramp times, how many writes back to the
//! target, "back within the tolerance N s after the fault") is asserted exactly in virtual time by
//! hil-sim/tests/sim/closed_loop_faults.rs; the mapping is in docs/hil-sim.md ("Real-peer timing →
//! virtual time"). The windows here only say between which faults something must happen.

use crate::configs;
use crate::hil_sim;
use crate::observe;
use crate::run;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

use configs::*;
use observe::*;

fn assert_alive(gw: &mut Child, log: &Path, when: &str) {
    if let Some(st) = gw.try_wait().unwrap() {
        panic!(
            "the gateway died {when} ({st}):\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
    }
}

/// The closest the correction came to the ideal one in `from_s..to_s` (worst axis at each row), µm.
fn min_dev(devs: &[(f64, [f64; 3])], from_s: f64, to_s: f64) -> f64 {
    devs.iter()
        .filter(|(t, _)| *t >= from_s && *t < to_s)
        .map(|(_, d)| d.iter().fold(0.0f64, |m, v| m.max(v.abs())))
        .fold(f64::INFINITY, f64::min)
}

fn sleep_until(t0: Instant, at_s: f64) {
    let due = t0 + Duration::from_secs_f64(at_s);
    if let Some(d) = due.checked_duration_since(Instant::now()) {
        std::thread::sleep(d);
    }
}

#[test]
fn gateway_rides_through_transport_and_sensor_faults_against_hil_sim() {
    let _turn = crate::turn::take(file!());
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    // Kept in the target dir after the run for a post-mortem (configs, gateway logs, hil-sim output).
    let dir = run::run_dir("gateway_faults_hil");
    let dir = dir.as_path();
    let out = dir.join("out");
    // `_rt` (not `_`): the runtime must outlive the hub it runs.
    let (_rt, hub) = run::loopback_hub();
    let truth = run::demo_truth_model();
    let sim_cfg = dir.join("sim.toml");
    std::fs::write(
        &sim_cfg,
        sim_toml(hub.local_addr().port(), &dir.join("weighing-pty"), &truth),
    )
    .unwrap();
    let mut sim = run::Sim::spawn(&hil_sim, &sim_cfg, &out);
    let [plc, pty] = <[String; 2]>::try_from(
        sim.wait_for(&["hil-sim: modbus tcp on ", "hil-sim: weighing lines on "]),
    )
    .unwrap();
    // The simulation clock started a few ms before hil-sim printed its addresses.
    let t0 = Instant::now();
    let field = dir.join("field.toml");
    std::fs::write(
        &field,
        field_toml(hub.local_addr().port(), &plc, Path::new(&pty)),
    )
    .unwrap();

    let (mut gw, log1) = run::start_gateway(dir, "gateway1.log", &field, &truth);
    sleep_until(t0, KILL_AT_S);
    assert_alive(&mut gw, &log1, "during the faults");
    run::signal(&gw, "-KILL");
    gw.wait().unwrap();
    let (mut gw, log2) = run::start_gateway(dir, "gateway2.log", &field, &truth);
    sleep_until(t0, TERM_AT_S);
    assert_alive(&mut gw, &log2, "after the SIGKILL restart");
    run::stop_gateway(&mut gw, &log2);
    let (mut gw, log3) = run::start_gateway(dir, "gateway3.log", &field, &truth);

    // The program ends by itself (M30) after ≈ 31 s.
    let deadline = Instant::now() + Duration::from_secs(40);
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
    let sim_wall_s = t0.elapsed().as_secs_f64();
    assert_alive(&mut gw, &log3, "at the end of the program");
    run::stop_gateway(&mut gw, &log3);
    std::thread::sleep(Duration::from_millis(100));
    let sim_log = sim.log_text();
    assert!(st.success(), "hil-sim failed: {st}\n{sim_log}");
    drop(hub);

    // hil-sim really injected every transport fault, each start and clear once.
    for what in ["ModbusDown", "CanNodeSilent (node 1)", "SerialGarbage"] {
        for edge in ["started", "cleared"] {
            let n = sim_log
                .matches(&format!("hil-sim: fault {what} {edge} at"))
                .count();
            assert_eq!(n, 1, "{what} {edge}:\n{sim_log}");
        }
    }

    // Where the restarts fall on the simulation clock: hil-sim printed the end of the garbage window
    // at t = GARBAGE.1 (sim); the wall time we read it gives the sim clock's lag.
    let cleared_at = sim.printed_at("hil-sim: fault SerialGarbage cleared", t0);
    let lag_s = cleared_at - GARBAGE.1;
    // Only a bound that keeps the restarts' windows below meaningful: how far a loaded host lets
    // the simulation or this reader fall behind is not the gateway's business.
    assert!(
        (-0.5..5.0).contains(&lag_s),
        "the simulation is {lag_s:.2} s off real time"
    );

    let writes = check_writes(&out, lag_s);
    let recording = check_recording(&out, &writes);
    check_fault_logs(&log1, &log2, &log3);
    eprintln!(
        "faults against hil-sim: {} writes, {recording}; sim wall {sim_wall_s:.1} s",
        writes.len()
    );
}

/// The PLC's write log: clamp, dosing cap, nothing while the PLC is down, each new connection
/// continuing from what the PLC held.
fn check_writes(out: &Path, lag_s: f64) -> Vec<Write> {
    // ---- The PLC's write log: clamp, dosing cap, restarts.
    let writes = parse_writes(&std::fs::read_to_string(out.join("plc_writes.csv")).unwrap());
    assert!(writes.len() > 1000, "only {} writes", writes.len());
    let (max_abs, _) = assert_clamp_and_cap(&writes);
    assert_eq!(
        max_abs[1], CLAMP_Y_UM,
        "Y's clamp should bind in this run: {max_abs:?}"
    );
    assert!(
        max_abs[0] > 10.0 && max_abs[2] > 10.0,
        "corrections too small to test: {max_abs:?}"
    );
    // Modbus down: nothing reaches the PLC, then writes resume.
    let between = |a: f64, b: f64| writes.iter().filter(move |w| w.t_s >= a && w.t_s < b);
    assert_eq!(
        between(MODBUS_DOWN.0 + 0.05, MODBUS_DOWN.1).count(),
        0,
        "writes while the server was down"
    );
    // Resumed before the next fault (when exactly, and in how many writes back to the target, is
    // asserted in virtual time by `transport_down_and_back_resumes_from_what_the_plc_holds_…`).
    assert!(between(MODBUS_DOWN.1, CAN_SILENT.0).count() > 0);
    // Every new connection (the reconnect after `modbus_down`, each restarted gateway) continues
    // from what the PLC held, which is far from zero then, so a restart from zero would show.
    let changes: Vec<(&Write, &Write)> = writes
        .windows(2)
        .filter(|p| p[0].port != p[1].port)
        .map(|p| (&p[0], &p[1]))
        .collect();
    // Each new connection is looked for between its cause and the next scheduled event, not in a
    // window around the cause: how soon it comes depends on how the host schedules the processes.
    let reconnects = [
        ("after modbus_down", MODBUS_DOWN.1 - 0.5, CAN_SILENT.0),
        ("after SIGKILL", KILL_AT_S - lag_s - 0.5, TERM_AT_S - lag_s),
        ("after SIGTERM", TERM_AT_S - lag_s - 0.5, f64::INFINITY),
    ];
    let in_window = |t_s: f64| reconnects.iter().any(|(_, a, b)| t_s >= *a && t_s < *b);
    for (what, a, b) in reconnects {
        assert!(
            changes.iter().any(|(_, w)| w.t_s >= a && w.t_s < b),
            "no new connection {what} (between {a:.1} and {b:.1} s): {changes:?}"
        );
    }
    for (held, first) in &changes {
        if in_window(first.t_s) {
            let held_max = held.um.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(held_max > 3.0, "the PLC held only {:?}", held.um);
        }
        for k in 0..3 {
            assert!(
                (first.um[k] - held.um[k]).abs() <= CAP_UM + LSB_UM + 1e-9,
                "jump on a new connection: {held:?} → {first:?}"
            );
        }
    }
    writes
}

/// The recording: the correction against the ideal one around the faults; a one-line summary.
fn check_recording(out: &Path, writes: &[Write]) -> String {
    // ---- The recording: recovery after each fault, substitution during the sensor fault.
    let recording = std::fs::read_to_string(out.join("recording.csv")).unwrap();
    let devs = deviations(&recording);
    // Written shifts are applied. How many of them a 10 ms recording row catches depends on how the
    // host schedules hil-sim and the gateway, so this real-socket run only checks that the latched
    // shift follows the writes at all. Exactly one latch per strobe flip, every write applied, and
    // "the applied shift never moves more than one cap between two servo steps" are asserted
    // exactly in virtual time by hil-sim/tests/sim/closed_loop_faults.rs (the capped-write counts back to
    // the target, `assert_no_jump` on every 1 ms step); the write log's clamp and cap per write are
    // checked above, independent of timing.
    let share = applied_share(writes, &recording);
    assert!(share > 0.0, "none of the written shifts was ever applied");
    let all = [0, 1, 2];
    // The correction is right before any fault, and right again at the end, after every fault and
    // both restarts.
    let mut report = Vec::new();
    for (a, b) in [(2.5, MODBUS_DOWN.0), (TERM_AT_S + 2.5, 30.0)] {
        let d = max_dev(&devs, a, b, &all);
        report.push(format!("{a:.1}–{b:.1} s: {d:.2} µm"));
        assert!(
            d <= TOL_UM,
            "not within {TOL_UM} µm in {a}..{b} s: {d:.2} µm off the ideal"
        );
    }
    // Between the faults it comes back within the tolerance before the next one. How soon, and
    // that it stays, is asserted exactly in virtual time (hil-sim/tests/sim/closed_loop_faults.rs:
    // the capped writes back to the target after `modbus_down` and the silent node, the clean run
    // rejoined after the stuck/NaN sensor and the garbage, the unbroken run met after a restart).
    let recovered = [
        ("modbus_down", MODBUS_DOWN.1, CAN_SILENT.0),
        ("can_node_silent", CAN_SILENT.1, T_STUCK.0),
        ("stuck/NaN", T_NAN.1, GARBAGE.0),
        ("serial_garbage", GARBAGE.1, KILL_AT_S),
        ("SIGKILL", KILL_AT_S, TERM_AT_S),
    ];
    for (what, a, b) in recovered {
        let d = min_dev(&devs, a, b);
        report.push(format!("after {what}: {d:.2} µm"));
        assert!(
            d <= TOL_UM,
            "not back within {TOL_UM} µm after {what} ({a}..{b} s): at best {d:.2} µm off"
        );
    }
    // The X encoder silent: every axis holds, then ramps out (the model needs all positions). The
    // hold time and the ramp are asserted exactly by `a_silent_encoder_node_holds_for_exactly_…`.
    let during_silence = max_dev(&devs, CAN_SILENT.0, CAN_SILENT.1 + SETTLE_S, &all);
    assert!(
        during_silence > 5.0,
        "encoder silence had no effect: {during_silence:.2} µm"
    );
    // Spindle sensor NaN (0x7FFF on CAN): the neighbour keeps Z's thermal term. The stuck phase
    // before it (judged after 1 s) is asserted exactly by `a_stuck_then_nan_spindle_sensor_…`.
    let substituted = max_dev(&devs, T_NAN.0 + 0.2, T_NAN.1, &[2]);
    assert!(
        substituted <= TOL_UM,
        "Z lost its thermal term: {substituted:.2} µm"
    );
    let (max_abs, max_step) = assert_clamp_and_cap(writes);
    format!(
        "max |x,y,z| {max_abs:?} µm, max step {max_step} µm, applied share {share:.2}, \
         encoder-silence deviation {during_silence:.1} µm, substituted Z within {substituted:.2} µm, \
         {}",
        report.join(", ")
    )
}

/// The three gateways' fault logs: each fault once at start and once at clear, every fault cleared,
/// each restart continuing from what the controller held.
fn check_fault_logs(log1: &Path, log2: &Path, log3: &Path) {
    // ---- The gateway's fault log (gateway clock ≈ simulation clock; startup faults before 2 s).
    // Each episode is looked for between the fault before it and the one after it: the instants of
    // the edges are asserted exactly in virtual time (`one_episode` in closed_loop_faults.rs).
    let log1 = std::fs::read_to_string(log1).unwrap();
    let ev = fault_events(&log1);
    let starts = episodes(&ev);
    // Episodes of (source, kind) starting in from..=to (s on the gateway clock).
    let count = |src: &str, kind: &str, from: f64, to: f64| {
        starts
            .get(&(src.to_string(), kind.to_string()))
            .map_or(0, |v| v.iter().filter(|t| **t >= from && **t <= to).count())
    };
    assert_eq!(
        count(
            "sink.origin_shift",
            "disconnected",
            MODBUS_DOWN.0 - 1.0,
            CAN_SILENT.0
        ),
        1,
        "{starts:?}\n{log1}"
    );
    assert_eq!(
        count("x_mm", "stale", CAN_SILENT.0 - 1.0, T_STUCK.0),
        1,
        "{starts:?}"
    );
    for quiet in ["y_mm", "z_mm"] {
        assert_eq!(
            count(quiet, "stale", CAN_SILENT.0 - 1.0, T_STUCK.0),
            0,
            "{starts:?}"
        );
    }
    assert_eq!(
        count("T_spindle_C", "stuck", T_STUCK.0 - 1.0, T_NAN.1),
        1,
        "{starts:?}"
    );
    assert_eq!(
        count("T_spindle_C", "out_of_range", T_NAN.0 - 1.0, GARBAGE.0),
        1,
        "NaN → 0x7FFF: {starts:?}"
    );
    for quiet in ["T_spindle2_C", "T_xscrew_C"] {
        // Only the start-up Stale (before the first CiA 404 PDO) is allowed.
        assert!(
            starts
                .iter()
                .all(|((s, _), t)| s != quiet || t.iter().all(|t| *t < 2.0)),
            "{quiet} had a fault: {starts:?}"
        );
    }
    assert!(
        count("F_cut_N", "out_of_range", GARBAGE.0 - 1.0, KILL_AT_S) >= 1,
        "the 90 kN readings were not rejected: {starts:?}"
    );
    // Every fault that started also cleared (the run ended healthy), in every process.
    for (i, log) in [
        log1.clone(),
        std::fs::read_to_string(log2).unwrap(),
        std::fs::read_to_string(log3).unwrap(),
    ]
    .iter()
    .enumerate()
    {
        let ev = fault_events(log);
        let mut open: BTreeMap<(String, String), bool> = BTreeMap::new();
        for (s, k, started, _) in &ev {
            open.insert((s.clone(), k.clone()), *started);
        }
        let _ = episodes(&ev);
        if i > 0 {
            assert!(
                log.contains("controller holds these corrections; continuing from them"),
                "gateway {}: {log}",
                i + 1
            );
        }
        // gateway 3 is still running when hil-sim ends; its sources may have gone stale by the stop.
        if i < 2 {
            let still: Vec<_> = open.iter().filter(|(_, s)| **s).collect();
            assert!(
                still.is_empty(),
                "gateway {}: faults never cleared: {still:?}",
                i + 1
            );
        }
    }
}
