//! `MachineModel::evaluate` side by side with the floor (`floor_vmc`: a hand-specialised evaluator
//! of `deploy/examples/vmc-3axis.toml` giving the same breakdown, `tests/model/floor.rs`), issue 39 point 1.
//!
//! Run: `cargo bench -p retrocomp-model --bench floor` (figures in docs/model.md, "Speed").
//! Instructions per evaluation of both: `cargo run --profile bench -p retrocomp-model --example
//! floor_count` (under valgrind).
//!
//! Both evaluators see the same points (those of `benches/models.rs`), each with its own state, time
//! advancing 1 ms per evaluation; every evaluation writes the total and all 32 terms. Each benchmark
//! runs with criterion's wall clock (`wall/…`) and with the thread's CPU time (`cpu/…`,
//! `CLOCK_THREAD_CPUTIME_ID`), which stays meaningful on a shared machine.

#[path = "floor_vmc/mod.rs"]
mod floor_vmc;

use std::hint::black_box;

use criterion::measurement::Measurement;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use retrocomp_model::ModelInput;

#[path = "thread_cpu/mod.rs"]
mod thread_cpu;
use thread_cpu::ThreadCpuTime;

fn bench<M: Measurement>(c: &mut Criterion<M>, clock: &str) {
    let m = floor_vmc::vmc_model();
    let floor = floor_vmc::Floor::new(&m);
    let mut pts = floor_vmc::bench_inputs(&m, 4096);
    let (mut state, mut fstate) = (m.new_state(), floor.new_state());
    let (mut out, mut fout) = (m.new_breakdown(), m.new_breakdown());

    let mut g = c.benchmark_group(format!("{clock}/floor"));
    g.throughput(Throughput::Elements(1));
    let (mut i, mut t) = (0usize, 0.0);
    g.bench_function("plan_exact_one", |b| {
        b.iter(|| {
            let input = &mut pts[i & 4095];
            i += 1;
            t += 0.001;
            input.t_s = t;
            m.evaluate(black_box(&*input), &mut state, &mut out);
            black_box(&out);
        });
    });
    let (mut i, mut t) = (0usize, 0.0);
    g.bench_function("floor_exact_one", |b| {
        b.iter(|| {
            let input = &mut pts[i & 4095];
            i += 1;
            t += 0.001;
            input.t_s = t;
            floor.run(black_box(&*input), &mut fstate, &mut fout);
            black_box(&fout);
        });
    });
    g.finish();

    // 10⁶ points, one state, 1 ms apart: `evaluate_batch` and the floor in a loop.
    let batch: Vec<ModelInput> = (0..1_000_000u32)
        .map(|k| {
            let mut p = pts[k as usize & 4095].clone();
            p.t_s = f64::from(k) * 0.001;
            p
        })
        .collect();
    let mut g = c.benchmark_group(format!("{clock}/floor-batch"));
    g.sample_size(10);
    g.throughput(Throughput::Elements(1_000_000));
    g.bench_function("plan_evaluate_batch_1e6", |b| {
        b.iter(|| {
            let mut st = m.new_state();
            let mut acc = 0.0;
            m.evaluate_batch(&batch, &mut st, &mut out, |_, o| {
                acc += black_box(o).total_um[0];
            });
            black_box(acc)
        });
    });
    g.bench_function("floor_loop_1e6", |b| {
        b.iter(|| {
            let mut st = floor.new_state();
            let mut acc = 0.0;
            for p in &batch {
                floor.run(p, &mut st, &mut fout);
                acc += black_box(&fout).total_um[0];
            }
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
