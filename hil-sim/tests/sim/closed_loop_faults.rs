//! Fault scenarios of the closed loop, in virtual time (issue 14.4): hil-sim's world ↔ the bus codecs
//! ↔ retrocomp's engine ↔ the origin-shift sink core ↔ the simulated PLC, stepped in one process by
//! `hil_sim::harness::ClosedLoop` (no threads, sockets or sleeps: nothing here depends on how fast or
//! busy the machine is). Every scenario asserts the clamp and the cap per write against what the PLC
//! applied, that the applied shift never jumps, and recovery exactly: fault edges at the computed
//! instants, and the number of writes back to the target, or bit-identity with the same run without
//! the fault. The real-socket tests (`tests/real_peers/gateway_faults_hil.rs` and friends) keep one run per
//! transport for the shells.

use crate::closed_loop_support;

use closed_loop_support::*;
use hil_sim::harness::ClosedLoop;
use retrocomp_gateway::FaultKind;

/// The first dwell (X150 Y100) and the second (X40 Y30, 130 mm later at 60 mm/s) of [`MOVES`], s.
const DWELL1: (f64, f64) = (3.5, 6.5);
const DWELL2: (f64, f64) = (8.7, 14.6);

/// The number of writes of at most one cap that take `held` to `target` on every axis.
fn capped_writes(held: [f64; 3], target: [f64; 3]) -> usize {
    (0..3)
        .map(|k| ((target[k] - held[k]).abs() / CAP_UM - 1e-9).ceil() as usize)
        .max()
        .unwrap()
}

/// The value writes from `t_s` on until the applied shift equals `target` (and stays there to
/// the end of `until_s`); panics if it never does.
fn writes_until_applied(h: &ClosedLoop, t_s: f64, until_s: f64, target: [f64; 3]) -> usize {
    let reached = from(h.trace(), t_s)
        .filter(|r| r.t_s <= until_s)
        .find(|r| r.applied_um == target)
        .unwrap_or_else(|| {
            let rows: Vec<_> = from(h.trace(), t_s).step_by(500).collect();
            panic!("never reached {target:?}: {rows:?}")
        })
        .t_s;
    for r in from(h.trace(), reached).filter(|r| r.t_s <= until_s) {
        assert_eq!(r.applied_um, target, "left the target at {} s", r.t_s);
    }
    h.writes()
        .iter()
        .filter(|w| VALUE_REGISTERS.contains(&w.address) && w.t_s >= t_s && w.t_s < reached)
        .count()
}

/// Only the spindle sensor faults: the neighbour it leans on and the other CiA 404 sensor stay
/// healthy after start-up (their first frames). (The spindle sensor's own `Stuck` and `OutOfRange`
/// are one episode each, `one_episode` in the scenario.)
fn assert_only_the_spindle_sensor_faults(h: &ClosedLoop) {
    for quiet in ["T_spindle2_C", "T_xscrew_C"] {
        let late: Vec<_> = h
            .fault_edges()
            .iter()
            .filter(|e| e.source == quiet && e.t_s >= 0.5)
            .collect();
        assert!(late.is_empty(), "{quiet} faulted: {late:?}");
    }
}

/// The largest difference of Z's output between two runs in `from_s..to_s`, µm.
fn z_off(h: &ClosedLoop, clean: &ClosedLoop, from_s: f64, to_s: f64) -> f64 {
    h.trace()
        .iter()
        .zip(clean.trace())
        .filter(|(r, _)| r.t_s >= from_s && r.t_s < to_s)
        .map(|(r, c)| (r.output_um[2] - c.output_um[2]).abs())
        .fold(0.0, f64::max)
}

fn lsb_target(h: &ClosedLoop) -> [f64; 3] {
    h.trace().last().unwrap().output_um.map(lsb_round)
}

