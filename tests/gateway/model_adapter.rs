//! The gateway drives the real machine model (`crates/model/src`) through `MachineModelAdapter`, with the
//! Studer S-36 tables of Asad Ullah 2013 (seed 004, Table 6.1: EZZ forward −0.0096 mm and reverse
//! −0.0063 mm at z = 510 mm). Correction = −error; a reversal is blended, never stepped.

use std::collections::BTreeMap;
use std::path::Path;

use retrocomp_bus::{Health, Sample};
use retrocomp_gateway::Engine;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_model::MachineModel;

const CFG: &str = r#"
[gateway]
name = "studer"
cycle_ms = 10
[safety]
max_correction_um = 100.0
max_change_um_per_cycle = 5.0
ramp_um_per_s = 1000.0
stale_hold_s = 1.0
[direction]
deadband_mm = 0.005
switch_time_s = 0.1
[[axis]]
name = "z"
position_channel = "z_mm"
[[axis]]
name = "x"
position_channel = "x_mm"
"#;

#[test]
fn studer_table_6_1_through_the_gateway() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let model =
        MachineModel::from_toml_path(&root.join("deploy/examples/studer-s36.toml")).unwrap();
    let mut m = MachineModelAdapter::new(model);
    let cfg = FieldConfig::parse(CFG, Path::new("studer.toml")).unwrap();
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let mut t = 0.0;
    let mut step = |e: &mut Engine, z: f64| {
        t += 0.01;
        for (ch, v) in [("z_mm", z), ("x_mm", 0.0)] {
            let channel = e.channels_mut().resolve(ch);
            e.handle_sample(&Sample {
                channel,
                t_s: t,
                value: v,
                health: Health::Ok,
            });
        }
        e.cycle(t, &mut m)
    };
    // Forward from 400 to 510 mm, then dwell: the z correction includes −EZZ_forward(510) = +9.6 µm.
    for k in 0..=110 {
        step(&mut e, 400.0 + f64::from(k));
    }
    for _ in 0..50 {
        step(&mut e, 510.0);
    }
    let snap = e.snapshot();
    let z = snap.axes.iter().find(|a| a.axis == "z").unwrap();
    let ezz = z
        .terms_um
        .iter()
        .find(|(k, _)| k.contains("EZZ"))
        .map(|(_, v)| *v);
    assert!(
        ezz.is_some_and(|v| (v - 9.6).abs() < 1e-6),
        "EZZ term {ezz:?} in {:?}",
        z.terms_um
    );
    // Reverse by 0.02 mm (beyond the 5 µm deadband): blends to −EZZ_reverse ≈ +6.3 µm without a step.
    let mut last = ezz_of(&snap);
    let mut worst = 0.0f64;
    for k in 1..=40 {
        step(&mut e, 510.0 - 0.001 * f64::from(k.min(20)));
        let snap = e.snapshot();
        let v = ezz_of(&snap);
        worst = worst.max((v - last).abs());
        last = v;
    }
    assert!((last - 6.3).abs() < 0.01, "reverse EZZ near 510 mm: {last}");
    assert!(
        worst < 0.3 * (9.6 - 6.3),
        "largest step during the reversal {worst} µm"
    );
}

fn ezz_of(snap: &retrocomp_gateway::StatusSnapshot) -> f64 {
    let z = snap.axes.iter().find(|a| a.axis == "z").unwrap();
    *z.terms_um
        .iter()
        .find(|(k, _)| k.contains("EZZ"))
        .unwrap()
        .1
}
