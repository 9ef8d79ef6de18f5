//! Which of two equivalent thermal descriptions `diagnose` names (issue 12 items 2, 3, 6).
//!
//! In the `regime` family a `thermal_drift` truth acts on a node temperature that is itself a
//! first-order lag of `rpm`, read through a sensor with its own 15–30 s lag and 0.1 °C steps. A lag
//! of `rpm`, or a lag of the sensor that smooths its steps, fits the recording within a few ΔBIC
//! of the drift and predicts held-out blocks no better. Before the parsimony rule
//! (`select_step.rs`, `prefer_simpler`; and the driver rule needing a held-out gain of its own)
//! these cases came back as lags: regime recall 0.643 on seed 2026. A lag of the sensor with a τ
//! so short that it stays within the reading's 0.1 °C resolution (τ 30 s: seed 7 case 13; case 7
//! until session 17, see below) also predicts 1–2 % better by smoothing the steps; that is the
//! same term as far as the sensor can tell, so the drift is named (`within_resolution`, session
//! 12). The opposite cases must not break: where the heat source is seen ONLY through `rpm`
//! (`rpm_heat`), the lag of rpm is the physics and must still be named; a true lag of a sensor is
//! still named as that lag.

use hil_sim::cases::{Family, generate_family_case};
use retrocomp_analysis::diagnose::effects::EffectModel;
use retrocomp_analysis::diagnose::report::Finding;
use retrocomp_analysis::diagnose::{diagnose, select::Options};

fn param(f: &Finding, key: &str) -> Option<serde_json::Value> {
    f.params.get(key).cloned()
}

/// Each finding as `effect(Some(sensor))`, for the failure messages.
fn named(findings: &[Finding]) -> Vec<String> {
    findings
        .iter()
        .map(|f| format!("{}({:?})", f.effect, param(f, "sensor")))
        .collect()
}

#[test]
fn a_drift_on_a_measured_temperature_is_named_as_that_drift_not_as_the_lag_it_equals() {
    // Regime cases whose truth is `thermal_drift` and that came back `thermal_lag`: seed 2026 (of
    // rpm: 4, 7, 19; of the sensor itself, τ 46 s: 13) before the parsimony rule; seed 7 (of the
    // sensor itself, τ 30 s on the grid, within its 0.1 °C steps: 13) before the resolution
    // rule. Seed 7 case 7 was the resolution rule's other case until session 17: with the lag's
    // reading taken as it arrives (`models::lag`) the winning lag has τ 169 s (CI 51–379 s),
    // ΔBIC 28.8 above the drift and 2 % better held out, beyond the sensor's resolution, so the
    // rule rightly does not apply and the case is a counted miss (docs/diagnose.md).
    for (seed, i) in [(2026, 4), (2026, 7), (2026, 13), (2026, 19), (7, 13)] {
        let (rec, m) = generate_family_case(Family::Regime, seed, i);
        let EffectModel::ThermalDrift { sensor, um_per_k } = &m.hidden[0].model else {
            panic!(
                "regime seed {seed} case {i}: expected a thermal_drift truth, got {:?}",
                m.hidden
            );
        };
        let d = diagnose(&rec, &Options::default()).unwrap();
        let found = named(&d.report.findings);
        let f = d
            .report
            .findings
            .iter()
            .find(|f| f.effect == "thermal_drift" && f.axis == "x")
            .unwrap_or_else(|| {
                panic!(
                    "regime seed {seed} case {i}: truth thermal_drift({sensor}), found {found:?}"
                )
            });
        assert_eq!(
            param(f, "sensor").and_then(|v| v.as_str().map(str::to_string)),
            Some(sensor.clone()),
            "regime seed {seed} case {i}: found {found:?}"
        );
        let gain = param(f, "um_per_K").and_then(|v| v.as_f64()).unwrap();
        assert!(
            (gain - um_per_k).abs() <= 0.15 * um_per_k.abs(),
            "regime seed {seed} case {i}: gain {gain} µm/K against the truth's {um_per_k}"
        );
    }
}

#[test]
fn a_heat_source_seen_only_through_rpm_is_still_named_as_the_rpm_lag() {
    // Seed 2026, every effect case of rpm_heat (indices with i mod 10 ≥ 3 in 0..20).
    let mut missed = vec![];
    for i in (0..20).filter(|i| i % 10 >= 3) {
        let (rec, m) = generate_family_case(Family::RpmHeat, 2026, i);
        assert!(matches!(
            &m.hidden[0].model,
            EffectModel::ThermalLag { sensor, .. } if sensor == "rpm"
        ));
        let d = diagnose(&rec, &Options::default()).unwrap();
        let named_rpm = d.report.findings.iter().any(|f| {
            f.effect == "thermal_lag"
                && param(f, "sensor")
                    .and_then(|v| v.as_str().map(str::to_string))
                    .is_some_and(|s| s == "rpm")
        });
        if !named_rpm {
            missed.push(i);
        }
    }
    assert!(
        missed.is_empty(),
        "rpm_heat cases with no lag of the spindle speed: {missed:?}"
    );
}

#[test]
fn a_true_lag_of_a_sensor_is_still_named_as_that_lag() {
    // Seed 7, every regime effect case whose truth is a lag of a temperature sensor: a real time
    // constant departs from the reading by more than its resolution, so the resolution rule
    // leaves it alone.
    let mut checked = 0;
    for i in (0..20).filter(|i| i % 10 >= 3) {
        let (rec, m) = generate_family_case(Family::Regime, 7, i);
        let EffectModel::ThermalLag { sensor, .. } = &m.hidden[0].model else {
            continue;
        };
        if sensor == "rpm" {
            continue;
        }
        let d = diagnose(&rec, &Options::default()).unwrap();
        let found = named(&d.report.findings);
        assert!(
            d.report.findings.iter().any(|f| f.effect == "thermal_lag"
                && param(f, "sensor").and_then(|v| v.as_str().map(str::to_string))
                    == Some(sensor.clone())),
            "regime seed 7 case {i}: truth thermal_lag({sensor}), found {found:?}"
        );
        checked += 1;
    }
    assert!(checked >= 3, "only {checked} sensor-lag truths in seed 7");
}
