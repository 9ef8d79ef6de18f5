//! `retrocomp fit thermal`'s compensation options, written and read back (docs/diagnose.md,
//! "Compensation model"): a fit on what a base model leaves (`--residual`), a heat source seen
//! only through `rpm` (`--drivers rpm^2`), a sensor the base model already reads unlagged entered
//! again through a lag (a lag state of its own), and `--criterion average`. The model as written,
//! evaluated by the same code the gateway and `diagnose --model` use, must predict what the
//! regression predicts, and the written model must carry where its lags stood at the last row.

use retrocomp_analysis::diagnose::model_sim::{final_lag_state, simulate_axes};
use retrocomp_analysis::fit::regression::{Criterion, first_order_lag};
use retrocomp_analysis::fit::to_model::{add_thermal, to_checked_toml};
use retrocomp_analysis::fit::workflow::{ContextOptions, Driver, fit_context_with, source_values};
use retrocomp_model::MachineModel;
use retrocomp_model::parse_component;
use retrocomp_model::recording::Recording;

/// Base: EXX = 2 µm/K · (T_a − 20). Truth adds 3e-7 µm/rpm² through a 600 s lag of rpm² and
/// 1.5 µm/K through a 1200 s lag of T_a.
const BASE: &str = "schema = 1\n[machine]\nname = \"base\"\nchain = \"X F Y Z\"\ntool_axis = \"-z\"\n\
    [axes.x]\n[axes.y]\n[axes.z]\n[[tools]]\nname = \"tool\"\noffset_mm = [0.0, 0.0, 0.0]\n\
    [[sensors]]\nname = \"a\"\nreference_C = 20.0\n\
    [[thermal]]\nname = \"base\"\ntarget = \"EXX\"\nkind = \"polynomial_dt\"\nsensors = [\"a\"]\n\
    e0_um = 0.0\nb_um_per_K = [2.0]\n";

fn recording() -> Recording {
    let n = 4000;
    let t: Vec<f64> = (0..n).map(|i| 15.0 * i as f64).collect();
    let rpm: Vec<f64> = t
        .iter()
        .map(|t| match (t / 7200.0) as u32 % 4 {
            0 => 0.0,
            1 => 2000.0,
            2 => 0.0,
            _ => 4000.0,
        })
        .collect();
    let heat = first_order_lag(&t, &rpm.iter().map(|r| r * r).collect::<Vec<_>>(), 1800.0);
    let ta: Vec<f64> = heat.iter().map(|h| 20.0 + 5e-7 * h).collect();
    let rpm_lag = first_order_lag(&t, &rpm.iter().map(|r| r * r).collect::<Vec<_>>(), 600.0);
    let ta_lag = first_order_lag(&t, &ta, 1200.0);
    let mut csv = String::from("t_s,rpm,T_a_C,ex_um\n");
    for i in 0..n {
        let wiggle = 0.05 * ((i * 7919) % 13) as f64 / 13.0;
        let ex = 2.0 * (ta[i] - 20.0) + 3e-7 * rpm_lag[i] + 1.5 * (ta_lag[i] - 20.0) + wiggle;
        csv.push_str(&format!("{},{},{},{ex}\n", t[i], rpm[i], ta[i]));
    }
    Recording::read_strict(csv.as_bytes(), "synthetic.csv").unwrap()
}

