//! The closed loop with the quadrature sink, in virtual time (issue 14.4): hil-sim's world ↔ the
//! bus codecs ↔ retrocomp's engine ↔ the real quadrature core (`CountQuantizer` → `EdgeScheduler`,
//! A/B edges under the 400 ns gap and the 100 kHz rate) ↔ the simulated controller's ×4 receiver
//! (`QuadDecoder`), whose counts go into the servo's feedback (`World::inject_counts`). One count
//! is the sim's 1 µm feedback count; +n counts move the slide −n µm, so the controller applies
//! `−received` µm. Asserted against what the controller's receiver took: the clamp, the cap per
//! cycle (one count per 5 ms cycle at most), no jump, no illegal transition, and recovery exactly
//! (the receiver holds the engine's output rounded to whole counts at every step), also across a
//! restart of the box (it continues from the counts it persisted).

use crate::closed_loop_support;

use closed_loop_support::*;
use hil_sim::harness::{ClosedLoop, Pulse};
use retrocomp_gateway::FaultKind;

const DWELL1_END: f64 = 6.5;

/// The box quantizes half away from zero (`CountQuantizer`): the controller holds this, µm.
fn counts_of(output_um: f64) -> f64 {
    output_um.round()
}

/// At every step the controller holds exactly the engine's output in whole counts (the box owes
/// nothing at a step's end: at most one count per cycle, 10 µs apart at 100 kHz), within the
/// clamp; consecutive steps differ by at most one cap; every edge was a legal single step.
fn assert_counts_follow_the_output(h: &ClosedLoop, min_edges: usize) {
    for r in h.trace() {
        for k in 0..3 {
            assert_eq!(
                r.applied_um[k],
                counts_of(r.output_um[k]),
                "axis {k} at {} s: the controller holds something else than the output: {r:?}",
                r.t_s
            );
            assert!(
                r.applied_um[k].abs() <= clamp_of(k),
                "beyond the clamp: {r:?}"
            );
        }
    }
    assert_no_jump(h.trace(), &[]);
    let bad: Vec<&Pulse> = h.pulses().iter().filter(|p| p.step.is_err()).collect();
    assert!(bad.is_empty(), "illegal transitions: {bad:?}");
    // Cap per cycle: no two edges of one axis within one 5 ms cycle.
    for axis in retrocomp_model::Axis::ALL {
        let of_axis: Vec<&Pulse> = h.pulses().iter().filter(|p| p.axis == axis).collect();
        for w in of_axis.windows(2) {
            assert!(
                w[1].t_ns - w[0].t_ns >= 5_000_000,
                "two counts within one cycle: {w:?}"
            );
        }
    }
    assert!(
        h.pulses().len() >= min_edges,
        "only {} edges",
        h.pulses().len()
    );
}

fn nonzero(v: [f64; 3]) -> bool {
    v.iter().any(|x| *x != 0.0)
}

#[test]
fn a_silent_encoder_node_ramps_the_counts_out_and_back_one_count_per_cycle() {
    let (silent, back) = (4.0, 5.5);
    let faults = node_silent(1, silent, back);
    let mut h = closed_loop_quadrature(sim_config(MOVES, true, &faults));
    h.run_until(silent);
    let held = h.applied_um();
    assert!(nonzero(held), "a correction to lose: {held:?}");
    assert_eq!(held, h.trace().last().unwrap().output_um.map(counts_of));
    h.run_until(DWELL1_END);
    // The same fault instants as with the origin shift (the engine does not know the sink).
    let (start, clear) = one_episode(&h, "x_mm", FaultKind::Stale);
    assert_at(clear, back, "x_mm fresh again");
    let at_back = h
        .trace()
        .iter()
        .find(|r| (r.t_s - (back - 0.001)).abs() < 1e-9)
        .unwrap()
        .applied_um;
    assert_eq!(
        at_back, [0.0; 3],
        "ramped out to zero counts before the node came back"
    );
    // Back: from 0 to the target, one count per cycle, never away from it: the edges after the
    // return net exactly the target and all go one way per axis.
    let target = h.trace().last().unwrap().output_um.map(counts_of);
    assert_eq!(h.applied_um(), target);
    for (k, axis) in retrocomp_model::Axis::ALL.into_iter().enumerate() {
        let steps: Vec<i64> = h
            .pulses()
            .iter()
            .filter(|p| p.axis == axis && p.t_ns as f64 >= back * 1e9)
            .map(|p| p.step.unwrap())
            .collect();
        assert_eq!(
            steps.iter().sum::<i64>() as f64,
            -target[k],
            "axis {k}: {steps:?}"
        );
        assert!(
            steps.windows(2).all(|w| w[0] == w[1]),
            "axis {k} turned back: {steps:?}"
        );
    }
    eprintln!("quadrature silent node: stale {start} s, back {clear} s, {held:?} → 0 → {target:?}");
    assert_counts_follow_the_output(&h, 21);
}

