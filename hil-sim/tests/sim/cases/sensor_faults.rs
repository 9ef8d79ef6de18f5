//! No false sensor fault on the benchmark's healthy recordings (issue 36 point 4): every family of
//! `hil-sim gen-cases` simulates working sensors (quantised, noisy, with decoys, drifting ambient,
//! regime changes), so diagnose's sensor check (`sensor_faults.rs`) must report nothing on them:
//! a false fault would silently remove a real driver from the physics search.

use hil_sim::cases::{Family, generate_family_case};
use retrocomp_analysis::diagnose::features::Context;
use retrocomp_analysis::diagnose::sensor_faults::scan;

#[test]
fn no_family_of_the_benchmark_shows_a_sensor_fault() {
    let mut bad = vec![];
    for family in Family::ALL {
        for index in 0..20 {
            let (rec, _) = generate_family_case(family, 7, index);
            for f in scan(&Context::from_recording(&rec)) {
                bad.push(format!("{} case {index}: {f:?}", family.name()));
            }
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}
