//! Stopping with `on_stop = "ramp_out"` in virtual time, through the gateway's own sink cores
//! (`GatewayCore::handle_stop`, as the runtime's sinks on SIGTERM): the controller's correction goes
//! to 0 within the cap per write (origin shift) or one count per cycle (quadrature), never away from
//! 0, whatever the engine's outputs still are; an axis whose controller value is beyond the clamp is
//! left where it is. Asserted against what the simulated controller applies.

use crate::closed_loop_support;

use closed_loop_support::*;
use hil_sim::harness::{ClosedLoop, Pulse};
use retrocomp_model::Axis;

/// Stop at `t_stop` and step until the sink has ramped out or `limit_s` (then one more second
/// to show it would not). Returns the instant it ramped out.
fn stop_and_ramp_out(h: &mut ClosedLoop, limit_s: f64) -> f64 {
    h.stop_gateway();
    while !h.is_ramped_out() && h.t_s() < limit_s + 1.0 {
        h.step();
    }
    assert!(
        h.is_ramped_out(),
        "not ramped out by {} s: {:?}",
        h.t_s(),
        h.applied_um()
    );
    assert!(
        h.t_s() <= limit_s + 1e-9,
        "ramped out at {} s, expected by {limit_s} s",
        h.t_s()
    );
    h.t_s()
}

/// The largest |value| among the axes, in units of `step`.
fn steps_of(held: [f64; 3], step: f64) -> f64 {
    held.iter()
        .map(|v| (v.abs() / step).ceil())
        .fold(0.0, f64::max)
}

#[test]
fn stopping_ramps_the_plc_out_within_the_cap_per_write_and_never_away_from_zero() {
    let mut h = closed_loop(sim_config(MOVES, true, ""));
    h.run_until(4.0);
    let held = h.applied_um();
    assert!(
        steps_of(held, CAP_UM) >= 3.0,
        "a correction of several caps to ramp out: {held:?}"
    );
    let (_, period_s) = h.periods_s();
    let writes_before = h.writes().len();
    // One cap per two periods (a write is confirmed by the next period's read of what the PLC
    // applies before the guard lets the next cap go: it writes from what the controller holds),
    // the read that shows 0, and one period of phase.
    let limit_s = h.t_s() + (2.0 * steps_of(held, CAP_UM) + 3.0) * period_s;
    let ramped_s = stop_and_ramp_out(&mut h, limit_s);
    assert_eq!(h.applied_um(), [0.0; 3]);
    let ramp: Vec<_> = h.writes()[writes_before..]
        .iter()
        .filter(|w| VALUE_REGISTERS.contains(&w.address))
        .collect();
    assert!(ramp.len() >= 3, "{} value writes", ramp.len());
    for w in &ramp {
        for k in 0..3 {
            // Every write takes one whole cap toward 0 (the rest, at the end): no more, no less.
            let applied = w.applied_um[k];
            let expected = applied - applied.signum() * applied.abs().min(CAP_UM);
            assert_eq!(w.registers_um[k], expected, "axis {k}: {w:?}");
        }
    }
    let writes = ramp.len();
    // The engine still wants its correction: the sink, not the engine, went to 0 — and stays.
    assert_ne!(h.trace().last().unwrap().output_um, [0.0; 3]);
    h.run_until(ramped_s + 0.5);
    assert!(from(h.trace(), ramped_s).all(|r| r.applied_um == [0.0; 3]));
    eprintln!("origin-shift stop: {held:?} → 0 in {writes} writes");
}

#[test]
fn stopping_ramps_the_counts_out_one_count_per_cycle_all_one_way() {
    let mut h = closed_loop_quadrature(sim_config(MOVES, true, ""));
    h.run_until(4.0);
    let held = h.applied_um();
    assert!(steps_of(held, 1.0) >= 3.0, "counts to ramp out: {held:?}");
    let (cycle_s, _) = h.periods_s();
    let stop_ns = (h.t_s() * 1e9).round() as u64;
    // One count (1 µm) per cycle, and one cycle for the last edge to be out.
    let limit_s = h.t_s() + (steps_of(held, 1.0) + 2.0) * cycle_s;
    let ramped_s = stop_and_ramp_out(&mut h, limit_s);
    assert_eq!(h.applied_um(), [0.0; 3]);
    assert_eq!(
        h.received_counts(),
        Some([0; 3]),
        "the receiver's net count"
    );
    let after: Vec<&Pulse> = h.pulses().iter().filter(|p| p.t_ns > stop_ns).collect();
    assert!(after.iter().all(|p| p.step.is_ok()), "illegal transitions");
    for (k, axis) in Axis::ALL.into_iter().enumerate() {
        let of_axis: Vec<&&Pulse> = after.iter().filter(|p| p.axis == axis).collect();
        let steps: Vec<i64> = of_axis.iter().map(|p| p.step.unwrap()).collect();
        // +n counts move the slide −n µm: from `held` to 0 the counts net +held.
        assert_eq!(
            steps.iter().sum::<i64>() as f64,
            held[k],
            "axis {k}: {steps:?}"
        );
        assert!(
            steps.windows(2).all(|w| w[0] == w[1]),
            "axis {k} turned back: {steps:?}"
        );
        assert!(
            of_axis
                .windows(2)
                .all(|w| w[1].t_ns - w[0].t_ns >= 5_000_000),
            "axis {k}: two counts within one cycle"
        );
    }
    assert_ne!(h.trace().last().unwrap().output_um, [0.0; 3]);
    let edges_at_ramped = h.pulses().len();
    h.run_until(ramped_s + 0.5);
    assert_eq!(
        h.pulses().len(),
        edges_at_ramped,
        "edges after the ramp-out"
    );
    eprintln!(
        "quadrature stop: {held:?} → 0 in {:.3} s",
        ramped_s - stop_ns as f64 * 1e-9
    );
}

#[test]
fn stopping_leaves_a_count_beyond_the_clamp_where_it_is_and_ramps_the_other_axes() {
    use retrocomp_gateway::sinks::quadrature::HeldCounts;
    let mut h = closed_loop_quadrature(sim_config(MOVES, true, ""));
    h.run_until(1.0);
    let beyond = (clamp_of(0) + 10.0).round() as i64;
    h.held_counts().clone().save("x", beyond).unwrap();
    h.restart_gateway().unwrap();
    h.run_until(4.0);
    let held = h.applied_um();
    assert!(
        held[1] != 0.0 || held[2] != 0.0,
        "y or z to ramp out: {held:?}"
    );
    let (cycle_s, _) = h.periods_s();
    let until = h.t_s() + (steps_of([0.0, held[1], held[2]], 1.0) + 2.0) * cycle_s;
    h.stop_gateway();
    h.run_until(until);
    assert!(
        !h.is_ramped_out(),
        "x holds a count beyond the clamp: never ramped out"
    );
    let now = h.applied_um();
    assert_eq!((now[1], now[2]), (0.0, 0.0), "y and z ramped out: {now:?}");
    assert_eq!(
        now[0], held[0],
        "x not ramped from a value beyond the clamp"
    );
    assert_eq!(
        h.held_counts().get("x"),
        Some(beyond),
        "x's count untouched"
    );
}
