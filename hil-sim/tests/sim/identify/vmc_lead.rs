//! Issue 15, point 4 — why `vmc-3axis.toml` is judged against the truth as the plates sample it
//! (docs/identify.md, "`vmc-3axis.toml` in X"). Its X positioning table (100 points 8.08 mm apart)
//! holds a ball-screw lead wave of 5 mm, 1.2 µm at its nodes; 8.08 mm is 1.62 leads, so the table
//! aliases the wave, and the hidden machine (the table linearly interpolated, as hil-sim probes it)
//! carries a 21 mm / 13 mm zigzag and almost nothing at the 5 mm lead. A periodic term at the known
//! lead therefore cannot identify what the plates miss: this test pins those numbers. Y and Z carry
//! the same 5 mm wave tabulated every 5.05 mm (1.01 leads): aliased into a 500 mm wave, long enough
//! for the plates. µm, mm.

use retrocomp_model::{Axis, ComponentId, MachineModel, Motion};

const LEAD_MM: f64 = 5.0;

fn positioning(model: &MachineModel, axis: Axis) -> impl Fn(f64) -> f64 + '_ {
    let id = ComponentId {
        axis,
        motion: Motion::Translation(axis),
    };
    let c = model
        .spec()
        .components
        .iter()
        .find(|c| c.id == id)
        .expect("positioning component");
    // Direction 0: the mean of both directions, what hil-sim's artefact probings see.
    move |q: f64| c.function.eval(q, 0).0
}

/// Least squares by the normal equations (a handful of columns), Gaussian elimination.
fn lstsq(rows: &[Vec<f64>], y: &[f64]) -> Vec<f64> {
    let n = rows[0].len();
    let mut m = vec![vec![0.0; n + 1]; n];
    for (r, yi) in rows.iter().zip(y) {
        for i in 0..n {
            for j in 0..n {
                m[i][j] += r[i] * r[j];
            }
            m[i][n] += r[i] * yi;
        }
    }
    for i in 0..n {
        let p = (i..n)
            .max_by(|&a, &b| m[a][i].abs().total_cmp(&m[b][i].abs()))
            .unwrap();
        m.swap(i, p);
        for r in 0..n {
            if r != i {
                let f = m[r][i] / m[i][i];
                let pivot = m[i].clone();
                for (a, b) in m[r].iter_mut().zip(&pivot) {
                    *a -= f * b;
                }
            }
        }
    }
    (0..n).map(|i| m[i][n] / m[i][i]).collect()
}

/// Smooth part (quadratic in q/len) + the lead wave, fitted at `nodes`: (wave amplitude, largest
/// residual, smooth coefficients).
fn fit_lead(f: &dyn Fn(f64) -> f64, nodes: &[f64], len: f64) -> (f64, f64, Vec<f64>) {
    let w = std::f64::consts::TAU / LEAD_MM;
    let rows: Vec<Vec<f64>> = nodes
        .iter()
        .map(|&q| {
            let s = q / len;
            vec![1.0, s, s * s, (w * q).sin(), (w * q).cos()]
        })
        .collect();
    let y: Vec<f64> = nodes.iter().map(|&q| f(q)).collect();
    let c = lstsq(&rows, &y);
    let worst = rows
        .iter()
        .zip(&y)
        .map(|(r, y)| (y - r.iter().zip(&c).map(|(a, b)| a * b).sum::<f64>()).abs())
        .fold(0.0, f64::max);
    (c[3].hypot(c[4]), worst, c[..3].to_vec())
}

/// Amplitude of the period-`p` sinusoid in `g` over [0, len] (Fourier projection, 0.05 mm steps).
fn amplitude(g: &dyn Fn(f64) -> f64, len: f64, p: f64) -> f64 {
    let n = (len / 0.05) as usize;
    let (mut s, mut c) = (0.0, 0.0);
    for k in 0..n {
        let q = k as f64 * 0.05;
        let a = std::f64::consts::TAU * q / p;
        s += g(q) * a.sin();
        c += g(q) * a.cos();
    }
    2.0 * s.hypot(c) / n as f64
}

#[test]
fn vmc_positioning_waves_are_a_5_mm_lead_aliased_by_their_own_tables() {
    let p =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/examples/vmc-3axis.toml");
    let vmc = MachineModel::from_toml_path(&p).unwrap();
    for (axis, len, amp) in [
        (Axis::X, 800.0, 1.2),
        (Axis::Y, 500.0, 0.9),
        (Axis::Z, 500.0, 0.7),
    ] {
        let f = positioning(&vmc, axis);
        let step = len / 99.0;
        let nodes: Vec<f64> = (0..100).map(|k| f64::from(k) * step).collect();
        // At its nodes the table is a smooth part plus exactly the 5 mm lead wave.
        let (a, worst, smooth) = fit_lead(&f, &nodes, len);
        assert!(
            (a - amp).abs() < 0.01 && worst < 0.01,
            "{axis:?}: lead wave {a:.3} µm (want {amp}), residual {worst:.4} µm"
        );
        // Where the nodes put it: phase steps of step/lead turns, folded to the nearest integer.
        let turns = step / LEAD_MM;
        let alias_mm = step / (turns - turns.round()).abs();
        let zig = |q: f64| {
            let s = q / len;
            f(q) - smooth[0] - smooth[1] * s - smooth[2] * s * s
        };
        let at_lead = amplitude(&zig, len, LEAD_MM);
        let at_alias = amplitude(&zig, len, alias_mm);
        eprintln!(
            "{axis:?}: table every {step:.3} mm holds {a:.2} µm at the {LEAD_MM} mm lead; the \
             interpolated table carries {at_alias:.3} µm at {alias_mm:.1} mm, {at_lead:.3} µm at \
             the lead"
        );
        if axis == Axis::X {
            // The zigzag plates alias: 21 mm, 0.72 µm; the lead term would find 0.04 µm.
            assert!((alias_mm - 21.05).abs() < 0.1, "{alias_mm}");
            assert!(at_alias > 0.6 && at_lead < 0.06, "{at_alias} {at_lead}");
        } else {
            // 1.01 leads per node: a 500 mm wave, as long as the travel — the plates follow it.
            assert!(alias_mm > 400.0, "{axis:?}: {alias_mm}");
            assert!(at_lead < 0.1 * amp, "{axis:?}: {at_lead}");
        }
    }
}
