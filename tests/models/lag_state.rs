//! `[lag_state]`: a model that stores where its lags stood at the last row of the recording it was
//! fitted on continues that recording exactly (`MachineModel::new_state_at`, used by `retrocomp
//! eval`), reads and writes back unchanged, and is ignored when the new recording does not start
//! after the stored time. Temperatures °C, rpm, errors µm.

use retrocomp_model::{LagStart, MachineModel, ModelState};

const MODEL: &str = r#"
schema = 1
[machine]
name = "lagged"
chain = "X F Y Z"

[[tools]]
name = "T1"
offset_mm = [0.0, 0.0, 0.0]

[[sensors]]
name = "col"
reference_C = 20.0
tau_s = 900.0

[[sensors]]
name = "spindle_heat"
reference_C = 0.0
tau_s = 1500.0
column = "rpm"
exponent = 2.0

[[sensors]]
name = "bed"
reference_C = 20.0

[[thermal]]
name = "growth"
target = "EZZ"
kind = "polynomial_dt"
sensors = ["col", "spindle_heat", "bed"]
e0_um = 0.5
b_um_per_K = [3.0, 2.0e-7, -1.5]
"#;

/// Row i of a run sampled every 15 s: the column warms and cools, rpm steps, the bed drifts.
fn row(i: usize) -> (f64, [f64; 3]) {
    let t = 15.0 * i as f64;
    let col = 22.0 + 3.0 * (t / 7200.0).sin();
    let rpm = [0.0, 2500.0, 5000.0, 1250.0][(i / 300) % 4];
    let bed = 20.0 + t / 36000.0;
    (t, [col, rpm, bed])
}

/// ez (µm) at rows `rows`, from `state`.
fn run(m: &MachineModel, state: &mut ModelState, rows: std::ops::Range<usize>) -> Vec<f64> {
    let mut input = m.new_input();
    let mut out = m.new_breakdown();
    rows.map(|i| {
        let (t, temps) = row(i);
        input.t_s = t;
        input.temps_c[..3].copy_from_slice(&temps);
        m.evaluate(&input, state, &mut out);
        out.total_um[2]
    })
    .collect()
}

#[test]
fn a_stored_lag_state_continues_the_recording_as_if_it_had_been_fed_from_the_start() {
    let m = MachineModel::from_toml_str(MODEL, "lagged").unwrap();
    let (n, k) = (2000, 1100);
    let whole = run(&m, &mut m.new_state(), 0..n);

    // Fitted on rows 0..k: the state after row k − 1 goes into the model and through its TOML.
    let mut state = m.new_state();
    run(&m, &mut state, 0..k);
    let stored = m.lag_state_of(&state, row(k - 1).0);
    assert_eq!(
        stored
            .lagged
            .iter()
            .map(|(s, _)| s.as_str())
            .collect::<Vec<_>>(),
        ["col", "spindle_heat"],
        "only sensors with a lag have a state"
    );
    let mut spec = m.spec().clone();
    spec.lag_state = Some(stored);
    let text = MachineModel::from_spec(spec.clone()).to_toml_string();
    assert!(text.contains("[lag_state]"), "{text}");
    let back = MachineModel::from_toml_str(&text, "written").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(back.spec(), &spec, "the lag state reads back unchanged");

    // A recording that starts at row k, alone.
    let (mut resumed, start) = back.new_state_at(row(k).0);
    assert_eq!(
        start,
        LagStart::Resumed {
            stored_t_s: row(k - 1).0,
            sensors: 2
        }
    );
    let tail = run(&back, &mut resumed, k..n);
    let worst = tail
        .iter()
        .zip(&whole[k..])
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-9, "continued run differs by {worst} µm");

    // Without the stored state the same rows start every lag at its first reading: different.
    let fresh = run(&m, &mut m.new_state(), k..n);
    let first_gap = (fresh[0] - whole[k]).abs();
    assert!(
        first_gap > 0.1,
        "the test must be able to fail: a fresh start differs by only {first_gap} µm at row k"
    );
}

/// The model without a stored state, and with the state after rows 0..k stored.
fn stored_after(k: usize) -> (MachineModel, MachineModel) {
    let m0 = MachineModel::from_toml_str(MODEL, "lagged").unwrap();
    let mut state = m0.new_state();
    run(&m0, &mut state, 0..k);
    let mut spec = m0.spec().clone();
    spec.lag_state = Some(m0.lag_state_of(&state, row(k - 1).0));
    (m0, MachineModel::from_spec(spec))
}

#[test]
fn a_stored_state_is_not_used_for_a_recording_that_starts_at_or_before_it() {
    let (m0, m) = stored_after(900);
    for first in [0usize, 899] {
        let (mut s, start) = m.new_state_at(row(first).0);
        assert_eq!(
            start,
            LagStart::StoredNotBefore {
                stored_t_s: row(899).0
            }
        );
        assert_eq!(
            run(&m, &mut s, first..first + 50),
            run(&m0, &mut m0.new_state(), first..first + 50)
        );
    }
}

#[test]
fn after_a_gap_of_many_time_constants_the_stored_state_has_decayed_to_the_reading() {
    let (m0, m) = stored_after(600);
    // 40 000 s later: 44 τ of the column, 27 τ of the spindle lag.
    let first = 599 + 40_000 / 15;
    let (mut s, start) = m.new_state_at(row(first).0);
    assert!(matches!(start, LagStart::Resumed { sensors: 2, .. }));
    let resumed = run(&m, &mut s, first..first + 1);
    let fresh = run(&m0, &mut m0.new_state(), first..first + 1);
    assert!(
        (resumed[0] - fresh[0]).abs() < 1e-6,
        "{} vs {}",
        resumed[0],
        fresh[0]
    );
}
