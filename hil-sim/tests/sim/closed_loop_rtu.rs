//! The virtual-time twin of `gateway_faults_rtu_hil`: the same gateway (`T_spindle_C` over Modbus
//! RTU, its neighbour `T_spindle2_C` on CAN, the `[[recovery]]` estimate), the same poller rule
//! (`retrocomp_bus::modbus::PollSchedule`: the runtime's poller runs it too) and the same mute of
//! the sim's RTU slave, 7–10 s, asserted on exact instants instead of wall-clock windows: when the
//! channel goes stale and comes back (from the poll period, reply timeout and reconnect backoff of
//! `tests/fixtures/faults_hil/rtu_source.toml`), that the estimate stands in for the whole mute
//! without dropping compensation, that the sink's writes never pause, and that the correction
//! stays on the run without the fault.

use crate::closed_loop_support;

use closed_loop_support::*;
use hil_sim::harness::ClosedLoop;
use retrocomp_gateway::FaultKind;

/// The RTU slave's mute, s (as `gateway_faults_rtu_hil`'s `RTU_DOWN`).
const RTU_DOWN: (f64, f64) = (7.0, 10.0);
/// `rtu_source.toml`: poll period, reply timeout, longest reconnect backoff, s.
const PERIOD_S: f64 = 0.05;
const TIMEOUT_S: f64 = 0.2;
const BACKOFF_MAX_S: f64 = 0.4;
/// The gateway's cycle (the fixture's `cycle_ms`), s.
const CYCLE_S: f64 = 0.005;
/// How far the correction may be from the run without the fault, µm (the real-peer run's
/// tolerance against the ideal correction).
const TOL_UM: f64 = 5.0;

/// Out-and-back strokes, 3 s each, for ≈ 18.5 s: warm, and still warming through the mute.
fn program() -> String {
    let strokes = "G1 X150 Y100 F3600\nG1 X0 Y0\n".repeat(3);
    format!("S3000 M3\nG4 P0.5\n{strokes}M5")
}

fn rtu_loop(faults: bool) -> ClosedLoop {
    let mut extra = "[io.modbus]\ntemps_first_input = 0\n".to_string();
    if faults {
        extra += &format!(
            "[[io.faults]]\nkind = \"modbus_rtu_down\"\nfrom_s = {}\nto_s = {}\n",
            RTU_DOWN.0, RTU_DOWN.1
        );
    }
    ClosedLoop::new(
        sim_config(&program(), false, &extra),
        field_config_rtu(),
        model_factory(),
    )
    .expect("harness")
}

/// Step to the end, recording at every cycle whether `T_spindle_C` is usable (fresh or its
/// estimate) for the engine.
fn run_recording_usable(h: &mut ClosedLoop) -> Vec<(f64, bool)> {
    let mut usable = Vec::new();
    while !h.world().done() {
        h.step();
        let gw = h.gateway().unwrap();
        usable.push((h.t_s(), gw.channel_value("T_spindle_C").is_some()));
    }
    usable
}

