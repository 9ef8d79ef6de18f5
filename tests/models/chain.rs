//! The generic chain against the seeds' closed forms, and exact (4×4 HTM) against first order.
//!
//! * Graves et al. (Y-12 CRADA, Excello 921 T-base lathe), eqs. 3-25/3-26 (graves.md §1):
//!   ΔPx = δx(x) − δx(z) + Zt·εy(x) + (z + Z1 − Zt)·εy(z) − β·z
//!   ΔPz = δz(x) − δz(z) − Xt·εy(x) + (x − X1 + X2 + Xt)·εy(z) − α·x
//!   Graves states the Z slide's errors as carriage motions in the base frame with z the carriage
//!   coordinate (spindle moves +z); retrocomp states them relative to the workpiece with the machine
//!   coordinate z_m = −z (the tool moves −z relative to the spindle). Mapping: EXZ(z_m) = −δx(−z_m),
//!   EZZ = −δz, EBZ = −εy, EB0Z on z = β, EB0Z on x = −α. Offsets: Z carriage (X1, 0, Z1), X carriage
//!   (X2, 0, 0), tool (Xt, 0, Zt).
//! * Spaan (1995) eqs. 2.2–2.9: E = Σ_i [e_i(q_i) + ε_i(q_i) × p_i], p_i = l + Σ_{u ≥ i} q_u ê_u.
//! * Proptest: |exact − first order| ≤ C·ε² for random small errors on random chains.

use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use retrocomp_model::{Interpolation, MachineModel, ModelInput, Table};

