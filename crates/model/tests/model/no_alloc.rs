//! No allocation per evaluation (issue 39 point 1): `evaluate`, `evaluate_first_order` and
//! `evaluate_batch` of vmc-3axis allocate nothing once the state and breakdown exist, counted by the
//! binary's global allocator wrapper (per thread: the harness runs other tests on other threads). The floor
//! (`benches/floor_vmc`) is held to the same.

use crate::counting_alloc::allocs;
use crate::floor_vmc;

#[test]
fn evaluations_allocate_nothing() {
    let m = floor_vmc::vmc_model();
    let floor = floor_vmc::Floor::new(&m);
    let pts = floor_vmc::bench_inputs(&m, 4096);
    let (mut state, mut fstate) = (m.new_state(), floor.new_state());
    let mut out = m.new_breakdown();
    // One evaluation each first: the lag state starts at the first reading.
    m.evaluate(&pts[0], &mut state, &mut out);
    floor.run(&pts[0], &mut fstate, &mut out);

    let mut batch_state = m.new_state();
    let before = allocs();
    for p in &pts[1..] {
        m.evaluate(p, &mut state, &mut out);
        m.evaluate_first_order(p, &mut state, &mut out);
    }
    let mut sum = 0.0;
    m.evaluate_batch(&pts, &mut batch_state, &mut out, |_, o| {
        sum += o.total_um[0];
    });
    assert_eq!(
        allocs(),
        before,
        "evaluate, evaluate_first_order, evaluate_batch"
    );

    let before = allocs();
    for p in &pts[1..] {
        floor.run(p, &mut fstate, &mut out);
        sum += out.total_um[0];
    }
    assert_eq!(allocs(), before, "the floor");
    assert!(sum.is_finite());
}
