//! Fitting on synthetic data with known truth (hil-sim recordings are not available in this
//! branch yet): piecewise-quadratic axis tables, thermal regression with lags and sensor
//! selection, load regression on strain; each validated on held-out data with Spaan's δ.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use retrocomp_analysis::fit::regression::{Criterion, first_order_lag};
use retrocomp_analysis::fit::workflow::{fit_axis, fit_context};
use retrocomp_analysis::iso230_2::Reading;
use retrocomp_analysis::table::Direction;
use retrocomp_model::recording::Recording;

fn truth_axis(x: f64, d: Direction) -> f64 {
    let b = if d == Direction::Forward { 2.0 } else { -2.0 };
    0.02 * x + 8e-5 * (x - 300.0f64).max(0.0).powi(2) + b
}

#[test]
fn axis_fit_recovers_the_curve_and_validates_on_a_held_out_run() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut rs = Vec::new();
    for run in 1..=5 {
        for i in 0..=25 {
            let x = 20.0 * f64::from(i);
            for d in [Direction::Forward, Direction::Reverse] {
                rs.push(Reading {
                    target_mm: x,
                    run,
                    direction: d,
                    deviation_um: truth_axis(x, d) + rng.random_range(-0.3..0.3),
                });
            }
        }
    }
    let f = fit_axis(&rs, 50.0, 1e-4, Some(5)).unwrap();
    let h = f.heldout.unwrap();
    assert!(h.delta > 0.9, "δ = {}", h.delta);
    assert!(
        h.max_residual_um < 0.8,
        "max residual {}",
        h.max_residual_um
    );
    for x in [0.0, 155.0, 300.0, 420.0, 500.0] {
        assert!(
            (f.forward.eval(x) - truth_axis(x, Direction::Forward)).abs() < 0.4,
            "at {x}"
        );
        assert!(
            (f.reverse.eval(x) - truth_axis(x, Direction::Reverse)).abs() < 0.4,
            "at {x}"
        );
    }
    assert!(
        f.forward.knots_mm.iter().any(|k| (k - 300.0).abs() <= 50.0),
        "{:?}",
        f.forward.knots_mm
    );
    assert!(fit_axis(&rs, 50.0, 1e-4, Some(9)).is_err());
}

/// A recording (docs/recording-csv.md columns) with six temperature sensors, two strains, and an X error
/// that follows T_spindle through a 600 s lag and T_column directly.
fn recording(seed: u64) -> String {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = 1440; // 8 h at 20 s
    let t: Vec<f64> = (0..n).map(|i| 20.0 * i as f64).collect();
    // Spindle: speed steps every 40 min heat the spindle sensor (itself a 300 s lag).
    let mut heat = Vec::with_capacity(n);
    let mut level = 0.0;
    for (i, _) in t.iter().enumerate() {
        if i % 120 == 0 {
            level = rng.random_range(0.0..8.0);
        }
        heat.push(22.0 + level);
    }
    let spindle = first_order_lag(&t, &heat, 300.0);
    let column: Vec<f64> = t
        .iter()
        .map(|s| 21.0 + 1.5 * (s / 9000.0).sin() + 0.4 * (s / 2100.0).cos())
        .collect();
    let ambient: Vec<f64> = t.iter().map(|s| 20.0 + 1.0 * (s / 15000.0).sin()).collect();
    let base: Vec<f64> = ambient
        .iter()
        .zip(&column)
        .map(|(a, c)| 0.5 * a + 0.5 * c + 0.3 * (a - 20.0).powi(2))
        .collect();
    let motor: Vec<f64> = t
        .iter()
        .map(|s| 25.0 + 2.0 * (s / 5000.0 + 1.0).sin())
        .collect();
    let coolant: Vec<f64> = t.iter().map(|s| 19.0 + 0.5 * (s / 3000.0).cos()).collect();
    let strain_guide: Vec<f64> = t
        .iter()
        .map(|s| {
            if ((s / 1800.0) as i64) % 2 == 0 {
                40.0
            } else {
                120.0
            }
        })
        .collect();
    let strain_decoy: Vec<f64> = t.iter().map(|s| 50.0 + 10.0 * (s / 700.0).sin()).collect();
    let lagged = first_order_lag(&t, &spindle, 600.0);
    let mut s = String::from(
        "t_s,x_mm,ex_um,ey_um,T_spindle_C,T_column_C,T_ambient_C,T_base_C,T_motor_C,T_coolant_C,strain_guide_ue,strain_decoy_ue,run\n",
    );
    for i in 0..n {
        let ex =
            1.5 + 3.0 * (lagged[i] - 22.0) - 2.0 * (column[i] - 21.0) + rng.random_range(-0.2..0.2);
        let ey = 0.05 * strain_guide[i] + rng.random_range(-0.2..0.2);
        let run = 1 + i / 360;
        s.push_str(&format!(
            "{},{},{ex:.4},{ey:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{:.3},{run}\n",
            t[i],
            100.0,
            spindle[i],
            column[i],
            ambient[i],
            base[i],
            motor[i],
            coolant[i],
            strain_guide[i],
            strain_decoy[i]
        ));
    }
    s
}

