//! Quadrature injection: the merged A/B stream decodes to exactly native + injected counts, never
//! breaks the receiver's minimum edge gap (Heidenhain RS-422 "a ≥ 0.4 µs" at 400 kHz scanning
//! frequency, anchors-compensation.md §c) nor the injection rate, and drives real `OutputPin`s.

use embedded_hal_mock::eh1::digital::{Mock as PinMock, State, Transaction as PinTx};
use proptest::prelude::*;
use retrocomp_gateway::sinks::quadrature::{
    CountQuantizer, EdgeScheduler, Event, QuadDecoder, QuadraturePins, SchedulerConfig, Source,
    Step, levels_of_phase, simulate,
};

const GAP_NS: u64 = 400; // RS-422 at 400 kHz: a ≥ 0.4 µs

fn check_stream(
    sched: &EdgeScheduler,
    out: &[retrocomp_gateway::sinks::quadrature::Transition],
    native_sum: i64,
    target: i64,
) -> Result<(), TestCaseError> {
    let mut dec = QuadDecoder::new(false, false);
    for tr in out {
        dec.update(tr.a, tr.b)
            .map_err(|e| TestCaseError::fail(format!("decoder error at {} ns: {e}", tr.t_ns)))?;
    }
    prop_assert_eq!(
        dec.count(),
        native_sum + target,
        "decoded count != native + injected"
    );
    for w in out.windows(2) {
        prop_assert!(
            w[1].t_ns >= w[0].t_ns + GAP_NS,
            "edges {} ns apart",
            w[1].t_ns - w[0].t_ns
        );
    }
    let interval = sched.config().inject_interval_ns();
    let inj: Vec<u64> = out
        .iter()
        .filter(|t| t.source == Source::Injected)
        .map(|t| t.t_ns)
        .collect();
    for w in inj.windows(2) {
        prop_assert!(
            w[1] - w[0] >= interval,
            "injected edges {} ns apart < {interval}",
            w[1] - w[0]
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Random native motion (edges at ≥ the gap, as an in-spec encoder gives, with reversals) plus
    /// random correction targets at random times.
    #[test]
    fn merged_stream_counts_native_plus_injected(
        native in prop::collection::vec((GAP_NS..5 * GAP_NS, any::<bool>()), 0..300),
        targets in prop::collection::vec((0u64..200_000, -40i64..40), 0..8),
        rate_khz in 50.0f64..2_000.0,
    ) {
        let mut events = Vec::new();
        let mut t = 0;
        let mut native_sum = 0;
        for (dt, up) in &native {
            t += dt;
            let s = if *up { Step::Up } else { Step::Down };
            native_sum += s.sign();
            events.push((t, Event::Native(s)));
        }
        for (tt, n) in &targets {
            events.push((*tt, Event::Target(*n)));
        }
        events.sort_by_key(|e| e.0); // stable: same-time events keep their order
        let final_target = targets.iter().max_by_key(|(tt, _)| *tt)
            .map(|(tt, _)| {
                // the last target applied is the last one in sorted order at the max time
                events.iter().rev().find_map(|(t2, e)| match e { Event::Target(n) if t2 == tt => Some(*n), _ => None }).unwrap()
            })
            .unwrap_or(0);
        let mut sched = EdgeScheduler::new(SchedulerConfig {
            min_edge_gap_ns: GAP_NS,
            max_inject_rate_hz: rate_khz * 1e3,
        }).unwrap();
        let out = simulate(&mut sched, &events);
        check_stream(&sched, &out, native_sum, final_target)?;
        prop_assert_eq!(sched.injected_total(), final_target);
        prop_assert_eq!(sched.native_backlog(), 0);
    }

    /// Native latency stays below one gap while the encoder respects the gap.
    #[test]
    fn native_latency_below_one_gap(
        native in prop::collection::vec(GAP_NS..3 * GAP_NS, 1..200),
        target in -100i64..100,
    ) {
        let mut events = vec![(0, Event::Target(target))];
        let mut t = 0;
        for dt in &native { t += dt; events.push((t, Event::Native(Step::Up))); }
        let arrivals: Vec<u64> = events.iter().filter(|e| matches!(e.1, Event::Native(_))).map(|e| e.0).collect();
        let mut sched = EdgeScheduler::new(SchedulerConfig { min_edge_gap_ns: GAP_NS, max_inject_rate_hz: 2.5e6 }).unwrap();
        let out = simulate(&mut sched, &events);
        let emitted: Vec<u64> = out.iter().filter(|t| t.source == Source::Native).map(|t| t.t_ns).collect();
        prop_assert_eq!(emitted.len(), arrivals.len());
        for (a, e) in arrivals.iter().zip(&emitted) {
            prop_assert!(*e >= *a && *e - *a < GAP_NS, "native edge delayed {} ns", *e - *a);
        }
    }
}

#[test]
fn correction_um_to_edges_end_to_end() {
    // 0.5 µm per count; a +3.2 µm correction (slide must move +) injects round(−6.4) = −6 counts.
    let mut q = CountQuantizer::new(0.5, 1).unwrap();
    let mut sched = EdgeScheduler::new(SchedulerConfig {
        min_edge_gap_ns: GAP_NS,
        max_inject_rate_hz: 1e5,
    })
    .unwrap();
    sched.add_inject_counts(q.delta_counts(3.2).unwrap());
    let out = simulate(&mut sched, &[]);
    assert_eq!(out.len(), 6);
    assert!(
        out.iter()
            .all(|t| t.step == Step::Down && t.source == Source::Injected)
    );
    assert!((q.residual_um(3.2) - 0.2).abs() < 1e-12);
}

#[test]
fn drives_output_pins_one_line_per_edge() {
    // Two up-counts then one down-count from phase 0: A↑ (1,0), B↑ (1,1), B↓ (1,0).
    let a = PinMock::new(&[PinTx::set(State::Low), PinTx::set(State::High)]);
    let b = PinMock::new(&[
        PinTx::set(State::Low),
        PinTx::set(State::High),
        PinTx::set(State::Low),
    ]);
    let mut sched = EdgeScheduler::new(SchedulerConfig {
        min_edge_gap_ns: GAP_NS,
        max_inject_rate_hz: 1e6,
    })
    .unwrap();
    let mut pins = QuadraturePins::new(a, b, sched.levels()).unwrap();
    let out = simulate(
        &mut sched,
        &[
            (0, Event::Native(Step::Up)),
            (1_000, Event::Native(Step::Up)),
            (2_000, Event::Native(Step::Down)),
        ],
    );
    for tr in &out {
        pins.apply(tr).unwrap();
    }
    assert_eq!(pins.levels(), levels_of_phase(1));
    let (mut a, mut b) = pins.release();
    a.done();
    b.done();
}
