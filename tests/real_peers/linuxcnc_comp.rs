//! `retrocomp export --format linuxcnc` judged by a real headless LinuxCNC 2.9: the exported
//! tables are loaded through `[JOINT_n]COMP_FILE` (joint 0 with `COMP_FILE_TYPE = 0`, actual
//! positions; joint 1 with type 1, offsets) and after MDI moves the joint's applied correction
//! (`joint.N.backlash-corr`, and `motor-pos-cmd − pos-cmd`) equals −error (error = actual −
//! nominal, linear between table points, the end value held beyond the ends) at positions
//! approached in both directions and beyond both table ends, within 0.1 µm.

use crate::linuxcnc_support;

use std::process::Command;

use linuxcnc_support::headless::{Config, run_mdi};

/// The table: position_mm, forward_um, reverse_um (error = actual − nominal).
const TABLE: [(f64, f64, f64); 9] = [
    (0.0, 3.0, -21.0),
    (50.0, -5.0, -28.5),
    (100.0, 12.0, -9.0),
    (150.0, 8.2, -15.3),
    (200.0, -2.0, -30.0),
    (250.0, 15.0, -7.7),
    (300.0, 20.0, 1.0),
    (350.0, 4.4, -20.0),
    (400.0, -6.0, -33.0),
];

/// −error at `p` approached forward (`fwd`) or in reverse: linear, end values held.
fn correction_mm(p: f64, fwd: bool) -> f64 {
    let v = |i: usize| if fwd { TABLE[i].1 } else { TABLE[i].2 };
    let n = TABLE.len();
    let e_um = if p <= TABLE[0].0 {
        v(0)
    } else if p >= TABLE[n - 1].0 {
        v(n - 1)
    } else {
        let i = TABLE.iter().rposition(|r| r.0 <= p).unwrap();
        let f = (p - TABLE[i].0) / (TABLE[i + 1].0 - TABLE[i].0);
        v(i) + f * (v(i + 1) - v(i))
    };
    -e_um / 1000.0
}

#[test]
fn exported_comp_files_of_both_types_apply_minus_error_in_linuxcnc() {
    let _turn = crate::turn::take(file!());
    let dir = std::env::temp_dir().join(format!("retrocomp-lcnc-comp-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut csv = String::from("position_mm,forward_um,reverse_um\n");
    for (p, f, r) in TABLE {
        csv.push_str(&format!("{p},{f},{r}\n"));
    }
    let table = dir.join("table.csv");
    std::fs::write(&table, csv).unwrap();
    for t in [0, 1] {
        let out = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
            .args(["export", table.to_str().unwrap(), "--format", "linuxcnc"])
            .args(["--comp-type", &t.to_string(), "--out"])
            .arg(dir.join(format!("comp{t}.txt")))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let cfg = Config {
        joint_extra: [
            vec![
                format!("COMP_FILE = {}", dir.join("comp0.txt").display()),
                "COMP_FILE_TYPE = 0".into(),
            ],
            vec![
                format!("COMP_FILE = {}", dir.join("comp1.txt").display()),
                "COMP_FILE_TYPE = 1".into(),
            ],
            vec![],
        ],
        pins: [0, 1]
            .iter()
            .flat_map(|j| {
                ["backlash-corr", "pos-cmd", "motor-pos-cmd"].map(|p| format!("joint.{j}.{p}"))
            })
            .collect(),
    };
    // Forward up through the table and beyond its end, then reverse down and beyond the start.
    let targets = [
        -30.0, 20.0, 75.0, 130.0, 233.3, 300.0, 460.0, 380.0, 262.5, 200.0, 110.0, 30.0, -40.0,
    ];
    let mdi: Vec<String> = targets
        .iter()
        .map(|x| format!("G1 X{x} Y{x} F6000"))
        .collect();
    let res = run_mdi(&dir.join("lc"), &cfg, &mdi);
    assert_eq!(res.len(), targets.len());
    let mut prev = 0.0;
    let mut worst = 0.0f64;
    for ((line, v), &x) in res.iter().zip(&targets) {
        let fwd = x > prev;
        prev = x;
        let want = correction_mm(x, fwd);
        for j in 0..2 {
            let (corr, pos, motor) = (v[3 * j], v[3 * j + 1], v[3 * j + 2]);
            assert!((pos - x).abs() < 1e-9, "{line}: joint {j} at {pos}");
            for (what, got) in [("backlash-corr", corr), ("motor − pos", motor - pos)] {
                let dev = (got - want).abs() * 1000.0;
                worst = worst.max(dev);
                assert!(
                    dev <= 0.1,
                    "{line}: joint {j} (COMP_FILE_TYPE {j}) {what} {:.4} µm, −error {:.4} µm ({})",
                    got * 1000.0,
                    want * 1000.0,
                    if fwd { "forward" } else { "reverse" }
                );
            }
        }
    }
    eprintln!(
        "LinuxCNC COMP_FILE types 0 and 1: {} positions, worst |applied − (−error)| {worst:.4} µm",
        targets.len()
    );
}
