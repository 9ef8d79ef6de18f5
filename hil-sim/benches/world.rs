//! Simulation speed: 10 s of simulated time at a 1 kHz servo rate, 3 axes moving, thermal network
//! with 3 nodes and 3 sensors, cutting force, noise on (built-in geometry, then the project's
//! volumetric model). Real-time factor = 10 s / measured time. `program_to_end_recorded` is
//! `hil-sim run`'s loop: the same world run to the program's end with every sample written as a
//! recording row (docs/recording-csv.md CSV) into a sink; `program_to_end` is the same without the recording, so
//! the difference is the writer's cost.
//! Run: `cargo bench -p hil-sim --bench world`.

use criterion::{Criterion, criterion_group, criterion_main};
use hil_sim::recording::run_to_end;
use hil_sim::{SimConfig, World};

const CFG: &str = r#"
seed = 1
[program]
tool_mm = 100.0
gcode = """
S4000 M3
G1 F3000 X200 Y150 Z-50
G2 X250 Y200 I50 J0
G1 X0 Y0 Z0
G1 X200 Y150 Z-50
G1 X0 Y0 Z0
M30
"""
[truth.builtin]
exx_ppm = 20.0
ec0y_urad = 30.0
[hidden]
error_noise_um = 0.3
[hidden.backlash.x]
b_um = 5.0
[hidden.cyclic.y]
period_mm = 5.0
amplitude_um = 1.0
[hidden.thermal]
ambient_drift_C_per_h = 0.5
nodes = [
  { name = "spindle", tau_s = 600.0, rise_C_per_krpm = 2.0 },
  { name = "xscrew", tau_s = 300.0, rise_C_per_mm_s = { x = 0.2 } },
  { name = "column", tau_s = 1800.0, couple = [{ node = "spindle", tau_s = 900.0 }] },
]
sensors = [
  { name = "spindle", node = "spindle", tau_s = 20.0, noise_C = 0.02 },
  { name = "xscrew", node = "xscrew", tau_s = 5.0, noise_C = 0.02 },
  { name = "column", node = "column", noise_C = 0.02 },
]
effects = [
  { kind = "growth", node = "spindle", axis = "z", um_per_K = -5.0 },
  { kind = "expansion", node = "xscrew", axis = "x", ppm_per_K = 11.5 },
]
[hidden.cutting]
stock_top_z_mm = 0.0
compliance_um_per_N = { x = 0.01 }
"#;

fn bench(c: &mut Criterion) {
    let cfg = SimConfig::from_toml_str(CFG, None).unwrap();
    let mut g = c.benchmark_group("world");
    g.sample_size(10);
    g.bench_function("10s_sim_1kHz_3axes_thermal", |b| {
        b.iter(|| {
            let mut w = World::new(cfg.clone()).unwrap();
            for _ in 0..10_000 {
                w.tick();
            }
            assert!(w.t_s() > 9.99);
            w.readings().error_um
        });
    });
    // The whole program, without and with the recording: the difference is the writer's cost.
    g.bench_function("program_to_end", |b| {
        b.iter(|| {
            let mut w = World::new(cfg.clone()).unwrap();
            while !w.done() {
                w.tick();
            }
            w.readings().error_um
        });
    });
    g.bench_function("program_to_end_recorded", |b| {
        b.iter(|| {
            let mut w = World::new(cfg.clone()).unwrap();
            let (_, rows) = run_to_end(&mut w, std::io::sink(), |_| {}).unwrap();
            assert!(rows > 1000);
            rows
        });
    });
    // Same world with the project's exact (4×4 HTM) volumetric model as the geometry truth
    // (Studer S-36, all tables bidirectional), evaluated at every sample and for every truth query.
    let model =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/examples/studer-s36.toml");
    let mut vcfg = cfg.clone();
    vcfg.truth.builtin = Default::default();
    vcfg.truth.model_path = Some(model);
    g.bench_function("10s_sim_1kHz_3axes_thermal_volumetric_model", |b| {
        b.iter(|| {
            let mut w = World::new(vcfg.clone()).unwrap();
            for _ in 0..10_000 {
                w.tick();
            }
            assert!(w.t_s() > 9.99);
            w.readings().error_um
        });
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
