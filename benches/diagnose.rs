//! Speed of `retrocomp diagnose` (issue 7 item 7, issue 39 point 3): 100 000 samples × 20 context
//! channels on rayon's pool (every core; `RAYON_NUM_THREADS=1` for one). Targets ≤ 10 s per
//! diagnosis on one core, ≤ 2 s on two. Beside it, one call of `effective_n` (the long-run
//! variance every test and criterion of a diagnosis divides by; one FFT pair per call) on a
//! residual as long as the 10⁶-row recording of `hil-sim/examples/mill-1m.toml`. Figures:
//! docs/performance.md, docs/diagnose-results.md. Run: `cargo bench -p retrocomp --bench diagnose`.

use criterion::{Criterion, criterion_group, criterion_main};
use rand::{Rng, SeedableRng};
use retrocomp_analysis::diagnose::features::lowpass;
use retrocomp_analysis::diagnose::lsq::effective_n;
use retrocomp_analysis::diagnose::{diagnose, select::Options};
use retrocomp_model::recording::Recording;

/// 100k samples at 10 Hz (2.8 h): X/Y step-and-dwell with scans, 12 temperatures (one drives a
/// thermal lag of 900 s), 2 forces, 2 strains, rpm, tool, 2 decoys = 20 context channels beside
/// positions; ex carries a hidden backlash + thermal lag, ey only noise.
fn recording() -> Recording {
    let n = 100_000;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
    let x: Vec<f64> = (0..n)
        .map(|i| ((i / 50) % 60) as f64 * 5.0)
        .map(|v| if v > 150.0 { 300.0 - v } else { v })
        .collect();
    let y: Vec<f64> = (0..n)
        .map(|i| (i as f64 * 0.013).sin() * 100.0 + 100.0)
        .collect();
    let mut cols: Vec<(String, Vec<f64>)> = vec![
        ("t_s".into(), t.clone()),
        ("x_mm".into(), x.clone()),
        ("y_mm".into(), y),
    ];
    let mut temps = vec![];
    for k in 0..12 {
        let tau = 600.0 + 300.0 * f64::from(k);
        let drive: Vec<f64> = t
            .iter()
            .map(|s| 20.0 + 5.0 * (s / (3000.0 + 500.0 * f64::from(k))).sin().abs())
            .collect();
        let tk = lowpass(&t, &drive, tau);
        temps.push(tk.clone());
        cols.push((
            format!("T_s{k}_C"),
            tk.iter()
                .map(|v| v + rng.random_range(-0.02..0.02))
                .collect(),
        ));
    }
    for k in 0..2 {
        cols.push((
            format!("F_c{k}_N"),
            (0..n)
                .map(
                    |i| if (i / 5000) % 3 == k { 300.0 } else { 0.0 } + rng.random_range(-2.0..2.0),
                )
                .collect(),
        ));
        cols.push((
            format!("strain_g{k}_ue"),
            (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        ));
    }
    cols.push((
        "rpm".into(),
        (0..n)
            .map(|i| if i < 60_000 { 6000.0 } else { 0.0 })
            .collect(),
    ));
    cols.push((
        "tool_mm".into(),
        (0..n)
            .map(|i| 100.0 + 50.0 * ((i / 25_000) % 2) as f64)
            .collect(),
    ));
    cols.push((
        "aux_a".into(),
        (0..n).map(|_| rng.random_range(0.0..1.0)).collect(),
    ));
    cols.push((
        "aux_b".into(),
        (0..n).map(|i| (i as f64 * 1e-4).cos()).collect(),
    ));
    let lag = lowpass(&t, &temps[3], 900.0);
    let mut dir = 1.0;
    let ex: Vec<f64> = (0..n)
        .map(|i| {
            if i > 0 && x[i] != x[i - 1] {
                dir = (x[i] - x[i - 1]).signum();
            }
            2.0 * dir + 3.0 * (lag[i] - lag[0]) + rng.random_range(-1.0..1.0)
        })
        .collect();
    let ey: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    cols.push(("ex_um".into(), ex));
    cols.push(("ey_um".into(), ey));
    cols.push(("sim_ex_um".into(), vec![0.0; n]));
    cols.push(("sim_ey_um".into(), vec![0.0; n]));
    Recording::from_columns(cols).unwrap()
}

fn bench(c: &mut Criterion) {
    let rec = recording();
    let ctx_channels = rec.names().len() - 3 - 4; // minus t_s, x_mm, y_mm and the four error/sim columns
    assert_eq!(ctx_channels, 20);
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    g.bench_function("100k_samples_20_context_channels", |b| {
        b.iter(|| {
            let d = diagnose(std::hint::black_box(&rec), &Options::default()).unwrap();
            assert!(d.report.findings.iter().any(|f| f.effect == "backlash"));
            d
        });
    });
    g.finish();
}

/// Rows of the mill-1m recording (`hil-sim/examples/mill-1m.toml`).
const MILL_1M_ROWS: usize = 1_035_560;

/// `effective_n` of an AR(1) (ρ 0.95) plus white residual of [`MILL_1M_ROWS`] rows.
fn bench_effective_n(c: &mut Criterion) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut ar = 0.0;
    let r: Vec<f64> = (0..MILL_1M_ROWS)
        .map(|_| {
            ar = 0.95 * ar + rng.random_range(-1.0..1.0);
            ar + rng.random_range(-1.0..1.0)
        })
        .collect();
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(20);
    g.bench_function("effective_n_1035560_rows", |b| {
        b.iter(|| {
            let n_eff = effective_n(std::hint::black_box(&r));
            // The AR(1) part makes neighbouring rows share most of their information.
            assert!(n_eff > 0.0 && n_eff < 0.5 * MILL_1M_ROWS as f64, "{n_eff}");
            n_eff
        });
    });
    g.finish();
}

criterion_group!(benches, bench, bench_effective_n);
criterion_main!(benches);