#[test]
fn a_stuck_then_nan_spindle_sensor_keeps_the_counts_on_the_output_without_dropping() {
    let faults = STUCK_THEN_NAN;
    let mut h = closed_loop_quadrature(sim_config(STROKES, false, faults));
    let mut clean = closed_loop_quadrature(sim_config(STROKES, false, ""));
    h.run_to_end();
    clean.run_to_end();
    let (stuck, _) = one_episode(&h, "T_spindle_C", FaultKind::Stuck);
    let (nan, ok) = one_episode(&h, "T_spindle_C", FaultKind::OutOfRange);
    assert_at(nan, 5.0, "OutOfRange start");
    assert_at(ok, step_time(&h, 6.55), "OutOfRange clear");
    assert!(stuck < nan, "stuck at {stuck} s");
    assert_compensation_never_dropped(&h);
    // Before the fault the two runs are the same run, bit for bit (edges included).
    let n = h.trace().iter().take_while(|r| r.t_s < 3.0).count();
    assert_eq!(h.trace()[..n], clean.trace()[..n]);
    let before = |p: &&Pulse| (p.t_ns as f64) < 3.0e9;
    assert_eq!(
        h.pulses().iter().filter(before).collect::<Vec<_>>(),
        clean.pulses().iter().filter(before).collect::<Vec<_>>()
    );
    assert_counts_follow_the_output(&h, 21);
    assert_counts_follow_the_output(&clean, 21);
}

#[test]
fn a_restarted_box_continues_from_the_persisted_counts_without_an_edge_at_takeover() {
    // Pulses have no read-back: the box persists the count the controller holds ahead of every
    // step (retrocomp_gateway::sinks::quadrature::held, here the harness's in-memory store). A restarted box reads
    // it back: it drives the lines at that count's phase (the receiver sees no edge), continues
    // its counts from it and the engine is seeded with what it realises, so the controller holds
    // exactly the engine's output afterwards — never the old counts plus a second correction.
    let mut h = closed_loop_quadrature(sim_config(MOVES, true, ""));
    h.run_until(DWELL1_END - 1.0);
    let old = h.received_counts().unwrap();
    let held = h.applied_um();
    assert!(nonzero(held), "{held:?}");
    // The takeover is only a test of the phase when some count is not ≡ 0 mod 4.
    assert!(old.iter().any(|c| c.rem_euclid(4) != 0), "{old:?}");
    for (k, axis) in retrocomp_model::Axis::ALL.into_iter().enumerate() {
        assert_eq!(
            h.held_counts().get(axis.name()),
            Some(old[k]),
            "axis {k}: persisted ahead of the edges, nothing owed at a step's end"
        );
    }
    let before = h.pulses().len();
    h.restart_gateway().unwrap();
    assert_eq!(
        h.pulses().len(),
        before,
        "an edge at takeover: {:?}",
        &h.pulses()[before..]
    );
    assert_eq!(h.received_counts().unwrap(), old);
    h.run_until(DWELL1_END);
    // The first cycle of the new engine starts from what the controller holds (one cap at most).
    let first = h
        .trace()
        .iter()
        .find(|r| r.t_s > DWELL1_END - 1.0 + 1e-9)
        .unwrap();
    for k in 0..3 {
        assert!(
            (first.output_um[k] - held[k]).abs() <= 1.0 + 1e-9,
            "axis {k}: the new engine does not continue from the held {held:?}: {first:?}"
        );
    }
    let out = h.trace().last().unwrap().output_um.map(counts_of);
    let now = h.received_counts().unwrap();
    for k in 0..3 {
        assert_eq!(now[k] as f64, -out[k], "axis {k}: old {old:?}, now {now:?}");
    }
    assert!(
        h.pulses()[before..].iter().all(|p| p.generation == 1),
        "the old box emitted after its death"
    );
    // At every step (across the restart): the controller holds the output's counts, within the
    // clamp, one cap per cycle, every edge a legal single step.
    assert_counts_follow_the_output(&h, 10);
    eprintln!("quadrature restart: controller held {held:?} µm (counts {old:?}), now {out:?} µm");
}

#[test]
fn a_persisted_count_beyond_the_clamp_injects_nothing_on_that_axis_and_is_a_fault() {
    // What the store says the controller holds beyond the clamp (a file from another machine, a
    // bad edit) is no start value: the restarted box refuses that axis — nothing injected, never
    // ramped from, a `sink.quadrature.x` BeyondClamp fault — and drives the others, as the
    // runtime's sink does (the harness steps the sink's own core).
    use retrocomp_gateway::sinks::quadrature::HeldCounts;
    let mut h = closed_loop_quadrature(sim_config(MOVES, true, ""));
    h.run_until(1.0);
    let beyond = (clamp_of(0) + 10.0).round() as i64;
    h.held_counts().clone().save("x", beyond).unwrap();
    let before = h.pulses().len();
    h.restart_gateway().unwrap();
    h.run_until(DWELL1_END);
    // The lines start at the persisted count's phase (the file is believed), which the receiver
    // may see as one step at the takeover instant; after it, nothing on x.
    let after: Vec<&Pulse> = h.pulses()[before..]
        .iter()
        .filter(|p| p.t_ns > 1_000_000_000)
        .collect();
    assert!(
        after.iter().all(|p| p.axis != retrocomp_model::Axis::X),
        "edges on x after a beyond-clamp start: {:?}",
        after
            .iter()
            .filter(|p| p.axis == retrocomp_model::Axis::X)
            .take(3)
            .collect::<Vec<_>>()
    );
    assert!(
        after.iter().any(|p| p.axis != retrocomp_model::Axis::X),
        "the other axes are still driven"
    );
    assert_eq!(
        h.held_counts().get("x"),
        Some(beyond),
        "x's count untouched"
    );
    let e = edges(&h, "sink.quadrature.x", FaultKind::BeyondClamp);
    assert_eq!(e.len(), 1, "one start, never cleared: {e:?}");
    assert!(e[0].started && e[0].t_s >= 1.0, "{e:?}");
}
