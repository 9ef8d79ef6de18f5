//! The fast evaluation plan (`crates/model/src/plan.rs`, behind `evaluate`, `evaluate_first_order` and
//! `evaluate_batch`) gives the straightforward evaluator's results (`evaluate_reference`,
//! `crates/model/src/engine.rs`): every term, the total and every flag, and the same lag states, within
//! 1e-9 µm, on random input streams that visit what the plan treats specially — direction flips
//! and unknown direction, table nodes, ends and positions beyond them (clamp + flag), lag steps
//! with jitter, gaps and time going backwards, missing and non-finite sensors, forces and strains,
//! tool changes, and invalid positions.

use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use retrocomp_model::{
    ErrorBreakdown, ErrorFunction, Interpolation, MachineModel, ModelInput, ModelState, Table,
};

const TOL_UM: f64 = 1e-9;

fn example(name: &str) -> MachineModel {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("deploy/examples")
        .join(name);
    MachineModel::from_toml_path(&p).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// Positions worth visiting on each machine axis: the table nodes (ends included) of its
/// components, and its travel.
fn interesting_positions(m: &MachineModel) -> [Vec<f64>; 3] {
    let mut out: [Vec<f64>; 3] = Default::default();
    for c in &m.spec().components {
        if let ErrorFunction::Table(t) = &c.function {
            out[c.id.axis.index()].extend(&t.positions_mm);
        }
    }
    for a in &m.spec().axes {
        if let Some((lo, hi)) = a.travel_mm {
            out[a.axis.index()].extend([lo, hi]);
        }
    }
    for v in &mut out {
        if v.is_empty() {
            v.extend([0.0, 100.0]);
        }
    }
    out
}

/// The next input of a random stream: mostly small moves, sometimes a jump to a node, a table end
/// or beyond it; a time step that is usually 1 ms with float jitter.
fn next_input(
    m: &MachineModel,
    rng: &mut ChaCha8Rng,
    nodes: &[Vec<f64>; 3],
    prev: &ModelInput,
) -> ModelInput {
    let mut p = prev.clone();
    for (a, node) in nodes.iter().enumerate() {
        let lo = node.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = node.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let r: f64 = rng.random();
        p.pos_mm[a] = if r < 0.6 {
            prev.pos_mm[a] + rng.random_range(-5.0..5.0)
        } else if r < 0.75 {
            node[rng.random_range(0..node.len())]
        } else if r < 0.85 {
            // Beyond either end: clamped and flagged.
            if rng.random_bool(0.5) {
                lo - rng.random_range(0.0..50.0)
            } else {
                hi + rng.random_range(0.0..50.0)
            }
        } else {
            rng.random_range(lo..=hi)
        };
        if rng.random_bool(0.3) {
            p.dir[a] = [-1, 0, 1, -3, 7][rng.random_range(0..5)];
        }
    }
    p.t_s += match rng.random_range(0..20) {
        0 => rng.random_range(0.0..30.0), // a gap: the lag takes a large step
        1 => -rng.random_range(0.0..0.01), // backwards: states held, flagged
        2 => 0.0,
        _ => 0.001,
    };
    for (k, t) in p.temps_c.iter_mut().enumerate() {
        *t = if rng.random_range(0..200) == 0 {
            f64::NAN
        } else if t.is_finite() {
            *t + rng.random_range(-0.05..0.06)
        } else {
            20.0 + 0.2 * k as f64
        };
    }
    for f in p.forces_n.iter_mut().chain(p.strains_ue.iter_mut()) {
        *f = if rng.random_range(0..300) == 0 {
            f64::INFINITY
        } else {
            rng.random_range(-300.0..600.0)
        };
    }
    // Occasionally a short channel vector (missing inputs), another tool, a tool length, or a
    // non-finite position (everything zero, flagged).
    if rng.random_range(0..400) == 0 {
        p.temps_c.pop();
    } else if p.temps_c.len() < m.temperature_sensors().len() {
        p.temps_c.push(21.0);
    }
    p.tool = [0, 0, 0, 1, 5][rng.random_range(0..5)];
    p.tool_mm = rng.random_bool(0.2).then(|| rng.random_range(50.0..200.0));
    if rng.random_range(0..500) == 0 {
        let mut bad = p.clone();
        bad.pos_mm[rng.random_range(0..3)] = f64::NAN;
        return bad;
    }
    p
}

fn assert_same(fast: &ErrorBreakdown, reference: &ErrorBreakdown, what: &str) {
    assert_eq!(fast.flags, reference.flags, "{what}: flags");
    assert_eq!(fast.terms_um.len(), reference.terms_um.len(), "{what}");
    let worst = (0..3)
        .map(|i| (fast.total_um[i] - reference.total_um[i]).abs())
        .fold(0.0, f64::max);
    assert!(
        worst <= TOL_UM,
        "{what}: total {:?} vs {:?}",
        fast.total_um,
        reference.total_um
    );
    for (k, (a, b)) in fast.terms_um.iter().zip(&reference.terms_um).enumerate() {
        for i in 0..3 {
            assert!(
                (a[i] - b[i]).abs() <= TOL_UM,
                "{what}: term {k}: {a:?} vs {b:?}"
            );
        }
    }
}

fn assert_same_state(fast: &ModelState, reference: &ModelState, what: &str) {
    let (f, r) = (&fast.thermal, &reference.thermal);
    assert_eq!(f.last_t_s, r.last_t_s, "{what}");
    assert_eq!(f.len(), r.len(), "{what}: sensors");
    for i in 0..f.len() {
        match (f.lagged_c(i), r.lagged_c(i)) {
            (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-9, "{what}: lag {a} vs {b}"),
            (a, b) => assert_eq!(a, b, "{what}: lag started"),
        }
    }
    for (a, b) in f.delta_c.iter().zip(&r.delta_c) {
        assert!((a - b).abs() <= 1e-9, "{what}: ΔT {a} vs {b}");
    }
}

/// Runs `n` points of one random stream through the plan and the reference, exact and first order
/// (four states), and returns how many points each flag was raised on (to prove the stream visited
/// them).
fn compare(m: &MachineModel, n: usize, seed: u64) -> [usize; 5] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let nodes = interesting_positions(m);
    let mut states: Vec<ModelState> = (0..4).map(|_| m.new_state()).collect();
    let mut outs: Vec<ErrorBreakdown> = (0..4).map(|_| m.new_breakdown()).collect();
    // The plan must not depend on the buffer having been sized for it.
    outs[0] = ErrorBreakdown::default();
    let mut input = m.new_input();
    input.t_s = 100.0;
    let mut seen = [0usize; 5];
    for i in 0..n {
        input = next_input(m, &mut rng, &nodes, &input);
        let [s0, s1, s2, s3] = &mut states[..] else {
            unreachable!()
        };
        let [o0, o1, o2, o3] = &mut outs[..] else {
            unreachable!()
        };
        m.evaluate(&input, s0, o0);
        m.evaluate_reference(&input, s1, o1, true);
        m.evaluate_first_order(&input, s2, o2);
        m.evaluate_reference(&input, s3, o3, false);
        let what = format!("{} point {i} {input:?}", m.name());
        assert_same(o0, o1, &format!("exact, {what}"));
        assert_same(o2, o3, &format!("first order, {what}"));
        assert_same_state(s0, s1, &what);
        assert_same_state(s2, s3, &what);
        let f = o1.flags;
        for (c, on) in seen.iter_mut().zip([
            f.clamped.iter().any(|&b| b),
            f.outside_travel.iter().any(|&b| b),
            f.invalid_input,
            f.missing_input,
            f.time_backwards,
        ]) {
            *c += usize::from(on);
        }
    }
    seen
}

