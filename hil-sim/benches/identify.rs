//! Issue 15, point 6: six hole plates of 10×10 holes (each probed twice: 1200 probings, 2400
//! observations) identified on one core — the whole `identify` (outlier pass, stepwise knot
//! elimination, final solve) plus the model written. Target ≤ 2 s. The six are `hil-sim artefacts`'
//! default plan (three placements, each probed with two probes); the seven- and twelve-measurement
//! plans are timed too.
//!
//! `cargo bench -p hil-sim --bench identify -- --warm-up-time 1 --measurement-time 3`

use criterion::{Criterion, criterion_group, criterion_main};
use hil_sim::artefacts::{Metrology, Plan, measure_plan};
use retrocomp_analysis::identify::Geometry;
use retrocomp_analysis::identify::report::to_spec;
use retrocomp_analysis::identify::{Options, identify};
use retrocomp_model::MachineModel;

fn bench(c: &mut Criterion) {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/examples/old-mill-3axis.toml");
    let truth = MachineModel::from_toml_path(&p).unwrap();
    let geo = Geometry::from_chain("X F Y Z").unwrap();
    for (name, plan, n) in [
        ("identify_six_plates_10x10", Plan::Six, 6),
        ("identify_seven_plates_10x10", Plan::Seven, 7),
        ("identify_twelve_plates_10x10", Plan::Twelve, 12),
    ] {
        let plates = measure_plan(&truth, &Metrology::default(), 1, plan).plates;
        assert_eq!(plates.len(), n);
        assert!(
            plates.iter().all(|p| p.probes.len() == 200),
            "10×10 holes, two probings each"
        );
        c.bench_function(name, |b| {
            b.iter(|| {
                let id = identify(&geo, &plates, &[], &Options::default()).unwrap();
                MachineModel::from_spec(to_spec(&id, "bench")).to_toml_string()
            });
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
