//! `to_toml_string` round-trips: fit and diagnose save models with it, so a written model must read
//! back as the same spec and evaluate identically.

use std::path::Path;

use retrocomp_model::MachineModel;

const EXAMPLES: [&str; 4] = [
    "studer-s36.toml",
    "studer-s36-positional.toml",
    "excello-921.toml",
    "vmc-3axis.toml",
];

fn load(name: &str) -> MachineModel {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("deploy/examples")
        .join(name);
    MachineModel::from_toml_path(&p).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn examples_write_and_read_back_identically() {
    for name in EXAMPLES {
        let m = load(name);
        let text = m.to_toml_string();
        let back = MachineModel::from_toml_str(&text, "written")
            .unwrap_or_else(|e| panic!("{name}: {e}\n{text}"));
        assert_eq!(
            back.spec(),
            m.spec(),
            "{name}: spec changed in the round trip"
        );
        assert_eq!(back.to_toml_string(), text, "{name}: writing is stable");
        assert_eq!(back.term_names(), m.term_names());

        // Same numbers at a spread of points, both directions, warm and loaded.
        let (mut s1, mut s2) = (m.new_state(), back.new_state());
        let (mut o1, mut o2) = (m.new_breakdown(), back.new_breakdown());
        for k in 0..200 {
            let f = f64::from(k);
            let mut input = m.new_input();
            input.pos_mm = [(f * 7.3) % 500.0, (f * 3.1) % 400.0, -((f * 5.7) % 300.0)];
            input.dir = [if k % 2 == 0 { 1 } else { -1 }, 1, -1];
            input.t_s = f;
            input
                .temps_c
                .iter_mut()
                .for_each(|t| *t = 22.0 + (f * 0.1).sin());
            input.forces_n.iter_mut().for_each(|x| *x = 50.0);
            input.strains_ue.iter_mut().for_each(|x| *x = 12.0);
            m.evaluate(&input, &mut s1, &mut o1);
            back.evaluate(&input, &mut s2, &mut o2);
            assert_eq!(o1, o2, "{name} at point {k}");
        }
    }
}

#[test]
fn units_are_converted_once_and_written_canonically() {
    // Table 6.1 δzz F at Z = 0 is 0.0007 mm → 0.7 µm; εyz 0.0030 mm/m → 3.0 µrad; Szx → µrad.
    let text = load("studer-s36.toml").to_toml_string();
    assert!(text.contains("forward_um = [0.7, 0.7, -0.1"), "{text}");
    assert!(
        text.contains("forward_urad = [3.0, 0.7000000000000001, 0.0")
            || text.contains("forward_urad = [3.0, 0.7, 0.0"),
        "{text}"
    );
    assert!(text.contains("value_urad = 382.35294117647"), "{text}");
    assert!(!text.contains("_mm_per_m") && !text.contains("forward_mm"));
}
