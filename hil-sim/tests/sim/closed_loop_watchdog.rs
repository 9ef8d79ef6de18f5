//! The virtual-time twin of `gateway_watchdog_hil`: the PLC's heartbeat watchdog (`[plc.watchdog]`,
//! the rule of docs/gateway.md) against the gateway's own sink core writing a heartbeat every
//! period, with the box killed (SIGKILL), frozen (SIGSTOP/SIGCONT) and stopped with a ramp-out
//! (SIGTERM). Asserted on the PLC's own record ([`ClosedLoop::plc_events`]) at exact instants: the
//! trip one timeout after the last heartbeat the PLC saw change, the ramp to 0 at exactly its rate
//! in whole counts, every latch of the box within the cap of what the PLC applied, the box back
//! from what the PLC holds.

use crate::closed_loop_support;

use closed_loop_support::*;
use hil_sim::controller::{PlcEvent, PlcEventKind};
use hil_sim::harness::ClosedLoop;

const HEARTBEAT_REGISTER: u16 = 12;
/// The PLC's heartbeat timeout (50 write periods), s; the box is told it (`heartbeat_timeout_ms`).
const TIMEOUT_S: f64 = 0.5;
/// The PLC's ramp-out rate, µm/s.
const RAMP_UM_PER_S: f64 = 20.0;
/// The sim's PLC scan, s (the fixture's `scan_s`).
const SCAN_S: f64 = 0.004;
/// A correction the PLC must hold before each fault, so a missing ramp would show, µm.
const HOLDS_UM: f64 = 6.0;

fn watchdog_loop() -> ClosedLoop {
    let program = format!(
        "S3000 M3\nG4 P0.5\n{}M5",
        "G1 X150 Y100 F3600\nG1 X0 Y0\n".repeat(4)
    );
    let extra = format!(
        "[plc.watchdog]\nheartbeat_register = {HEARTBEAT_REGISTER}\ntimeout_s = {TIMEOUT_S}\nramp_um_per_s = {RAMP_UM_PER_S}\n"
    );
    ClosedLoop::new(
        sim_config(&program, false, &extra),
        field_config_heartbeat(HEARTBEAT_REGISTER, 500),
        model_factory(),
    )
    .expect("harness")
}

