//! Speed of the volumetric error engine on `deploy/examples/vmc-3axis.toml` (18 bidirectional
//! 100-point tables, 3 squareness, 16 sensors with lag, 7 thermal and 3 load terms).
//!
//! Run: `cargo bench --bench models` (figures and the exact command in docs/model.md, Speed)
//! Targets (issue 2): one exact evaluation ≤ 250 ns; a batch of 10⁶ points ≥ 4 M evaluations/s.
//!
//! Each benchmark runs twice: `wall/…` with criterion's wall clock and `cpu/…` with the benchmark
//! thread's own CPU time (`clock_gettime(CLOCK_THREAD_CPUTIME_ID)`), which stays meaningful when the
//! machine is shared and the thread is preempted (wall time then counts other processes' slices).

use std::hint::black_box;
use std::path::Path;

use criterion::measurement::Measurement;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use retrocomp_model::{MachineModel, ModelInput};

#[path = "../crates/model/benches/thread_cpu/mod.rs"]
mod thread_cpu;
use thread_cpu::ThreadCpuTime;

fn model() -> MachineModel {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/examples/vmc-3axis.toml");
    MachineModel::from_toml_path(&p).expect("example model loads")
}

/// A deterministic spread of points over the work zone with warm sensors and loads.
fn inputs(model: &MachineModel, n: usize) -> Vec<ModelInput> {
    (0..n)
        .map(|i| {
            let f = i as f64;
            let mut input = model.new_input();
            input.pos_mm = [(f * 7.31) % 800.0, (f * 3.77) % 500.0, (f * 5.13) % 500.0];
            input.dir = [
                if i % 2 == 0 { 1 } else { -1 },
                if i % 3 == 0 { -1 } else { 1 },
                0,
            ];
            input.t_s = f * 0.001;
            for (k, t) in input.temps_c.iter_mut().enumerate() {
                *t = 20.0 + 0.1 * k as f64 + (f * 1e-4).sin();
            }
            for x in input.forces_n.iter_mut() {
                *x = 150.0;
            }
            for s in input.strains_ue.iter_mut() {
                *s = 40.0;
            }
            input
        })
        .collect()
}

fn bench<M: Measurement>(c: &mut Criterion<M>, clock: &str) {
    let m = model();
    let mut pts = inputs(&m, 4096);
    let mut state = m.new_state();
    let mut out = m.new_breakdown();

    let mut g = c.benchmark_group(format!("{clock}/vmc-3axis"));
    g.throughput(Throughput::Elements(1));
    let mut i = 0usize;
    let mut t = 0.0;
    g.bench_function("evaluate_exact_one", |b| {
        b.iter(|| {
            let input = &mut pts[i & 4095];
            i += 1;
            t += 0.001;
            input.t_s = t;
            m.evaluate(black_box(&*input), &mut state, &mut out);
            black_box(out.total_um)
        });
    });
    g.bench_function("evaluate_first_order_one", |b| {
        b.iter(|| {
            let input = &mut pts[i & 4095];
            i += 1;
            t += 0.001;
            input.t_s = t;
            m.evaluate_first_order(black_box(&*input), &mut state, &mut out);
            black_box(out.total_um)
        });
    });
    // Breakdown: the same points through the geometric part only (no sensors, thermal, load).
    let mut geo_spec = m.spec().clone();
    geo_spec.sensors.clear();
    geo_spec.thermal.clear();
    geo_spec.forces.clear();
    geo_spec.load.clear();
    let geo = MachineModel::from_spec(geo_spec);
    let (mut gs, mut go) = (geo.new_state(), geo.new_breakdown());
    let geo_pts: Vec<ModelInput> = pts
        .iter()
        .map(|p| ModelInput {
            pos_mm: p.pos_mm,
            dir: p.dir,
            ..geo.new_input()
        })
        .collect();
    g.bench_function("evaluate_exact_geometry_only_one", |b| {
        b.iter(|| {
            let input = &geo_pts[i & 4095];
            i += 1;
            geo.evaluate(black_box(input), &mut gs, &mut go);
            black_box(go.total_um)
        });
    });
    // Breakdown: the 18 component functions alone (the table lookups).
    let funcs: Vec<_> = m
        .spec()
        .components
        .iter()
        .map(|c| (c.id.axis.index(), c.function.clone()))
        .collect();
    g.bench_function("tables_only_18", |b| {
        b.iter(|| {
            let input = &geo_pts[i & 4095];
            i += 1;
            let mut acc = 0.0;
            for (a, f) in &funcs {
                acc += f.eval(input.pos_mm[*a], input.dir[*a]).0;
            }
            black_box(acc)
        });
    });
    g.finish();

    // Batch: 10⁶ points, one state, exact evaluation, times advancing 1 ms per point.
    let mut batch: Vec<ModelInput> = Vec::with_capacity(1_000_000);
    for k in 0..1_000_000usize {
        let mut p = pts[k & 4095].clone();
        p.t_s = k as f64 * 0.001;
        batch.push(p);
    }
    let mut g = c.benchmark_group(format!("{clock}/vmc-3axis-batch"));
    g.sample_size(10);
    g.throughput(Throughput::Elements(batch.len() as u64));
    g.bench_function("evaluate_exact_1e6", |b| {
        b.iter(|| {
            let mut st = m.new_state();
            let mut acc = 0.0;
            for p in &batch {
                m.evaluate(p, &mut st, &mut out);
                acc += out.total_um[0];
            }
            black_box(acc)
        });
    });
    // The same through the batch API (one reused breakdown; `black_box` makes every term count as
    // read).
    g.bench_function("evaluate_batch_exact_1e6", |b| {
        b.iter(|| {
            let mut st = m.new_state();
            let mut acc = 0.0;
            m.evaluate_batch(&batch, &mut st, &mut out, |_, o| {
                acc += black_box(o).total_um[0];
            });
            black_box(acc)
        });
    });
    g.finish();
}

fn wall(c: &mut Criterion) {
    bench(c, "wall");
}

fn cpu(c: &mut Criterion<ThreadCpuTime>) {
    bench(c, "cpu");
}

criterion_group!(wall_clock, wall);
criterion_group! {
    name = cpu_clock;
    config = Criterion::default().with_measurement(ThreadCpuTime::new());
    targets = cpu
}
criterion_main!(wall_clock, cpu_clock);