#[test]
fn transport_down_and_back_resumes_from_what_the_plc_holds_in_exactly_the_capped_writes() {
    let (down, back) = (5.0, 11.0);
    let faults = format!("[[io.faults]]\nkind = \"modbus_down\"\nfrom_s = {down}\nto_s = {back}\n");
    let mut h = closed_loop(sim_config(MOVES, true, &faults));
    let (_, period) = h.periods_s();
    h.run_until(down);
    let before = lsb_target(&h);
    assert_eq!(h.applied_um(), before, "converged in the first dwell");
    h.run_until(back);
    let held = h.applied_um();
    assert_eq!(held, before, "the PLC kept its shift across the comms loss");
    h.run_until(DWELL2.1);
    // The target where the dwell settled (the motor encoder sees the applied shift, so the target
    // moves by a fraction of a count while the shift changes).
    let target = lsb_target(&h);
    assert!(
        (0..3).any(|k| (target[k] - held[k]).abs() >= 3.0 * CAP_UM),
        "the move changed too little to test: {held:?} → {target:?}"
    );
    // The client learns of the loss when its request in flight fails (the period before `down`
    // still waits for the PLC's ack: its next read goes out at `down` and fails), and tries again
    // on the real `bus::Backoff` schedule (reconnect_min_ms 100 doubling to reconnect_max_ms
    // 5000), at the first write period at or after each due instant: 5.0 + 0.1 → 5.1, + 0.2 → 5.3,
    // + 0.4 → 5.7, + 0.8 → 6.5, + 1.6 → 8.1, + 3.2 → 11.3, the first attempt after the link is
    // back at 11 s.
    let failed_at = step_time(&h, down);
    let expected = [
        (5.1, false),
        (5.3, false),
        (5.7, false),
        (6.5, false),
        (8.1, false),
        (11.3, true),
    ];
    let attempts = h.connect_attempts();
    assert_eq!(attempts.len(), expected.len(), "{attempts:?}");
    for (a, (t, ok)) in attempts.iter().zip(expected) {
        assert_at(a.t_s, step_time(&h, t), "connect attempt");
        assert_eq!(a.ok, ok, "{a:?}");
    }
    // The same instants from the backoff itself, so the literal list above is the real schedule.
    let mut backoff = retrocomp_bus::Backoff::from_millis(100, 5000);
    let mut due = failed_at;
    for (t, _) in expected {
        due = period_at_or_after(due + backoff.next_delay().as_secs_f64(), period);
        assert!((due - t).abs() < 1e-6, "backoff due {due}, listed {t}");
    }
    let resumed = step_time(&h, 11.3);
    // Nothing reached the PLC from the loss until the reconnect (not even after the link was back
    // at 11 s: the client waits out its backoff); the sink's fault is one episode from the failed
    // request to the first period after the reconnect.
    assert!(h.writes().iter().all(|w| w.t_s < down || w.t_s >= resumed));
    let (start, clear) = one_episode(&h, "sink.origin_shift", FaultKind::Disconnected);
    assert_at(start, failed_at, "Disconnected start");
    // The period of the reconnect reads twice (values 0–5, then strobe/ack 10–11: one step each),
    // writes the values at the next step, and clears the fault when it completes (strobe, ack,
    // read-back: waiting for the PLC's ack it may outlast one period, whose tick is skipped).
    let first = h.writes().iter().find(|w| w.t_s >= back).unwrap();
    assert_at(
        first.t_s,
        step_time(&h, 11.3 + 0.003),
        "first write after the return",
    );
    assert!(
        clear > first.t_s && clear < resumed + 2.0 * period,
        "cleared at {clear} s"
    );
    // Recovery: one cap per write from what the PLC held to the target.
    let n = writes_until_applied(&h, back, DWELL2.1, target);
    assert_eq!(n, capped_writes(held, target), "{held:?} → {target:?}");
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[]);
}

