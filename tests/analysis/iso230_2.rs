//! ISO 230-2:2014 evaluation: thesis fixture (Asad Ullah 2013, Tables 6.1/6.2 as mean-only F/R data)
//! and property tests of the bidirectional invariants.

use proptest::prelude::*;
use retrocomp_analysis::iso230_2::{Reading, evaluate};
use retrocomp_analysis::laser_import::parse_readings;
use retrocomp_analysis::table::Direction;

fn fixture(name: &str) -> Vec<Reading> {
    let path = format!(
        "{}/tests/fixtures/analysis/{name}",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap();
    parse_readings(&path, &text).unwrap()
}

/// Asad Ullah (2013) Table 6.1 δzz F/R (p. 6x, digest §3.1): E ≈ 11.6 µm, B ≈ 5.1 µm at 180 mm.
#[test]
fn asad_ullah_table_6_1_z_axis() {
    let rep = evaluate(&fixture("asadullah_z_iso230_2.csv")).unwrap();
    let a = &rep.axis;
    assert_eq!(rep.targets.len(), 18);
    assert!((a.e_um - 11.6).abs() < 0.05, "E = {}", a.e_um);
    assert!((a.b_um - 5.1).abs() < 0.05, "B = {}", a.b_um);
    let worst = rep
        .targets
        .iter()
        .max_by(|p, q| p.reversal_um.abs().total_cmp(&q.reversal_um.abs()))
        .unwrap();
    assert_eq!(worst.target_mm, 180.0);
    assert!((a.e_up_um - 10.3).abs() < 0.05 && (a.e_down_um - 10.0).abs() < 0.05);
    // Mean-only data: s, R and A are undefined and must not be invented.
    assert_eq!(
        (a.r_um, a.a_um, a.r_up_um, a.a_down_um),
        (None, None, None, None)
    );
    assert!(rep.note.is_some());
}

/// Asad Ullah (2013) Table 6.2 δxx F/R (digest §3.2): E ≈ 31.8 µm, B ≈ 9.8 µm.
#[test]
fn asad_ullah_table_6_2_x_axis() {
    let rep = evaluate(&fixture("asadullah_x_iso230_2.csv")).unwrap();
    let a = &rep.axis;
    assert!((a.e_um - 31.8).abs() < 0.05, "E = {}", a.e_um);
    assert!((a.b_um - 9.8).abs() < 0.05, "B = {}", a.b_um);
    assert!((a.e_up_um - 22.9).abs() < 0.05 && (a.e_down_um - 30.3).abs() < 0.05);
    assert!((a.b_mean_um - 7.45).abs() < 0.01, "B̄ = {}", a.b_mean_um);
}

#[test]
fn json_keys_follow_the_contract_and_undefined_values_are_null() {
    let rep = evaluate(&fixture("asadullah_z_iso230_2.csv")).unwrap();
    let v = serde_json::to_value(&rep).unwrap();
    assert_eq!(v["standard"], "ISO 230-2:2014");
    for k in ["E_um", "E_up_um", "E_down_um", "M_um", "B_um", "B_mean_um"] {
        assert!(v["axis"][k].is_number(), "{k}");
    }
    assert!(v["axis"]["R_um"].is_null());
    assert!(v["axis"]["A_um"].is_null());
}

fn readings_strategy() -> impl Strategy<Value = Vec<Reading>> {
    (2usize..8, 2u32..6).prop_flat_map(|(m, n)| {
        prop::collection::vec(-50.0f64..50.0, m * n as usize * 2).prop_map(move |xs| {
            let mut out = Vec::new();
            let mut k = 0;
            for i in 0..m {
                for run in 1..=n {
                    for d in [Direction::Forward, Direction::Reverse] {
                        out.push(Reading {
                            target_mm: 25.0 * i as f64,
                            run,
                            direction: d,
                            deviation_um: xs[k],
                        });
                        k += 1;
                    }
                }
            }
            out
        })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn bidirectional_invariants(rs in readings_strategy()) {
        let a = evaluate(&rs).unwrap().axis;
        let eps = 1e-9;
        prop_assert!(a.e_um + eps >= a.e_up_um.max(a.e_down_um));
        prop_assert!(a.m_um <= a.e_um + eps);
        let (r, ru, rd) = (a.r_um.unwrap(), a.r_up_um.unwrap(), a.r_down_um.unwrap());
        prop_assert!(r + eps >= ru.max(rd));
        let (aa, au, ad) = (a.a_um.unwrap(), a.a_up_um.unwrap(), a.a_down_um.unwrap());
        prop_assert!(aa + eps >= au.max(ad));
        prop_assert!(a.b_um + eps >= a.b_mean_um.abs());
        prop_assert!(aa + eps >= a.e_um);
    }
}