fn max_abs(v: [f64; 3]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// Step until the PLC holds at least `um` on some axis (bounded by the program's end).
fn until_holds(h: &mut ClosedLoop, um: f64) {
    while max_abs(h.applied_um()) < um && !h.world().done() {
        h.step();
    }
    assert!(max_abs(h.applied_um()) >= um, "never held {um} µm");
}

/// The last instant the heartbeat register changed, at or before `t_s` (from the box's writes).
fn last_heartbeat(h: &ClosedLoop, t_s: f64) -> f64 {
    h.writes()
        .iter()
        .filter(|w| w.address == HEARTBEAT_REGISTER && w.t_s <= t_s + 1e-9)
        .map(|w| w.t_s)
        .next_back()
        .expect("a heartbeat")
}

/// Step until the PLC's record has a `kind` event after `from_s`; its instant.
fn until_event(h: &mut ClosedLoop, kind: PlcEventKind, from_s: f64, within_s: f64) -> f64 {
    let found = |h: &ClosedLoop| {
        h.plc_events()
            .iter()
            .find(|(t, e)| *t > from_s && e.kind == kind)
            .map(|(t, _)| *t)
    };
    while found(h).is_none() && h.t_s() < from_s + within_s && !h.world().done() {
        h.step();
    }
    found(h).unwrap_or_else(|| panic!("no {kind:?} within {within_s} s of {from_s} s"))
}

/// The PLC's ramp from its trip to 0, exactly its rule: from the trip's scan on, each scan takes
/// `ramp_um_per_s × scan_s` off what it held at the trip, and it applies that in whole counts
/// rounded toward 0 (never ahead of the ramp).
fn assert_ramps_at_the_rate(events: &[(f64, PlcEvent)], trip_s: f64, zero_s: f64) {
    let ramp: Vec<&(f64, PlcEvent)> = events
        .iter()
        .filter(|(t, _)| *t >= trip_s && *t <= zero_s)
        .collect();
    let (_, trip) = ramp
        .iter()
        .find(|(_, e)| e.kind == PlcEventKind::Trip)
        .expect("the trip");
    let steps = ramp
        .iter()
        .filter(|(_, e)| e.kind == PlcEventKind::Ramp)
        .count();
    assert!(steps >= 3, "a ramp of {steps} changes");
    for (t, e) in ramp.iter().filter(|(_, e)| e.kind == PlcEventKind::Ramp) {
        let scans = ((t - trip_s) / SCAN_S).round() as usize + 1;
        // Scan by scan, as a PLC's accumulator does (the sum of steps is not one product).
        let step_um = RAMP_UM_PER_S * SCAN_S;
        let expected = trip.shift_counts.map(|held| {
            let held_um = held as f64 * LSB_UM;
            let left_um =
                (0..scans).fold(
                    held_um.abs(),
                    |r, _| {
                        if r <= step_um { 0.0 } else { r - step_um }
                    },
                );
            (left_um / LSB_UM).trunc() as i64 * held.signum()
        });
        assert_eq!(e.shift_counts, expected, "at {t} s, {scans} scans: {e:?}");
    }
}

/// The heartbeat stopped at `from_s`: the PLC trips one timeout after the last heartbeat it saw
/// change (at that scan), and ramps to 0 by its rule. Returns (trip, at zero).
fn trip_and_ramp_to_zero(h: &mut ClosedLoop, from_s: f64) -> (f64, f64) {
    let trip = until_event(h, PlcEventKind::Trip, from_s, 2.0);
    let beat = last_heartbeat(h, from_s);
    assert!(
        trip >= beat + TIMEOUT_S - 1e-9 && trip <= beat + TIMEOUT_S + SCAN_S + 1e-9,
        "tripped at {trip} s, last heartbeat {beat} s"
    );
    let zero = until_event(h, PlcEventKind::AtZero, trip, 2.0);
    assert_ramps_at_the_rate(h.plc_events(), trip, zero);
    (trip, zero)
}

#[test]
fn the_plc_trips_one_timeout_after_the_last_heartbeat_ramps_at_its_rate_and_the_box_comes_back_from_it()
 {
    let mut h = watchdog_loop();
    let (_, period_s) = h.periods_s();

    // 1. SIGKILL: the heartbeat stops with the box.
    until_holds(&mut h, HOLDS_UM);
    let kill_s = h.t_s();
    h.kill_gateway();
    let (trip1, zero1) = trip_and_ramp_to_zero(&mut h, kill_s);
    assert_eq!(h.applied_um(), [0.0; 3]);

    // A new box starts from the PLC's 0 and takes the correction back within the cap per write.
    h.start_new_gateway().unwrap();
    let back1 = until_event(&mut h, PlcEventKind::Rearm, zero1, 1.0);
    until_holds(&mut h, HOLDS_UM);

    // 2. SIGSTOP: the same trip and ramp; after SIGCONT the box re-reads the PLC's 0 and goes on.
    let stop_s = h.t_s();
    h.freeze_gateway(true);
    let (trip2, zero2) = trip_and_ramp_to_zero(&mut h, stop_s);
    h.freeze_gateway(false);
    let cont_s = h.t_s();
    let back2 = until_event(&mut h, PlcEventKind::Rearm, cont_s, 1.0);
    assert!(
        back2 <= cont_s + 2.0 * period_s + SCAN_S,
        "re-armed at {back2} s, SIGCONT at {cont_s} s"
    );
    until_holds(&mut h, HOLDS_UM);

    // 3. SIGTERM with a ramp-out: the box takes its correction to 0 itself; when it then exits
    // and the PLC trips, the PLC already holds 0 and nothing moves.
    let term_s = h.t_s();
    h.stop_gateway();
    while !h.is_ramped_out() && h.t_s() < term_s + 5.0 {
        h.step();
    }
    assert!(h.is_ramped_out(), "not ramped out by {} s", h.t_s());
    let exit_s = h.t_s();
    h.kill_gateway();
    let trip3 = until_event(&mut h, PlcEventKind::Trip, exit_s, 2.0);
    let at_trip3 = h
        .plc_events()
        .iter()
        .find(|(t, e)| *t == trip3 && e.kind == PlcEventKind::Trip)
        .unwrap()
        .1;
    assert_eq!(
        at_trip3.shift_counts, [0; 3],
        "the PLC held 0 when it tripped"
    );
    h.run_until(trip3 + 0.5);
    assert!(
        h.plc_events()
            .iter()
            .all(|(t, e)| *t <= trip3 || e.kind == PlcEventKind::AtZero),
        "nothing moves after the last trip"
    );

    // Every latch of every box: within the cap of what the PLC applied, within the clamp.
    assert_clamp_and_cap_per_write(h.writes());
    let trips: Vec<f64> = h
        .plc_events()
        .iter()
        .filter(|(_, e)| e.kind == PlcEventKind::Trip)
        .map(|(t, _)| *t)
        .collect();
    assert_eq!(trips, [trip1, trip2, trip3], "three trips, no other");
    eprintln!(
        "watchdog: kill {kill_s} → trip {trip1} → 0 at {zero1} → rearm {back1}; stop {stop_s} → trip {trip2} → 0 at {zero2}, cont {cont_s} → rearm {back2}; term {term_s} → 0 at {exit_s} → trip {trip3}"
    );
}