#[test]
fn a_silent_encoder_node_holds_for_exactly_the_hold_time_ramps_out_and_comes_back_capped() {
    let (silent, back) = (4.0, 5.5);
    let faults = node_silent(1, silent, back);
    let mut h = closed_loop(sim_config(MOVES, true, &faults));
    h.run_until(silent);
    let target = lsb_target(&h);
    assert_eq!(h.applied_um(), target, "converged in the first dwell");
    let out_before = h.trace().last().unwrap().output_um;
    h.run_until(DWELL1.1);
    // The X encoder's last frame came at the last 2 ms tick before the silence: x_mm is stale at the
    // first cycle more than `stale_after_s` (0.1 s) after it, on the inputs' own clock.
    let last_frame = step_time(&h, silent - 0.002);
    let stale_at = cycles_in(&h, silent, back)
        .find(|c| c - last_frame > 0.1)
        .unwrap();
    let (start, clear) = one_episode(&h, "x_mm", FaultKind::Stale);
    assert_at(start, stale_at, "x_mm stale");
    // Back with the first frame after the silence, at the cycle of the same step.
    assert_at(clear, back, "x_mm fresh again");
    for quiet in ["y_mm", "z_mm"] {
        assert!(edges(&h, quiet, FaultKind::Stale).is_empty(), "{quiet}");
    }
    // Every axis drops (the model needs all positions): one episode each, same instants.
    for axis in ["x", "y", "z"] {
        let (s, c) = one_episode(&h, &format!("compensation.{axis}"), FaultKind::Stale);
        assert_at(s, stale_at, "drop start");
        assert_at(c, back, "drop clear");
    }
    // Hold exactly the last output for `stale_hold_s` (0.5 s), then ramp out to 0.
    let ramp_at = cycles_in(&h, stale_at, back)
        .find(|c| c - stale_at >= 0.5)
        .unwrap();
    for r in from(h.trace(), stale_at).filter(|r| r.t_s < ramp_at) {
        assert_eq!(r.output_um, out_before, "held at {} s", r.t_s);
    }
    let after = from(h.trace(), ramp_at).next().unwrap();
    assert_ne!(after.output_um, out_before, "ramping from {ramp_at} s");
    let held = h
        .trace()
        .iter()
        .find(|r| (r.t_s - back).abs() < 1e-9)
        .unwrap()
        .applied_um;
    assert_eq!(held, [0.0; 3], "ramped out before the node came back");
    // Back: from 0 to the target in exactly one cap per write (the sink's cap binds: the engine
    // ramps at 1 µm per 5 ms cycle, the sink writes 1 µm per 10 ms).
    let n = writes_until_applied(&h, back, DWELL1.1, target);
    assert_eq!(n, capped_writes(held, target), "0 → {target:?}");
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[]);
}

#[test]
fn a_foreign_value_in_the_plc_is_continued_from_and_left_in_exactly_the_capped_writes() {
    let mut h = closed_loop(sim_config(MOVES, true, ""));
    let (_, period) = h.periods_s();
    h.run_until(4.006);
    let target = lsb_target(&h);
    assert_eq!(h.applied_um(), target, "converged in the first dwell");
    // An operator sets X's shift 12 µm away from the target and strobes it in.
    let foreign = target[0] + if target[0] > 0.0 { -12.0 } else { 12.0 };
    h.foreign_write(0, foreign).unwrap();
    h.run_until(DWELL1.1);
    let latched = h
        .trace()
        .iter()
        .find(|r| r.applied_um[0] == foreign)
        .expect("the PLC applied the foreign value")
        .t_s;
    // The next period reads it and the engine continues from it: the next write is within one cap
    // of the foreign value (asserted for every write below), never back at the old target.
    let next = period_at_or_after(latched, period);
    let first = h.writes().iter().find(|w| w.t_s >= next).unwrap();
    assert!(
        (first.registers_um[0] - foreign).abs() <= CAP_UM,
        "{first:?}"
    );
    let n = writes_until_applied(&h, latched, DWELL1.1, target);
    let xs: Vec<f64> = h
        .writes()
        .iter()
        .filter(|w| w.address == 0 && w.t_s >= latched && w.t_s < latched + 0.2)
        .map(|w| w.registers_um[0])
        .collect();
    // Every write from the foreign value on moves one cap towards the target: the period that read
    // it wrote one cap towards the target (the last-step guard against what the PLC holds), and the
    // engine, reseeded with the value as read, ramps on from it at its next cycle (the reseed keeps
    // the safety state's cycle clock: no period stands still), so X takes exactly the capped writes.
    let step = CAP_UM * (target[0] - foreign).signum();
    let expected: Vec<f64> = (1..=xs.len())
        .map(|k| {
            let v = foreign + k as f64 * step;
            if step > 0.0 {
                v.min(target[0])
            } else {
                v.max(target[0])
            }
        })
        .collect();
    assert_eq!(xs, expected, "x written after the foreign {foreign} µm");
    assert_eq!(
        n,
        capped_writes([foreign, target[1], target[2]], target),
        "{foreign} → {target:?}: x written {xs:?}"
    );
    // Not a fault of the sink (the value is within the clamp and nothing of ours was pending).
    assert!(
        h.fault_edges()
            .iter()
            .all(|e| !e.source.starts_with("sink.")),
        "{:?}",
        h.fault_edges()
    );
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[latched]);
}