fn arr(v: &[f64]) -> String {
    format!(
        "[{}]",
        v.iter()
            .map(|x| format!("{x:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

fn table_toml(name: &str, pos: &[f64], fwd: &[f64], unit: &str) -> String {
    format!(
        "\n[[components]]\nname = \"{name}\"\npositions_mm = {}\nforward_{unit} = {}\n",
        arr(pos),
        arr(fwd)
    )
}

fn random_table(rng: &mut ChaCha8Rng, pos: &[f64], scale: f64) -> Vec<f64> {
    pos.iter()
        .map(|_| rng.random_range(-scale..scale))
        .collect()
}

#[test]
fn graves_eqs_3_25_and_3_26_from_the_generic_chain() {
    let mut rng = ChaCha8Rng::seed_from_u64(1995);
    for case in 0..20 {
        // Graves §4: X 22 in stroke in 1 in steps, Z 12 in in 0.5 in steps; constants per machine.
        let xs: Vec<f64> = (0..=22).map(|i| f64::from(i) * 25.4).collect();
        let zs: Vec<f64> = (0..=24).map(|i| f64::from(i) * 12.7).collect();
        let (x1, z1, x2) = (
            rng.random_range(-300.0..300.0),
            rng.random_range(-600.0..-100.0),
            rng.random_range(-300.0..300.0),
        );
        let (xt, zt) = (
            rng.random_range(10.0..200.0),
            rng.random_range(-200.0..-10.0),
        );
        let (alpha, beta) = (
            rng.random_range(-100.0..100.0),
            rng.random_range(-100.0..100.0),
        ); // µrad
        let dx_x = random_table(&mut rng, &xs, 25.0); // µm, ranges of graves.md §5
        let dz_x = random_table(&mut rng, &xs, 5.0);
        let ey_x = random_table(&mut rng, &xs, 15.0); // µrad (±3″)
        let dx_z = random_table(&mut rng, &zs, 3.0);
        let dz_z = random_table(&mut rng, &zs, 4.0);
        let ey_z = random_table(&mut rng, &zs, 10.0);

        // retrocomp model: Z tables re-indexed on z_m = −z and negated (see the module comment).
        let zm: Vec<f64> = zs.iter().rev().map(|z| -z).collect();
        let flip = |v: &[f64]| v.iter().rev().map(|x| -x).collect::<Vec<f64>>();
        let mut text = format!(
            "schema = 1\n[machine]\nname = \"excello-test\"\nchain = \"Z F X\"\ntool_axis = \"+x\"\n\
             [axes.z]\noffset_mm = [{x1:?}, 0.0, {z1:?}]\n[axes.x]\noffset_mm = [{x2:?}, 0.0, 0.0]\n\
             [[tools]]\nname = \"T\"\noffset_mm = [{xt:?}, 0.0, {zt:?}]\n\
             [[squareness]]\nname = \"EB0Z\"\non_axis = \"z\"\nvalue_urad = {beta:?}\n\
             [[squareness]]\nname = \"EB0Z\"\non_axis = \"x\"\nvalue_urad = {:?}\n",
            -alpha
        );
        text += &table_toml("EXX", &xs, &dx_x, "um");
        text += &table_toml("EZX", &xs, &dz_x, "um");
        text += &table_toml("EBX", &xs, &ey_x, "urad");
        text += &table_toml("EXZ", &zm, &flip(&dx_z), "um");
        text += &table_toml("EZZ", &zm, &flip(&dz_z), "um");
        text += &table_toml("EBZ", &zm, &flip(&ey_z), "urad");
        let m = MachineModel::from_toml_str(&text, "graves").unwrap_or_else(|e| panic!("{e}"));

        // Graves' own evaluation: linear interpolation in each table, then eqs. 3-25/3-26.
        let t = |pos: &[f64], v: &[f64]| {
            Table::new(pos.to_vec(), v.to_vec(), v.to_vec(), Interpolation::Linear)
        };
        let (tdx_x, tdz_x, tey_x, tdx_z, tdz_z, tey_z) = (
            t(&xs, &dx_x),
            t(&xs, &dz_x),
            t(&xs, &ey_x),
            t(&zs, &dx_z),
            t(&zs, &dz_z),
            t(&zs, &ey_z),
        );
        for _ in 0..50 {
            let x = rng.random_range(0.0..22.0 * 25.4);
            let z = rng.random_range(0.0..12.0 * 25.4);
            let (ex, ez_x, eyx) = (
                tdx_x.eval(x, 1).0,
                tdz_x.eval(x, 1).0,
                tey_x.eval(x, 1).0 * 1e-6,
            );
            let (dxz, dzz, eyz) = (
                tdx_z.eval(z, 1).0,
                tdz_z.eval(z, 1).0,
                tey_z.eval(z, 1).0 * 1e-6,
            );
            // mm × rad → mm; × 1e3 → µm. α, β in µrad × mm × 1e-3 → µm.
            let dpx = ex - dxz + zt * eyx * 1e3 + (z + z1 - zt) * eyz * 1e3 - beta * z * 1e-3;
            let dpz =
                ez_x - dzz - xt * eyx * 1e3 + (x - x1 + x2 + xt) * eyz * 1e3 - alpha * x * 1e-3;

            let input = ModelInput {
                pos_mm: [x, 0.0, -z],
                dir: [1, 0, 1],
                ..m.new_input()
            };
            let (mut s, mut out) = (m.new_state(), m.new_breakdown());
            m.evaluate_first_order(&input, &mut s, &mut out);
            assert!(
                (out.total_um[0] - dpx).abs() < 1e-9,
                "case {case}: ΔPx {} vs eq 3-25 {dpx}",
                out.total_um[0]
            );
            assert!(
                (out.total_um[2] - dpz).abs() < 1e-9,
                "case {case}: ΔPz {} vs eq 3-26 {dpz}",
                out.total_um[2]
            );
            m.evaluate(&input, &mut s, &mut out);
            // Exact differs only at second order (angles ≤ 100 µrad, arms ≤ 1 m → ≤ 0.01 µm).
            assert!((out.total_um[0] - dpx).abs() < 0.02 && (out.total_um[2] - dpz).abs() < 0.02);
        }
    }
}

/// Spaan's propagation with all frames at machine zero, for chain X-Y-Z (table → tool).
fn spaan(e: &[[f64; 3]; 3], eps_urad: &[[f64; 3]; 3], q: [f64; 3], l: [f64; 3]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for i in 0..3 {
        let mut p = l;
        for (u, pu) in p.iter_mut().enumerate() {
            if u >= i {
                *pu += q[u];
            }
        }
        let r = eps_urad[i].map(|v| v * 1e-3);
        let c = [
            r[1] * p[2] - r[2] * p[1],
            r[2] * p[0] - r[0] * p[2],
            r[0] * p[1] - r[1] * p[0],
        ];
        for k in 0..3 {
            out[k] += e[i][k] + c[k];
        }
    }
    out
}

#[test]
fn spaan_first_order_form_equals_the_generic_chain() {
    let mut rng = ChaCha8Rng::seed_from_u64(700);
    let names_t = [
        ["EXX", "EYX", "EZX"],
        ["EXY", "EYY", "EZY"],
        ["EXZ", "EYZ", "EZZ"],
    ];
    let names_r = [
        ["EAX", "EBX", "ECX"],
        ["EAY", "EBY", "ECY"],
        ["EAZ", "EBZ", "ECZ"],
    ];
    for case in 0..30 {
        // Random linear error functions e(q) = a + b·q so the convention shift below stays exact.
        let coef = |rng: &mut ChaCha8Rng, s: f64| {
            [rng.random_range(-s..s), rng.random_range(-s..s) * 1e-2]
        };
        let et: Vec<Vec<[f64; 2]>> = (0..3)
            .map(|_| (0..3).map(|_| coef(&mut rng, 20.0)).collect())
            .collect();
        let er: Vec<Vec<[f64; 2]>> = (0..3)
            .map(|_| (0..3).map(|_| coef(&mut rng, 10.0)).collect())
            .collect();
        let l = [
            rng.random_range(-50.0..50.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(-250.0..-50.0),
        ];
        let q = [
            rng.random_range(0.0..700.0),
            rng.random_range(0.0..500.0),
            rng.random_range(0.0..600.0),
        ];
        let at = |c: [f64; 2], x: f64| c[0] + c[1] * x;
        let mut e = [[0.0; 3]; 3];
        let mut r = [[0.0; 3]; 3];
        for i in 0..3 {
            for k in 0..3 {
                e[i][k] = at(et[i][k], q[i]);
                r[i][k] = at(er[i][k], q[i]);
            }
        }
        let want = spaan(&e, &r, q, l);
        let header = |chain: &str| {
            format!(
                "schema = 1\n[machine]\nname = \"spaan\"\nchain = \"{chain}\"\n[[tools]]\nname = \"l\"\noffset_mm = {}\n",
                arr(&l)
            )
        };

        // (1) Spaan's single chain is retrocomp's all-workpiece-side chain "X Y Z F": same functions.
        // (2) His Maho 700S has the table on X and Y, Z on the column: "X F Y Z". A tool-side carriage
        //     rotates about its own reference point, so his e_i (machine zero, Abbe absorbed, Fig 2.3)
        //     is retrocomp's δ_i − ε_i × q_i ê_i, i.e. δ_i = e_i + q_i·(ε_i × ê_i).
        for (chain, shifted) in [
            ("X Y Z F", [false, false, false]),
            ("X F Y Z", [false, true, true]),
        ] {
            let mut text = header(chain);
            for i in 0..3 {
                for k in 0..3 {
                    let mut c = vec![et[i][k][0], et[i][k][1], 0.0];
                    if shifted[i] {
                        // (ε × ê_i)_k = ε_{k+1}·ê_{i,k+2} − ε_{k+2}·ê_{i,k+1}
                        let mut unit = [0.0; 3];
                        unit[i] = 1.0;
                        let cr = |m: usize, n: usize| (er[i][m], unit[n]);
                        let (a1, b1) = cr((k + 1) % 3, (k + 2) % 3);
                        let (a2, b2) = cr((k + 2) % 3, (k + 1) % 3);
                        // q·(a1(q)·b1 − a2(q)·b2)·1e-3, a(q) = c0 + c1 q → degree 2 in q.
                        c[1] += (a1[0] * b1 - a2[0] * b2) * 1e-3;
                        c[2] += (a1[1] * b1 - a2[1] * b2) * 1e-3;
                    }
                    text += &format!(
                        "\n[[components]]\nname = \"{}\"\ncoefficients_um = {}\n",
                        names_t[i][k],
                        arr(&c)
                    );
                    text += &format!(
                        "\n[[components]]\nname = \"{}\"\ncoefficients_urad = {}\n",
                        names_r[i][k],
                        arr(&er[i][k])
                    );
                }
            }
            let m = MachineModel::from_toml_str(&text, "spaan").unwrap_or_else(|e| panic!("{e}"));
            let input = ModelInput {
                pos_mm: q,
                ..m.new_input()
            };
            let (mut s, mut out) = (m.new_state(), m.new_breakdown());
            m.evaluate_first_order(&input, &mut s, &mut out);
            for k in 0..3 {
                assert!(
                    (out.total_um[k] - want[k]).abs() < 1e-9,
                    "case {case} {chain}: {:?} vs Spaan {want:?}",
                    out.total_um
                );
            }
        }
    }
}

/// A random model with every component constant: translations `s·1000·u` µm, rotations `s·1e6·u`
/// µrad (u ∈ [−1, 1]), plus squareness `s·1e6·u` µrad, on a random chain with random offsets.
fn random_model(seed: u64, s: f64) -> (MachineModel, [f64; 3]) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let chains = [
        "X F Y Z", "F X Y Z", "X Y F Z", "Y X Z F", "Z F X", "Z X", "F Y X", "Z Y F X",
    ];
    let chain = chains[rng.random_range(0..chains.len())];
    let axes: Vec<char> = chain.chars().filter(|c| "XYZ".contains(*c)).collect();
    let mut r = |a: f64| rng.random_range(-a..a);
    let mut text = format!(
        "schema = 1\n[machine]\nname = \"prop\"\nchain = \"{chain}\"\n[[tools]]\nname = \"t\"\noffset_mm = [{:?}, {:?}, {:?}]\n",
        r(200.0),
        r(200.0),
        r(200.0)
    );
    for a in &axes {
        text += &format!(
            "[axes.{}]\noffset_mm = [{:?}, {:?}, {:?}]\n",
            a.to_ascii_lowercase(),
            r(300.0),
            r(300.0),
            r(300.0)
        );
    }
    for a in &axes {
        for e in ['X', 'Y', 'Z'] {
            text += &format!(
                "[[components]]\nname = \"E{e}{a}\"\ncoefficients_um = [{:?}]\n",
                s * 1000.0 * r(1.0)
            );
        }
        for e in ['A', 'B', 'C'] {
            text += &format!(
                "[[components]]\nname = \"E{e}{a}\"\ncoefficients_urad = [{:?}]\n",
                s * 1e6 * r(1.0)
            );
        }
    }
    for (name, p, q2) in [("EC0Y", 'X', 'Y'), ("EB0Z", 'X', 'Z'), ("EA0Z", 'Y', 'Z')] {
        if axes.contains(&p) && axes.contains(&q2) {
            text += &format!(
                "[[squareness]]\nname = \"{name}\"\nvalue_urad = {:?}\n",
                s * 1e6 * r(1.0)
            );
        }
    }
    let pos = [r(1000.0), r(1000.0), r(1000.0)];
    (
        MachineModel::from_toml_str(&text, "prop").unwrap_or_else(|e| panic!("{e}\n{text}")),
        pos,
    )
}

fn both(m: &MachineModel, pos: [f64; 3]) -> ([f64; 3], [f64; 3], f64) {
    let input = ModelInput {
        pos_mm: pos,
        ..m.new_input()
    };
    let (mut s, mut a, mut b) = (m.new_state(), m.new_breakdown(), m.new_breakdown());
    m.evaluate(&input, &mut s, &mut a);
    m.evaluate_first_order(&input, &mut s, &mut b);
    let sum: f64 = a.terms_um.iter().map(|t| t[0] + t[1] + t[2]).sum();
    assert!(
        (sum - a.total_um.iter().sum::<f64>()).abs() < 1e-9,
        "terms add up to the total"
    );
    (
        a.total_um,
        b.total_um,
        a.terms_um
            .last()
            .map_or(0.0, |h| h.iter().map(|x| x.abs()).fold(0.0, f64::max)),
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]
    #[test]
    fn exact_and_first_order_agree_to_second_order(seed in any::<u64>(), log_s in -6.0f64..-3.0) {
        // ε = s rad for angles and s·1 m for translations; arms ≤ ~3 m. Second-order terms are
        // ε·ε·arm ≈ s²·3e6 µm; C = 60 covers the ~20 pairwise products of 21 terms.
        let s = 10f64.powf(log_s);
        let (m, pos) = random_model(seed, s);
        let (exact, first, higher) = both(&m, pos);
        let bound = 60.0 * s * s * 1e6 * 3.0;
        for k in 0..3 {
            prop_assert!((exact[k] - first[k]).abs() <= bound, "s {} axis {}: |exact − first| = {} > {}", s, k, (exact[k] - first[k]).abs(), bound);
        }
        prop_assert!(higher <= bound);
        // …and the difference really is second order: halving ε quarters it (when it is not
        // already at rounding level).
        let (m2, _) = random_model(seed, s / 2.0);
        let (e2, f2, _) = both(&m2, pos);
        let d1: f64 = (0..3).map(|k| (exact[k] - first[k]).abs()).fold(0.0, f64::max);
        let d2: f64 = (0..3).map(|k| (e2[k] - f2[k]).abs()).fold(0.0, f64::max);
        if d1 > 1e-6 {
            prop_assert!(d2 < 0.3 * d1, "halving ε: {} → {} (expected ≈ ×0.25)", d1, d2);
        }
    }
}