#[test]
fn residual_fit_with_an_rpm_driver_evaluates_like_the_regression() {
    let rec = recording();
    let base = MachineModel::from_toml_str(BASE, "base.toml").unwrap();
    let base_um = simulate_axes(&base, &rec).unwrap()[0].clone();
    let drivers = [Driver {
        column: "rpm".into(),
        exponent: 2.0,
    }];
    for criterion in [Criterion::Bic, Criterion::Average] {
        let fit = fit_context_with(
            &rec,
            "ex_um",
            &ContextOptions {
                use_temperatures: true,
                use_strains: false,
                lags_s: &[0.0, 600.0, 1200.0],
                max_terms: 2,
                criterion,
                heldout_runs: &[],
                drivers: &drivers,
                base_um: Some(&base_um),
                refit_all: true,
            },
        )
        .unwrap();
        let signals: Vec<(&str, f64)> = fit
            .model
            .terms
            .iter()
            .map(|t| (t.signal.as_str(), t.tau_s))
            .collect();
        // The two true sources are found: rpm² through its 600 s lag, T_a through 1200 s.
        assert!(
            signals.contains(&("rpm^2", 600.0)),
            "{criterion:?}: {signals:?}"
        );
        assert!(
            signals.contains(&("T_a_C", 1200.0)),
            "{criterion:?}: {signals:?}"
        );
        assert_eq!(fit.model_rows, "all");
        let mut spec = base.spec().clone();
        let mean = |name: &str| fit.means.iter().find(|(s, _)| s == name).unwrap().1;
        add_thermal(&mut spec, &fit, parse_component("EXX").unwrap(), &mean).unwrap();
        // T_a is read unlagged by the base model: its lag is a sensor of its own on T_a_C.
        let alias = spec
            .sensors
            .iter()
            .find(|s| s.name == "a_tau_1200s")
            .unwrap();
        assert_eq!(alias.column.as_deref(), Some("T_a_C"));
        let driver = spec
            .sensors
            .iter()
            .find(|s| s.name == "rpm_sq_tau_600s")
            .unwrap();
        assert_eq!(
            (driver.column.as_deref(), driver.exponent),
            (Some("rpm"), Some(2.0))
        );
        spec.lag_state = final_lag_state(&MachineModel::from_spec(spec.clone()), &rec).unwrap();
        let (_, model) = to_checked_toml(spec).unwrap();
        assert!(model.spec().lag_state.is_some());
        let written = simulate_axes(&model, &rec).unwrap()[0].clone();
        // The regression's own terms, built from the fit's own regressor (`first_order_lag`):
        // the box's lag and the fit's are one convention (`models::lag`), so no shift is allowed.
        let t = rec.t_s();
        let mut regression = vec![fit.model.intercept_um; t.len()];
        for term in &fit.model.terms {
            let u = source_values(&rec, &term.signal).unwrap();
            let v = first_order_lag(t, &u, term.tau_s);
            regression
                .iter_mut()
                .zip(v)
                .for_each(|(r, v)| *r += term.coef * v);
        }
        let worst = written
            .iter()
            .zip(base_um.iter().zip(&regression))
            .map(|(w, (b, r))| (w - b - r).abs())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-6,
            "{criterion:?}: written model differs by {worst} µm"
        );
        // And it explains the recording. With one size (BIC) what is left is the 0.05 µm
        // wiggle; the mean of sizes 1 and 2 keeps half of the one-term fit's miss.
        let ex = rec.col("ex_um").unwrap();
        let rms = |v: &mut dyn Iterator<Item = f64>| {
            let (s, n) = v.fold((0.0, 0.0), |(s, n), x| (s + x * x, n + 1.0));
            (s / n).sqrt()
        };
        let left = rms(&mut ex.iter().zip(&written).map(|(e, w)| e - w));
        let base_left = rms(&mut ex.iter().zip(&base_um).map(|(e, b)| e - b));
        let bar = match criterion {
            Criterion::Average => 0.1 * base_left,
            _ => 0.05,
        };
        assert!(
            left < bar,
            "{criterion:?}: residual RMS {left} µm (base model alone {base_left} µm)"
        );
    }
}

/// `retrocomp fit thermal ARGS…` must fail before reading anything; its stderr.
fn refused(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["fit", "thermal", "none.csv", "--signal", "ex_um"])
        .args(args)
        .output()
        .unwrap();
    assert!(!out.status.success(), "{args:?} was accepted");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The CLI refuses what it cannot honour, before reading anything: `--residual` without a base
/// model, a driver power outside (0, 4].
#[test]
fn cli_refuses_a_residual_without_base_and_a_bad_driver_power() {
    let err = refused(&["--residual"]);
    assert!(err.contains("--base-model"), "{err}");
    let err = refused(&["--drivers", "rpm^9"]);
    assert!(
        err.contains("`rpm^9`: the power must be a number in (0, 4]"),
        "{err}"
    );
}