#[test]
fn a_mute_rtu_slave_goes_stale_in_one_timeout_is_estimated_throughout_and_back_within_the_backoff()
{
    let mut h = rtu_loop(true);
    let mut clean = rtu_loop(false);
    let usable = run_recording_usable(&mut h);
    clean.run_to_end();
    assert!(
        h.t_s() > RTU_DOWN.1 + 3.0,
        "the program ran past the mute: {}",
        h.t_s()
    );

    // One Stale episode of the RTU channel. It starts when the first request the mute slave left
    // unanswered times out (the first poll at or after the mute, plus the timeout) and clears at
    // the first poll after the mute that the backoff allows (at most one timeout and the longest
    // backoff after the mute, then a period), each seen by the next cycle.
    // (Before the sim's first sample, 10 ms in, its slave has no registers: the very first read
    // is refused and the channel is stale until the next poll — a start-up of the harness, in
    // both runs, so only edges after the first second count.)
    let after_start = |l: &ClosedLoop| -> Vec<(f64, bool)> {
        edges(l, "T_spindle_C", FaultKind::Stale)
            .iter()
            .filter(|e| e.t_s > 1.0)
            .map(|e| (e.t_s, e.started))
            .collect()
    };
    let episode = after_start(&h);
    assert!(
        episode.len() == 2 && episode[0].1 && !episode[1].1,
        "one Stale episode: {episode:?}"
    );
    let (start, clear) = (episode[0].0, episode[1].0);
    let first_poll = period_at_or_after(RTU_DOWN.0, PERIOD_S);
    assert!(
        start >= first_poll + TIMEOUT_S - 1e-9
            && start <= first_poll + TIMEOUT_S + PERIOD_S + CYCLE_S,
        "stale at {start} s (first poll in the mute at {first_poll} s)"
    );
    assert!(
        clear > RTU_DOWN.1 && clear <= RTU_DOWN.1 + TIMEOUT_S + BACKOFF_MAX_S + PERIOD_S + CYCLE_S,
        "back at {clear} s"
    );
    // The source's link, as the runtime reports it (`modbus.pt100-rtu` Disconnected): down at the
    // first unanswered request's timeout, which is also when its channel went stale, and up again
    // with the reconnect that brought the channel back.
    let link: Vec<(f64, bool)> = edges(&h, "modbus.pt100-rtu", FaultKind::Disconnected)
        .iter()
        .filter(|e| e.t_s > 1.0)
        .map(|e| (e.t_s, e.started))
        .collect();
    assert!(
        link.len() == 2 && link[0].1 && !link[1].1,
        "one link episode: {link:?}"
    );
    assert!(
        link[0].0 <= start && start - link[0].0 < CYCLE_S,
        "link down at {} s, channel stale at {start} s",
        link[0].0
    );
    assert!(
        link[1].0 <= clear && clear - link[1].0 < CYCLE_S,
        "link up at {} s, channel back at {clear} s",
        link[1].0
    );
    assert!(
        edges(&clean, "modbus.pt100-rtu", FaultKind::Disconnected)
            .iter()
            .all(|e| e.t_s < 1.0),
        "the clean run's link never drops after start-up"
    );
    // The clean run: never stale.
    assert!(after_start(&clean).is_empty());
    // The poller's own account: every unanswered request was a timeout, and it reconnected.
    let c = h.gateway().unwrap().modbus_counters(0).unwrap();
    assert!(h.rtu_unanswered() >= 3, "{} unanswered", h.rtu_unanswered());
    assert_eq!(c.timeouts, h.rtu_unanswered(), "{c:?}");
    assert!(c.connects >= 2 && c.connect_failures == 0, "{c:?}");

    // The estimate stands in at every cycle: the channel is never unusable, compensation never
    // drops, and no other channel faults.
    let lost: Vec<_> = usable
        .iter()
        .filter(|(t, u)| !u && *t > 1.0)
        .take(3)
        .collect();
    assert!(lost.is_empty(), "T_spindle_C unusable at {lost:?}");
    assert_compensation_never_dropped(&h);
    let others: Vec<_> = h
        .fault_edges()
        .iter()
        .filter(|e| e.source != "T_spindle_C" && e.source != "modbus.pt100-rtu" && e.t_s > 1.0)
        .collect();
    assert!(others.is_empty(), "{others:?}");

    // The sink never notices: the same value writes at the same instants as the clean run, all
    // within the clamp and the cap, and a correction close to the clean one.
    let times = |l: &ClosedLoop| -> Vec<f64> {
        l.writes()
            .iter()
            .filter(|w| VALUE_REGISTERS.contains(&w.address))
            .map(|w| w.t_s)
            .collect()
    };
    assert_eq!(times(&h), times(&clean), "the writes' instants");
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[]);
    let dev_in = |a_s: f64, b_s: f64| {
        h.trace()
            .iter()
            .zip(clean.trace())
            .filter(|(r, _)| r.t_s >= a_s && r.t_s < b_s)
            .map(|(a, b)| {
                (0..3)
                    .map(|k| (a.applied_um[k] - b.applied_um[k]).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max)
    };
    // Bit for bit the clean run until the mute; then the estimate (the neighbour lags the
    // spindle sensor a little) and the model's thermal lags that took it keep the correction
    // within the real-peer run's tolerance of the clean one, also after the channel is back.
    assert_eq!(dev_in(0.0, RTU_DOWN.0), 0.0, "before the mute");
    let (during, after) = (dev_in(RTU_DOWN.0, clear), dev_in(clear, f64::INFINITY));
    eprintln!(
        "rtu mute {RTU_DOWN:?}: stale {start} s, back {clear} s, {} unanswered, {c:?}, max |Δ| vs clean {during} µm during, {after} µm after",
        h.rtu_unanswered()
    );
    for d in [during, after] {
        assert!(d <= TOL_UM, "{d} µm off the run without the fault");
    }
}
