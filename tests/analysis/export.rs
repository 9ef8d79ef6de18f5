//! Controller-table export formats: Fanuc pitch tape (Asad Ullah 2013 Table 7.2), LinuxCNC comp
//! files and ISG CSV; round trips and located errors.

use proptest::prelude::*;
use retrocomp_analysis::export::fanuc::{
    FanucAxisConfig, cumulative_sum, from_fanuc, read_tape, to_fanuc, write_tape,
};
use retrocomp_analysis::export::isg::{AxisErrorMotions, read_isg, write_isg};
use retrocomp_analysis::export::linuxcnc::{CompFileType, read_comp, write_comp};
use retrocomp_analysis::table::{BidirectionalTable, Direction};

fn fixture(name: &str) -> (String, String) {
    let path = format!(
        "{}/tests/fixtures/analysis/{name}",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap();
    (path, text)
}

/// Asad Ullah (2013) Table 7.2 (MV-1060, digest §3.7): X values sum to +36, Y to +12 (Y peaks at
/// +13); points are 20 mm apart with the reference point at machine zero.
#[test]
fn table_7_2_imports_with_the_thesis_cumulative_sums() {
    let (path, text) = fixture("asadullah_table_7_2.tape");
    let axes = read_tape(&path, &text).unwrap();
    assert_eq!(axes.len(), 3);
    let (x, y) = (&axes[0], &axes[1]);
    assert_eq!(
        (
            x.p3620_ref_point,
            x.p3624_interval_units,
            x.p1851_backlash_units
        ),
        (100, 20000, 0)
    );
    assert_eq!((y.p3620_ref_point, y.p1851_backlash_units), (200, 2));
    assert_eq!(cumulative_sum(x), 36);
    assert_eq!(cumulative_sum(y), 12);
    assert!(
        axes[2].values.is_empty(),
        "the thesis lists no Z pitch values"
    );

    let tx = from_fanuc(x, 1.0, 0.0).unwrap();
    // Point 50 (−1000 mm) to point 101 (+20 mm); correction rises by 36 µm, so error falls by 36.
    assert_eq!(tx.positions_mm[0], -1000.0);
    assert_eq!(*tx.positions_mm.last().unwrap(), 20.0);
    assert_eq!(
        tx.error_um(-1000.0, Direction::Forward) - tx.error_um(20.0, Direction::Forward),
        36.0
    );
    assert_eq!(
        tx.error_um(0.0, Direction::Forward),
        0.0,
        "zero at the reference point"
    );
    let ty = from_fanuc(y, 1.0, 0.0).unwrap();
    let corr_y: Vec<f64> = ty
        .mean_um()
        .iter()
        .map(|e| -(e - ty.mean_um()[0]))
        .collect();
    assert_eq!(
        corr_y.iter().cloned().fold(f64::MIN, f64::max),
        13.0,
        "Y peaks at +13"
    );
    // Backlash 2 units on Y: reverse − forward = lost motion.
    assert_eq!(ty.reverse_um[3] - ty.forward_um[3], 2.0);
}

#[test]
fn fanuc_tape_round_trips_textually_and_numerically() {
    let (path, text) = fixture("asadullah_table_7_2.tape");
    let axes = read_tape(&path, &text).unwrap();
    let written = write_tape(&axes);
    assert_eq!(read_tape("rewritten", &written).unwrap(), axes);

    // Table → Fanuc → table: the error at every grid point is within half a detection unit.
    let pos: Vec<f64> = (0..=25).map(|i| -500.0 + 20.0 * f64::from(i)).collect();
    let f: Vec<f64> = pos
        .iter()
        .map(|p| 8.0 * (p / 90.0).sin() + 0.013 * p)
        .collect();
    let r: Vec<f64> = f.iter().map(|v| v + 3.0).collect();
    let t = BidirectionalTable::new(pos.clone(), f, r).unwrap();
    let cfg = FanucAxisConfig {
        axis: 1,
        ref_point: 60,
        ref_position_mm: 0.0,
        interval_mm: 20.0,
        detection_unit_um: 1.0,
        magnification: 1,
        max_abs_value: 127,
    };
    let ax = to_fanuc(&t, &cfg).unwrap();
    assert_eq!(ax.p1851_backlash_units, 3);
    let back = from_fanuc(&read_tape("x", &write_tape(&[ax])).unwrap()[0], 1.0, 0.0).unwrap();
    // The error at the reference (0 mm) travels in 1850, so the absolute error comes back: two
    // roundings (pitch cumulative, shift) of half a unit each.
    for p in &pos {
        let want = 0.5 * (t.error_um(*p, Direction::Forward) + t.error_um(*p, Direction::Reverse));
        let got =
            0.5 * (back.error_um(*p, Direction::Forward) + back.error_um(*p, Direction::Reverse));
        assert!((got - want).abs() <= 1.0 + 1e-9, "at {p}: {got} vs {want}");
    }
}

/// Issue 13.5: the points are exactly those Fanuc's formula gives for the travel
/// (3621 = 3620 − negative travel/interval + 1, 3622 = 3620 + positive travel/interval), for
/// grid-aligned and unaligned ends, and the error at the reference point goes to 1850.
#[test]
fn fanuc_points_follow_the_formula_and_the_reference_error_goes_to_1850() {
    let cfg = FanucAxisConfig {
        axis: 1,
        ref_point: 60,
        ref_position_mm: 0.0,
        interval_mm: 20.0,
        detection_unit_um: 1.0,
        magnification: 1,
        max_abs_value: 127,
    };
    let table = |lo: f64, hi: f64, e_ref: f64| {
        let n = 13;
        let pos: Vec<f64> = (0..n)
            .map(|i| lo + (hi - lo) * f64::from(i) / f64::from(n - 1))
            .collect();
        // Linear error through e_ref at 0 mm, 0.05 µm/mm.
        let e: Vec<f64> = pos.iter().map(|p| e_ref + 0.05 * p).collect();
        BidirectionalTable::new(pos, e.clone(), e).unwrap()
    };
    // Travel −400 … +200 mm on the grid: 20 intervals below, 10 above.
    let ax = to_fanuc(&table(-400.0, 200.0, 7.4), &cfg).unwrap();
    assert_eq!(
        (ax.p3621_min_point, ax.p3622_max_point),
        (60 - 20 + 1, 60 + 10)
    );
    assert_eq!(
        ax.values.len(),
        30,
        "one value per 20 mm segment of the 600 mm travel"
    );
    assert_eq!(
        ax.p1850_ref_shift_units, -7,
        "−error at the reference, rounded"
    );
    // Unaligned ends round outward: −390 … +185 needs the same points.
    let ax2 = to_fanuc(&table(-390.0, 185.0, -3.6), &cfg).unwrap();
    assert_eq!((ax2.p3621_min_point, ax2.p3622_max_point), (41, 70));
    assert_eq!(ax2.p1850_ref_shift_units, 4);
    // The tape carries 1850 and reads back.
    let tape = write_tape(std::slice::from_ref(&ax));
    assert!(tape.contains("N1850 A1 P-7\n"), "{tape}");
    assert_eq!(read_tape("t", &tape).unwrap()[0], ax);
    // The lowest segment is carried by point 3621 (−400 → −380 mm: 20 mm × 0.05 = 1 µm error
    // rise → correction −1 unit).
    assert_eq!(ax.values[&41], -1);
}

#[test]
fn fanuc_tape_errors_are_located() {
    let text = "%\nN3620 A1 P10\nN3621 A1 P1\nN3622 A1 P12\nN3623 A1 P1\nN3624 A1 P1000\nN1851 A1 P0\nN10005 Px\nN10050 P1\nN9999 A1 P1\n%\n";
    let err = read_tape("t.tape", text).unwrap_err();
    let s: Vec<String> = err.0.iter().map(ToString::to_string).collect();
    assert_eq!(s.len(), 3, "{s:?}");
    assert!(s.iter().any(|m| m.starts_with("t.tape:8: column `Px`")));
    assert!(
        s.iter()
            .any(|m| m.starts_with("t.tape:9: column `N10050`") && m.contains("no axis"))
    );
    assert!(s.iter().any(|m| m.starts_with("t.tape:10: column `N9999`")));
}

#[test]
fn linuxcnc_both_types_round_trip_and_sign_is_locked() {
    let t = BidirectionalTable::new(
        vec![0.0, 100.0, 200.0],
        vec![0.0, 5.0, -2.5],
        vec![1.0, 6.5, -1.0],
    )
    .unwrap();
    // Type 0 holds actual positions: +5 µm error at 100 mm means the axis reaches 100.005.
    let s0 = write_comp(&t, CompFileType::Actual).unwrap();
    assert!(
        s0.lines()
            .nth(1)
            .unwrap()
            .starts_with("100.000000 100.005000 100.006500"),
        "{s0}"
    );
    // Type 1 holds nominal − actual = correction.
    let s1 = write_comp(&t, CompFileType::Offset).unwrap();
    assert!(
        s1.lines()
            .nth(1)
            .unwrap()
            .starts_with("100.000000 -0.005000 -0.006500"),
        "{s1}"
    );
    for (s, k) in [(s0, CompFileType::Actual), (s1, CompFileType::Offset)] {
        let back = read_comp("c", &s, k).unwrap();
        for i in 0..3 {
            assert!((back.forward_um[i] - t.forward_um[i]).abs() < 1e-3);
            assert!((back.reverse_um[i] - t.reverse_um[i]).abs() < 1e-3);
        }
    }
    let err = read_comp(
        "bad.comp",
        "0 0 0\n# c\n-1 0 0\n5 1\n",
        CompFileType::Actual,
    )
    .unwrap_err();
    assert_eq!(err.0.len(), 2);
    assert_eq!((err.0[0].line, err.0[1].line), (3, 4));
}

#[test]
fn isg_round_trip_and_header_check() {
    let m = AxisErrorMotions {
        axis: 'X',
        positions_mm: vec![0.0, 50.0, 100.0],
        translations_um: [
            vec![0.0, 1.5, 3.0],
            vec![0.2, -0.4, 0.1],
            vec![0.0, 0.0, -0.7],
        ],
        rotations_urad: [
            vec![1.0, 2.0, 3.0],
            vec![0.0, -5.0, -9.0],
            vec![4.0, 4.0, 4.0],
        ],
    };
    let s = write_isg(&m);
    assert!(s.lines().nth(1).unwrap() == "X EXX EYX EZX EAX EBX ECX");
    assert_eq!(read_isg("x.csv", &s).unwrap(), m);
    let semi = s.replace(' ', ";").replace("#;", "# ");
    assert_eq!(read_isg("x.csv", &semi).unwrap(), m);
    let err = read_isg("y.csv", "Y EXY EYY EZY EAY EBY\n").unwrap_err();
    assert!(err.0[0].to_string().starts_with("y.csv:1:"));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]
    /// Carried rounding: the cumulative Fanuc table never drifts more than half a unit from the
    /// exact correction, for any error curve (per-increment rounding would).
    #[test]
    fn fanuc_cumulative_rounding_bounded(errs in prop::collection::vec(-40.0f64..40.0, 3..60)) {
        let pos: Vec<f64> = (0..errs.len()).map(|i| 20.0 * i as f64).collect();
        let t = BidirectionalTable::unidirectional(pos.clone(), errs.clone()).unwrap();
        let cfg = FanucAxisConfig { axis: 1, ref_point: 1, ref_position_mm: 0.0, interval_mm: 20.0, detection_unit_um: 1.0, magnification: 1, max_abs_value: 1000 };
        let ax = to_fanuc(&t, &cfg).unwrap();
        let mut cum = 0i64;
        for (i, e) in errs.iter().enumerate().skip(1) {
            cum += ax.values[&(1 + i as u32)];
            let exact = -(e - errs[0]);
            prop_assert!((cum as f64 - exact).abs() <= 0.5 + 1e-9);
        }
    }
}