#[test]
fn a_restarted_gateway_continues_from_what_the_plc_holds_and_meets_the_unbroken_run() {
    // Restart mid-move (the target changing under the dosing cap) and compare with the same run
    // without the restart: both end the second dwell on the same shift.
    let run = |restart: bool| {
        let mut h = closed_loop(sim_config(MOVES, true, ""));
        h.run_until(7.5);
        if restart {
            let held = h.registers_held_um();
            h.restart_gateway().unwrap();
            // Up to the new engine's first cycle.
            h.run_until(7.505);
            // The new engine's first output continues from the registers, within one dosing cap.
            let out = h.trace().last().unwrap().output_um;
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                assert!(
                    (out[k] - held[*axis]).abs() <= CAP_UM,
                    "{axis}: {held:?} → {out:?}"
                );
            }
        }
        h.run_until(DWELL2.1);
        h
    };
    let restarted = run(true);
    let unbroken = run(false);
    let gen1: Vec<_> = restarted
        .writes()
        .iter()
        .filter(|w| w.generation == 1)
        .collect();
    assert!(
        gen1.first().is_some_and(|w| w.t_s < 7.52),
        "{:?}",
        gen1.first()
    );
    let target = lsb_target(&unbroken);
    assert_eq!(unbroken.applied_um(), target);
    assert_eq!(restarted.applied_um(), target, "met the unbroken run");
    assert_eq!(lsb_target(&restarted), target);
    assert_clamp_and_cap_per_write(restarted.writes());
    assert_no_jump(restarted.trace(), &[]);
}

#[test]
fn a_stuck_then_nan_spindle_sensor_is_replaced_by_its_neighbour_without_dropping_compensation() {
    let faults = STUCK_THEN_NAN;
    let mut h = closed_loop(sim_config(STROKES, false, faults));
    let mut clean = closed_loop(sim_config(STROKES, false, ""));
    for g in [&mut h, &mut clean] {
        g.gateway_mut().unwrap().record_samples("T_spindle_C");
    }
    // The value the engine uses for the spindle sensor and for its neighbour, every step.
    let mut used = Vec::new();
    while !h.world().done() {
        h.step();
        let gw = h.gateway().unwrap();
        used.push((
            h.t_s(),
            gw.channel_value("T_spindle_C"),
            gw.channel_value("T_spindle2_C"),
        ));
    }
    clean.run_to_end();
    let (stuck, _) = one_episode(&h, "T_spindle_C", FaultKind::Stuck);
    // Judged stuck by the detector's rule on the readings the gateway received (a CiA 404 frame
    // every 50 ms, decoded by the gateway's own source core): the first reading at least
    // `stuck_after_s` (1 s) after the first of the bit-identical run that holds the frozen value
    // (the reading at 3.0 s, or an earlier one when it matched).
    let samples = h.gateway().unwrap().recorded_samples();
    let k = samples.iter().position(|s| s.t_s >= 3.0 - 1e-9).unwrap();
    let frozen = samples[k].value;
    let first = (0..=k)
        .rev()
        .take_while(|&j| samples[j].value.to_bits() == frozen.to_bits())
        .last()
        .unwrap();
    let since = samples[first].t_s;
    let judged = samples[k..]
        .iter()
        .find(|s| s.t_s - since >= 1.0)
        .unwrap()
        .t_s;
    assert_at(stuck, judged, "Stuck start");
    for s in samples.iter().filter(|s| s.t_s >= since && s.t_s <= judged) {
        assert_eq!(
            s.value.to_bits(),
            frozen.to_bits(),
            "frozen from {since} s: {s:?}"
        );
    }
    // Up to the frozen frame the readings are the clean run's, bit for bit; the clean run's next
    // reading differs (noise 0.08 °C on 0.1 °C steps), so the runs part exactly there.
    let clean_samples = clean.gateway().unwrap().recorded_samples();
    assert_eq!(samples[..=k], clean_samples[..=k]);
    let parted = (k + 1..samples.len())
        .find(|&j| samples[j] != clean_samples[j])
        .unwrap();
    eprintln!(
        "stuck: frozen {frozen} °C from {since} s (fault at 3.0 s), judged at {judged} s; \
         readings part from the clean run at {} s",
        samples[parted].t_s
    );
    let n = h
        .trace()
        .iter()
        .take_while(|r| r.t_s < samples[parted].t_s - 1e-9)
        .count();
    assert_eq!(
        h.trace()[..n],
        clean.trace()[..n],
        "identical until the readings part"
    );
    // NaN goes out as 0x7FFF (over range): out of range from the first frame at 5.0 s; clear with
    // the first good frame (a sensor fault's window includes its end, `physics/faults.rs`: the
    // first good reading is on the next CiA 404 frame, 50 ms after 6.5 s).
    let (nan, ok) = one_episode(&h, "T_spindle_C", FaultKind::OutOfRange);
    assert_at(nan, 5.0, "OutOfRange start");
    assert_at(ok, step_time(&h, 6.55), "OutOfRange clear");
    // From the stuck judgement to the first good reading, the engine uses exactly the
    // neighbour's estimate (coefficients [0, 1]: T_spindle2_C itself), at every step; before the
    // judgement the frozen reading, after the clear the sensor's own.
    let mut replaced = 0;
    for (t, v, v2) in &used {
        if *t >= stuck - 1e-9 && *t < ok - 1e-9 {
            assert_eq!(
                *v, *v2,
                "at {t} s the spindle sensor is not its neighbour's estimate"
            );
            assert!(v.is_some(), "no value at {t} s");
            replaced += 1;
        } else if *t >= since - 1e-9 && *t < stuck - 1e-9 {
            assert_eq!(*v, Some(frozen), "at {t} s");
        }
    }
    assert_eq!(
        replaced,
        h.trace()
            .iter()
            .filter(|r| r.t_s >= stuck - 1e-9 && r.t_s < ok - 1e-9)
            .count()
    );
    // The neighbour's estimate stood in throughout: compensation never dropped.
    assert_compensation_never_dropped(&h);
    assert_only_the_spindle_sensor_faults(&h);
    // What the substitution costs Z (a model error, not a timing window: the neighbour sits on
    // the same node with a slower sensor lag and its own noise, and the model's thermal lag
    // carries what the frozen reading fed it for 1 s): within 3 µm of the clean run.
    let worst = z_off(&h, &clean, stuck, ok);
    eprintln!("substituted Z: at most {worst:.2} µm off the clean run");
    assert!(worst <= 3.0, "Z {worst} µm off the clean run");
    // Back on its own sensor, the loop rejoins the clean run bit for bit (outputs, applied shift)
    // within a second of the first good reading.
    let apart = h
        .trace()
        .iter()
        .zip(clean.trace())
        .rposition(|(a, b)| a != b)
        .map_or(0.0, |i| h.trace()[i].t_s);
    eprintln!("after the clear ({ok} s): identical to the clean run again after {apart} s");
    assert!(apart < ok + 1.0, "still apart at {apart} s");
    assert_eq!(h.trace().len(), clean.trace().len());
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[]);
}