#[test]
fn thermal_fit_selects_the_true_sensors_and_lag() {
    let rec = Recording::read_strict(recording(2).as_bytes(), "rec.csv").unwrap();
    for crit in [Criterion::Bic, Criterion::Cp] {
        let f = fit_context(
            &rec,
            "ex_um",
            true,
            false,
            &[0.0, 600.0, 1800.0],
            3,
            crit,
            &[4],
        )
        .unwrap();
        let mut got: Vec<(String, f64)> = f
            .model
            .terms
            .iter()
            .map(|t| (t.signal.clone(), t.tau_s))
            .collect();
        got.sort_by(|a, b| a.0.cmp(&b.0));
        assert_eq!(
            got,
            vec![
                ("T_column_C".to_string(), 0.0),
                ("T_spindle_C".to_string(), 600.0)
            ],
            "{crit:?}: {:?}",
            f.selection.path
        );
        let coef = |name: &str| {
            f.model
                .terms
                .iter()
                .find(|t| t.signal == name)
                .unwrap()
                .coef
        };
        assert!((coef("T_spindle_C") - 3.0).abs() < 0.15 && (coef("T_column_C") + 2.0).abs() < 0.1);
        assert!(f.heldout.delta > 0.9, "δ = {}", f.heldout.delta);
        assert!(f.heldout.max_residual_um < 0.6);
        assert_eq!(f.heldout_rule, "runs [4]");
    }
}

#[test]
fn load_fit_uses_the_guide_strain() {
    let rec = Recording::read_strict(recording(3).as_bytes(), "rec.csv").unwrap();
    let f = fit_context(&rec, "ey_um", false, true, &[0.0], 2, Criterion::Bic, &[]).unwrap();
    assert_eq!(f.model.terms.len(), 1);
    assert_eq!(f.model.terms[0].signal, "strain_guide_ue");
    assert!((f.model.terms[0].coef - 0.05).abs() < 0.002);
    assert_eq!(f.heldout_rule, "last 30 % of samples");
    assert!(f.heldout.delta > 0.95);
}

#[test]
fn recording_errors_are_located() {
    let e = Recording::read_strict("t_s,ex_um\n0,1\n1,x\n2,3\n0.5,2\n".as_bytes(), "r.csv")
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("r.csv: 2 bad row(s)"), "{e}");
    assert!(
        e.contains("line 3, column `ex_um`: `x` is not a number"),
        "{e}"
    );
    assert!(
        e.contains("line 5, column `t_s`: time goes backwards (0.5 after 2)"),
        "{e}"
    );
}

mod to_model {
    use super::*;
    use retrocomp_analysis::fit::to_model::{
        AxisForm, add_load, add_thermal, axis_component, put_component, single_axis_spec,
        to_checked_toml,
    };
    use retrocomp_model::parse_component;
    use retrocomp_model::{Axis, MachineModel};

    fn runs() -> Vec<Reading> {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut rs = Vec::new();
        for run in 1..=4 {
            for i in 0..=25 {
                let x = 20.0 * f64::from(i);
                for d in [Direction::Forward, Direction::Reverse] {
                    rs.push(Reading {
                        target_mm: x,
                        run,
                        direction: d,
                        deviation_um: truth_axis(x, d) + rng.random_range(-0.2..0.2),
                    });
                }
            }
        }
        rs
    }

    fn eval(
        m: &MachineModel,
        x: f64,
        dir: i8,
        temps: &[f64],
        strains: &[f64],
        t_s: f64,
        state: &mut retrocomp_model::ModelState,
    ) -> [f64; 3] {
        let mut input = m.new_input();
        input.pos_mm = [x, 0.0, 0.0];
        input.dir = [dir, 0, 0];
        input.t_s = t_s;
        if !temps.is_empty() {
            input.temps_c = temps.to_vec();
        }
        if !strains.is_empty() {
            input.strains_ue = strains.to_vec();
        }
        let mut out = m.new_breakdown();
        m.evaluate(&input, state, &mut out);
        out.total_um
    }