#[test]
fn plan_equals_reference_on_vmc_3axis_random_stream() {
    let m = example("vmc-3axis.toml");
    let seen = compare(&m, 12_000, 1);
    // The stream must have exercised every special case, each on a good share of the points.
    for (name, count) in [
        "clamped",
        "outside travel",
        "invalid",
        "missing",
        "backwards",
    ]
    .iter()
    .zip(seen)
    {
        assert!(count >= 10, "{name} raised on only {count} points");
    }
}

#[test]
fn plan_equals_reference_on_the_other_examples() {
    for name in [
        "excello-921.toml",
        "studer-s36.toml",
        "studer-s36-positional.toml",
    ] {
        compare(&example(name), 3_000, 2);
    }
}

/// The plan groups linear tables per axis even when they are not adjacent in the file, and leaves
/// C¹ tables to the general path: a reordered vmc with two C¹ components still matches.
#[test]
fn plan_equals_reference_with_reordered_and_c1_components() {
    let mut spec = example("vmc-3axis.toml").spec().clone();
    spec.components.reverse();
    spec.components.swap(0, 9);
    for k in [2, 11] {
        if let ErrorFunction::Table(t) = &spec.components[k].function {
            spec.components[k].function = ErrorFunction::Table(Table::new(
                t.positions_mm.clone(),
                t.forward.clone(),
                t.reverse.clone(),
                Interpolation::C1,
            ));
        }
    }
    let m = MachineModel::from_spec(spec);
    compare(&m, 3_000, 3);
}

#[test]
fn batch_equals_one_by_one() {
    let m = example("vmc-3axis.toml");
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let nodes = interesting_positions(&m);
    let mut inputs = vec![m.new_input()];
    for _ in 0..500 {
        let next = next_input(&m, &mut rng, &nodes, &inputs[inputs.len() - 1]);
        inputs.push(next);
    }
    let (mut s1, mut o1) = (m.new_state(), m.new_breakdown());
    let mut got = Vec::new();
    m.evaluate_batch(
        &inputs,
        &mut m.new_state(),
        &mut m.new_breakdown(),
        |i, b| got.push((i, b.clone())),
    );
    assert_eq!(got.len(), inputs.len());
    for (input, (i, b)) in inputs.iter().zip(&got) {
        m.evaluate(input, &mut s1, &mut o1);
        assert_eq!(&o1, b, "point {i}");
    }
}