#[test]
fn garbage_on_the_force_line_is_rejected_and_the_loop_rejoins_the_clean_run_bit_for_bit() {
    let (g0, g1) = (2.0, 4.0);
    let faults = format!("[[io.faults]]\nkind = \"serial_garbage\"\nfrom_s = {g0}\nto_s = {g1}\n");
    let mut h = closed_loop(sim_config(STROKES, false, &faults));
    let mut clean = closed_loop(sim_config(STROKES, false, ""));
    h.run_to_end();
    clean.run_to_end();
    assert!(h.serial_bytes() > clean.serial_bytes(), "no garbage sent");
    let garbage = h.gateway().unwrap().serial_garbage_lines();
    assert!(garbage >= 10, "{garbage} garbage lines counted");
    assert_eq!(clean.gateway().unwrap().serial_garbage_lines(), 0);
    // The absurd 90 kN readings are rejected (out of range), never used.
    let oor = edges(&h, "F_cut_N", FaultKind::OutOfRange);
    assert!(!oor.is_empty());
    assert!(
        oor.iter().all(|e| e.t_s >= g0 && e.t_s <= g1 + 0.02),
        "{oor:?}"
    );
    // Identical before the window; after it, from one step on identical to the end.
    let n = h.trace().iter().take_while(|r| r.t_s < g0).count();
    assert_eq!(h.trace()[..n], clean.trace()[..n]);
    assert_eq!(h.trace().len(), clean.trace().len());
    let diverged = h
        .trace()
        .iter()
        .zip(clean.trace())
        .rposition(|(a, b)| a != b)
        .map_or(0.0, |i| h.trace()[i].t_s);
    eprintln!("garbage: {garbage} lines; identical to the clean run again after {diverged} s");
    assert!(diverged < g1 + 1.0, "still apart at {diverged} s");
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[]);
}

#[test]
fn the_same_configs_give_the_same_run() {
    let faults = "[[io.faults]]\nkind = \"modbus_down\"\nfrom_s = 2.0\nto_s = 2.5\n";
    let run = || {
        let mut h = closed_loop(sim_config(STROKES, false, faults));
        h.run_until(4.0);
        h
    };
    let (a, b) = (run(), run());
    assert_eq!(a.trace(), b.trace());
    assert_eq!(a.writes(), b.writes());
    assert_eq!(a.fault_edges(), b.fault_edges());
}
