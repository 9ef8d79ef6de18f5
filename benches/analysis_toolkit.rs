//! Throughput of the offline toolkit cores: ISO 230-2 evaluation of a full laser data set, NC
//! rewriting of a long program against the machine model, and the ballbar diagnosis.

use criterion::{Criterion, criterion_group, criterion_main};
use retrocomp_analysis::circular::{CircleSetup, CircleTrace, Rotation, analyse};
use retrocomp_analysis::iso230_2::{Reading, evaluate};
use retrocomp_analysis::nc::ModelErrors;
use retrocomp_analysis::nc::parser::parse_program;
use retrocomp_analysis::nc::rewrite::{RewriteConfig, rewrite};
use retrocomp_analysis::table::Direction;
use retrocomp_model::MachineModel;

fn iso(c: &mut Criterion) {
    // 41 targets × 5 runs × 2 directions (ISO 230-2 standard cycle on a 1 m axis).
    let mut rs = Vec::new();
    for i in 0..41 {
        for run in 1..=5 {
            for d in [Direction::Forward, Direction::Reverse] {
                let x = 25.0 * f64::from(i);
                rs.push(Reading {
                    target_mm: x,
                    run,
                    direction: d,
                    deviation_um: (x / 97.0).sin() + 0.1 * f64::from(run),
                });
            }
        }
    }
    c.bench_function("iso230_2_evaluate_410_readings", |b| {
        b.iter(|| evaluate(std::hint::black_box(&rs)).unwrap());
    });
}

fn nc(c: &mut Criterion) {
    let model = MachineModel::from_toml_path(
        &std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("deploy/examples/studer-s36.toml"),
    )
    .unwrap();
    // 2000 G1 moves across the Studer travel, each split at 5 mm (≈ 20 000 output points).
    let mut prog = String::from("G90 G01 X0 Z0 F1000;\n");
    for i in 0..2000 {
        let (x, z) = if i % 2 == 0 {
            (300.0, 500.0)
        } else {
            (10.0, 5.0)
        };
        prog.push_str(&format!("X{x} Z{z};\n"));
    }
    let blocks = parse_program("bench.nc", &prog, true).unwrap();
    let cfg = RewriteConfig {
        diameter_x: true,
        split_step_mm: Some(5.0),
        // The first move is split too: it needs a stated start.
        start_mm: Some([0.0; 3]),
        ..Default::default()
    };
    c.bench_function("nc_rewrite_2000_moves_split_5mm", |b| {
        b.iter(|| {
            rewrite(
                std::hint::black_box(&blocks),
                &ModelErrors::new(&model, true),
                &cfg,
            )
            .unwrap()
        });
    });
}

fn circle(c: &mut Criterion) {
    let trace = |rot: Rotation, s: f64| CircleTrace {
        rotation: rot,
        angle_rad: (0..720)
            .map(|i| {
                (s * std::f64::consts::TAU * f64::from(i) / 720.0).rem_euclid(std::f64::consts::TAU)
            })
            .collect(),
        dr_um: (0..720).map(|i| (f64::from(i) * 0.1).sin()).collect(),
    };
    let traces = [trace(Rotation::Ccw, 1.0), trace(Rotation::Cw, -1.0)];
    let setup = CircleSetup {
        radius_mm: 100.0,
        feed_mm_per_min: 1000.0,
        cyclic_period_x_mm: Some(5.0),
        cyclic_period_y_mm: None,
    };
    c.bench_function("circle_analyse_2x720_points", |b| {
        b.iter(|| analyse(std::hint::black_box(&traces), &setup).unwrap());
    });
}

criterion_group!(benches, iso, nc, circle);
criterion_main!(benches);
