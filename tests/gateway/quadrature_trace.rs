//! The quadrature edge trace's real-time side: the injector thread's loop (`run_injector_traced`),
//! tracing every level it writes, makes no heap allocation (counted by a global allocator wrapper
//! on its thread), and what it traced decodes to exactly the native + injected count it was fed,
//! with every edge at least the gap apart and injected ones at least the rate interval apart.
//! Units: counts (A/B edges), ns.

use std::time::Instant;

use retrocomp_gateway::sinks::quadrature::SimulatedPin;
use retrocomp_gateway::sinks::quadrature::trace::{HEADER, TraceConfig, TraceWriter};
use retrocomp_gateway::sinks::quadrature::{
    EdgeScheduler, Feed, Injector, QuadDecoder, SchedulerConfig, Step, run_injector_traced,
};

use crate::counting_alloc::allocs;

const GAP_NS: u64 = 400;
const RATE_HZ: f64 = 200_000.0;
const INTERVAL_NS: u64 = 5_000;

#[test]
fn the_traced_injector_loop_allocates_nothing_and_its_trace_decodes_to_its_count() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = TraceConfig {
        path: dir.path().join("trace.csv"),
        max_bytes: 1_000_000,
        buffer_edges: 4_096,
    };
    let mut writer = TraceWriter::start(&cfg, vec!["x".into()]).unwrap();
    let sched = EdgeScheduler::new(SchedulerConfig {
        min_edge_gap_ns: GAP_NS,
        max_inject_rate_hz: RATE_HZ,
    })
    .unwrap()
    .starting_at(6); // phase 2: the lines start high/high
    let inj = Injector::new(sched, SimulatedPin::default(), SimulatedPin::default()).unwrap();
    // The feed is filled (its sends allocate) before the loop runs on this thread.
    let (tx, rx) = std::sync::mpsc::channel();
    tx.send(Feed::Inject(150)).unwrap();
    for _ in 0..40 {
        tx.send(Feed::Native(Step::Down)).unwrap();
    }
    tx.send(Feed::Inject(-20)).unwrap();
    drop(tx);

    let trace = writer.for_axis(0).unwrap();
    let start = Instant::now();
    let before = allocs();
    let inj = run_injector_traced(inj, rx, |_| {}, start, Some(trace)).unwrap();
    let allocated = allocs() - before;
    assert_eq!(allocated, 0, "heap allocations in the traced injector loop");
    let c = inj.counts();
    assert_eq!((c.injected, c.owed), (130, 0));

    writer.finish();
    assert_eq!(writer.dropped(), 0);
    assert!(!writer.failed());
    let text = std::fs::read_to_string(&cfg.path).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(HEADER));
    let rows: Vec<(u64, bool, bool, String)> = lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f[1], "x", "{l}");
            (f[0].parse().unwrap(), f[2] == "1", f[3] == "1", f[4].into())
        })
        .collect();
    assert_eq!(
        rows.len() as u64,
        1 + c.edges,
        "a start row and one per edge"
    );
    let (_, a0, b0, ref first) = rows[0];
    assert_eq!((first.as_str(), a0, b0), ("start", true, true));
    let mut dec = QuadDecoder::new(a0, b0);
    for (t, a, b, _) in &rows[1..] {
        dec.update(*a, *b)
            .unwrap_or_else(|e| panic!("not one Gray-code step at {t} ns: {e}"));
    }
    assert_eq!(dec.count(), 130 - 40, "the trace counts native + injected");
    for w in rows[1..].windows(2) {
        assert!(
            w[1].0 >= w[0].0 + GAP_NS,
            "edges at {} and {} ns",
            w[0].0,
            w[1].0
        );
    }
    let injected: Vec<u64> = rows
        .iter()
        .filter(|r| r.3 == "injected")
        .map(|r| r.0)
        .collect();
    // The loop takes everything waiting before its first edge: the deltas net to 130 edges.
    assert_eq!(injected.len(), 130, "every injected edge traced");
    assert_eq!(c.edges, 130 + 40);
    for w in injected.windows(2) {
        assert!(
            w[1] >= w[0] + INTERVAL_NS,
            "injected at {} and {} ns",
            w[0],
            w[1]
        );
    }
}
