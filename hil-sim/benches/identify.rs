//! Issue 15, point 6: six hole plates of 10×10 holes (each probed twice: 1200 probings, 2400
//! observations) identified on one core — the whole `identify` (outlier pass, stepwise knot
//! elimination, final solve) plus the model written. Target ≤ 2 s. The six are one probe's
//! measurement of each of `hil-sim artefacts`' six placements; the plan's twelve measurements (both
//! probes) are timed too.
//!
//! `cargo bench -p hil-sim --bench identify -- --warm-up-time 1 --measurement-time 3`

use criterion::{Criterion, criterion_group, criterion_main};
use hil_sim::artefacts::{Metrology, measure_all};
use retrocomp::analysis::identify::design::Geometry;
use retrocomp::analysis::identify::report::to_spec;
use retrocomp::analysis::identify::{Options, identify};
use retrocomp::models::MachineModel;

fn bench(c: &mut Criterion) {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../deploy/examples/old-mill-3axis.toml");
    let truth = MachineModel::from_toml_path(&p).unwrap();
    let meas = measure_all(&truth, &Metrology::default(), 1);
    let geo = Geometry::from_chain("X F Y Z").unwrap();
    let six: Vec<_> = meas.plates.iter().step_by(2).cloned().collect();
    assert_eq!(six.len(), 6);
    for (name, plates) in [
        ("identify_six_plates_10x10", &six[..]),
        ("identify_twelve_plates_10x10", &meas.plates[..]),
    ] {
        c.bench_function(name, |b| {
            b.iter(|| {
                let id = identify(&geo, plates, &[], &Options::default()).unwrap();
                MachineModel::from_spec(to_spec(&id, "bench")).to_toml_string()
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
