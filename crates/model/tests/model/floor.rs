//! The floor (`benches/floor_vmc`, the hand-specialised evaluator of vmc-3axis the `floor` bench
//! measures `MachineModel::evaluate` against) gives `evaluate`'s breakdown: the total and every one
//! of the 32 terms within 1e-12 µm, and the same clamp and travel flags, on a stream of points over
//! the work zone and beyond it, in both directions and unknown direction, with warm sensors whose
//! lags step by 1 ms with float jitter and sometimes by a gap, both tools and explicit tool lengths,
//! and varying loads.

use crate::floor_vmc;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const TOL_UM: f64 = 1e-12;

#[test]
fn the_floor_gives_the_models_breakdown() {
    let m = floor_vmc::vmc_model();
    let floor = floor_vmc::Floor::new(&m);
    let (mut state, mut fstate) = (m.new_state(), floor.new_state());
    let (mut want, mut got) = (m.new_breakdown(), m.new_breakdown());
    let mut rng = ChaCha8Rng::seed_from_u64(39);
    let mut input = m.new_input();
    let travel = [800.0, 500.0, 500.0];
    let mut worst = 0.0f64;
    let mut clamped = 0;
    for i in 0..20_000 {
        for (a, hi) in travel.iter().enumerate() {
            input.pos_mm[a] = match rng.random_range(0..20) {
                0 => -rng.random_range(0.0..30.0),
                1 => hi + rng.random_range(0.0..30.0),
                2 => [0.0, 250.0, *hi, 8.0808, 5.0505 * 3.0][rng.random_range(0..5)],
                _ => rng.random_range(0.0..*hi),
            };
            input.dir[a] = [-1, 0, 1, -4, 3][rng.random_range(0..5)];
        }
        input.t_s += match rng.random_range(0..50) {
            0 => rng.random_range(0.5..60.0),
            _ => 0.001 * (1.0 + rng.random_range(-1e-9..1e-9)),
        };
        for (k, t) in input.temps_c.iter_mut().enumerate() {
            *t = 20.0 + 0.3 * f64::from(u8::try_from(k).expect("16")) + rng.random_range(-2.0..8.0);
        }
        for f in &mut input.forces_n {
            *f = rng.random_range(-400.0..400.0);
        }
        for s in &mut input.strains_ue {
            *s = rng.random_range(0.0..150.0);
        }
        input.tool = rng.random_range(0..2);
        input.tool_mm = rng.random_bool(0.2).then(|| rng.random_range(50.0..250.0));

        m.evaluate(&input, &mut state, &mut want);
        floor.run(&input, &mut fstate, &mut got);
        assert_eq!(got.flags, want.flags, "point {i}: {input:?}");
        clamped += usize::from(want.flags.clamped.iter().any(|&c| c));
        let pairs = got.terms_um.iter().zip(&want.terms_um);
        for (k, (g, w)) in std::iter::once((&got.total_um, &want.total_um))
            .chain(pairs)
            .enumerate()
        {
            for c in 0..3 {
                let d = (g[c] - w[c]).abs();
                worst = worst.max(d);
                assert!(
                    d <= TOL_UM,
                    "point {i}, {} {c}: {} vs {} ({input:?})",
                    k,
                    g[c],
                    w[c]
                );
            }
        }
    }
    assert!(clamped > 1000, "the stream visits the ends: {clamped}");
    println!("largest difference {worst:e} µm");
}