    /// The written model reproduces the fit with the documented sign (model ex = +EXX), in both
    /// forms, and passes the model's own validating parser.
    #[test]
    fn axis_fit_writes_a_model_that_evaluates_to_the_fit() {
        let rs = runs();
        let fit = fit_axis(&rs, 50.0, 1e-4, None).unwrap();
        let targets: Vec<f64> = rs.iter().map(|r| r.target_mm).collect();
        let id = parse_component("EXX").unwrap();
        for form in [AxisForm::Table, AxisForm::Piecewise] {
            let mut spec = single_axis_spec("fit", Axis::X, (0.0, 500.0));
            put_component(&mut spec, axis_component(&fit, id, form, &targets).unwrap()).unwrap();
            let (toml, m) = to_checked_toml(spec).unwrap();
            assert!(toml.contains("EXX"));
            let mut st = m.new_state();
            for x in [0.0, 140.0, 300.0, 460.0] {
                let (f, r) = (
                    eval(&m, x, 1, &[], &[], 0.0, &mut st)[0],
                    eval(&m, x, -1, &[], &[], 0.0, &mut st)[0],
                );
                match form {
                    AxisForm::Table => {
                        assert!(
                            (f - fit.forward.eval(x)).abs() < 1e-3
                                && (r - fit.reverse.eval(x)).abs() < 1e-3,
                            "{form:?} at {x}: {f} {r}"
                        );
                    }
                    AxisForm::Piecewise => {
                        let mean = 0.5 * (fit.forward.eval(x) + fit.reverse.eval(x));
                        assert!(
                            (f - mean).abs() < 1e-6 && (r - mean).abs() < 1e-6,
                            "{form:?} at {x}"
                        );
                    }
                }
            }
        }
    }

    /// Thermal and load terms written into the model predict what the regression predicts.
    #[test]
    fn thermal_and_load_terms_evaluate_like_the_regression() {
        let rec = Recording::read_strict(recording(5).as_bytes(), "rec.csv").unwrap();
        let fit_t = fit_context(
            &rec,
            "ex_um",
            true,
            false,
            &[0.0, 600.0],
            2,
            Criterion::Bic,
            &[4],
        )
        .unwrap();
        let fit_l =
            fit_context(&rec, "ex_um", false, true, &[0.0], 1, Criterion::Bic, &[4]).unwrap();
        let mut spec = single_axis_spec("base", Axis::X, (0.0, 500.0));
        let mean = |name: &str| {
            let v = rec.col(name).unwrap();
            v.iter().sum::<f64>() / v.len() as f64
        };
        add_thermal(&mut spec, &fit_t, parse_component("EXX").unwrap(), &mean).unwrap();
        let (_, m) = to_checked_toml(spec.clone()).unwrap();
        let t = rec.t_s();
        let pred = fit_t
            .model
            .predict(t, &|n: &str| rec.col(n).map(<[f64]>::to_vec))
            .unwrap();
        let sensors: Vec<String> = m.temperature_sensors().to_vec();
        let mut st = m.new_state();
        let mut worst = 0.0f64;
        for i in 0..t.len() {
            let temps: Vec<f64> = sensors
                .iter()
                .map(|s| rec.col(&format!("T_{s}_C")).unwrap()[i])
                .collect();
            let e = eval(&m, 100.0, 1, &temps, &[], t[i], &mut st)[0];
            worst = worst.max((e - pred[i]).abs());
        }
        // The model's lag and the regression's lag discretise the same ODE; they agree to 0.3 µm.
        assert!(worst < 0.3, "worst {worst}");

        let mut spec_l = single_axis_spec("base", Axis::X, (0.0, 500.0));
        add_load(&mut spec_l, &fit_l, parse_component("EXX").unwrap()).unwrap();
        let (_, ml) = to_checked_toml(spec_l).unwrap();
        let pred_l = fit_l
            .model
            .predict(t, &|n: &str| rec.col(n).map(<[f64]>::to_vec))
            .unwrap();
        let chans: Vec<String> = ml.strain_channels().to_vec();
        let mut st = ml.new_state();
        for i in (0..t.len()).step_by(97) {
            let strains: Vec<f64> = chans
                .iter()
                .map(|s| rec.col(&format!("strain_{s}_ue")).unwrap()[i])
                .collect();
            let e = eval(&ml, 100.0, 1, &[], &strains, t[i], &mut st)[0];
            assert!((e - pred_l[i]).abs() < 1e-6, "{e} vs {}", pred_l[i]);
        }
    }
}
