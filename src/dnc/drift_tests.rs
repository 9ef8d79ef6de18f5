//! The drift prediction in virtual time: the correction predicted for a block's end from a
//! quantised drift, its bounds (horizon, too short a series, a refused input), the guard after
//! it, and the engine asked twice at one time.

use retrocomp_analysis::nc::ErrorFunction;
use retrocomp_model::MachineModel;
use retrocomp_model::approach::Approach;

use super::core::DncCore;
use super::drift::{DriftConfig, DriftPredictor};
use super::lead::LeadConfig;
use super::live::{CorrectionAt, EngineAtPoint, LiveCorrections};
use super::tests::{MODEL, cfg, drain, engine, temp};
use retrocomp_gateway::engine::MachineModelAdapter;

const F: [Approach; 3] = [Approach::Forward; 3];
const R: [Approach; 3] = [Approach::Reverse; 3];

/// X correction = −(0.3 µm steps of `um_per_s · t`) − 0.01 µm/mm · x: a drift read through a
/// quantised sensor (0.1 °C × 3 µm/K), plus geometry; refused inputs in `[fail_from_s, fail_to_s)`.
struct Stepped {
    um_per_s: f64,
    fail: (f64, f64),
}

impl CorrectionAt for Stepped {
    fn correction_um(
        &mut self,
        pos_mm: [f64; 3],
        _dirs: [Approach; 3],
        now_s: f64,
    ) -> Result<[Option<f64>; 3], String> {
        if (self.fail.0..self.fail.1).contains(&now_s) {
            return Err("no recent value of T_spindle_C".into());
        }
        let drift = 0.3 * (self.um_per_s * now_s / 0.3).floor();
        Ok([Some(-(drift + 0.01 * pos_mm[0])), None, None])
    }
}

fn truth_um(um_per_s: f64, x_mm: f64, t_s: f64) -> f64 {
    -(um_per_s * t_s + 0.01 * x_mm)
}

const WINDOW: DriftConfig = DriftConfig {
    window_s: 60.0,
    max_horizon_s: 30.0,
};

fn predicting(um_per_s: f64, fail: (f64, f64), clamp_um: f64, cap_um: f64) -> LiveCorrections {
    LiveCorrections::new(
        Box::new(Stepped { um_per_s, fail }),
        [(clamp_um, cap_um), (0.0, 0.0), (0.0, 0.0)],
    )
    .with_drift(WINDOW)
}

/// Block `k` at `t_s`, estimated to end `ahead_s` later: X350 forward / X50 reverse alternating.
/// Returns (x_mm, correction sent µm).
fn block(lc: &LiveCorrections, k: usize, t_s: f64, ahead_s: f64) -> (f64, f64) {
    let (x, dirs) = if k.is_multiple_of(2) {
        (350.0, F)
    } else {
        (50.0, R)
    };
    lc.set_now(t_s);
    lc.set_end_s(t_s + ahead_s);
    let e = lc.error_um([x, 0.0, 0.0], dirs).unwrap();
    lc.commit();
    (x, -e[0])
}

#[test]
fn a_block_carries_the_correction_predicted_for_its_end_not_its_send_time() {
    let v = 0.06;
    let lc = predicting(v, (0.0, 0.0), 100.0, 50.0);
    let (mut worst_now, mut worst_pred) = (0.0_f64, 0.0_f64);
    for k in 0..150 {
        let t = 2.0 * k as f64;
        let (x, c) = block(&lc, k, t, 10.0);
        let at_send = Stepped {
            um_per_s: v,
            fail: (0.0, 0.0),
        }
        .correction_um([x, 0.0, 0.0], F, t)
        .unwrap()[0]
            .unwrap();
        if t < 15.0 {
            // Too short a series: the present value (to the block's 0.1 µm).
            assert!(
                (c - at_send).abs() <= 0.05 + 1e-9,
                "t {t}: {c} vs {at_send}"
            );
        } else if t >= 60.0 {
            worst_pred = worst_pred.max((c - truth_um(v, x, t + 10.0)).abs());
            worst_now = worst_now.max((at_send - truth_um(v, x, t + 10.0)).abs());
        }
    }
    // Without it the block is 0.6 µm (10 s × 0.06 µm/s) + a 0.3 µm step behind; with it only the
    // sensor's step and the block's 0.1 µm remain.
    assert!(worst_now > 0.6, "{worst_now}");
    assert!(worst_pred <= 0.3 + 0.05 + 0.02, "{worst_pred}");
}

#[test]
fn the_horizon_is_bounded_by_predict_max_s() {
    let v = 0.06;
    let lc = predicting(v, (0.0, 0.0), 100.0, 50.0);
    for k in 0..100 {
        let t = 2.0 * k as f64;
        // Estimated to end 1000 s later (a control stopped): extrapolated 30 s, no further.
        let (x, c) = block(&lc, k, t, 1000.0);
        if t >= 60.0 {
            let want = truth_um(v, x, t + WINDOW.max_horizon_s);
            assert!(
                (c - want).abs() <= 0.3 + 0.05 + 0.05,
                "t {t}: {c} vs {want}"
            );
        }
    }
}

#[test]
fn a_refused_input_restarts_the_series_and_the_present_value_is_sent_until_it_refills() {
    let v = 0.06;
    let lc = predicting(v, (100.0, 110.0), 100.0, 50.0);
    for k in 0..100 {
        let t = 2.0 * k as f64;
        let (x, c) = block(&lc, k, t, 10.0);
        let present = -(0.3 * (v * t / 0.3).floor() + 0.01 * x);
        if (100.0..110.0).contains(&t) {
            assert!(lc.model_fault().is_some());
        } else if (110.0..125.0).contains(&t) {
            // Healthy again, the series spans less than a quarter of the window: no extrapolation.
            assert!(
                (c - present).abs() <= 0.05 + 1e-9,
                "t {t}: {c} vs {present}"
            );
        } else if t >= 170.0 {
            assert!((c - truth_um(v, x, t + 10.0)).abs() <= 0.4, "t {t}: {c}");
        }
    }
}

#[test]
fn the_predicted_value_goes_through_the_guard_clamp_and_per_block_cap() {
    // 0.5 µm/s, 30 s ahead: the prediction jumps by 15 µm once the series is long enough, and
    // runs into the 20 µm clamp.
    let lc = predicting(0.5, (0.0, 0.0), 20.0, 0.5);
    let mut prev = 0.0;
    let mut reached = false;
    for k in 0..200 {
        let (_, c) = block(&lc, k, k as f64, 1000.0);
        assert!((c - prev).abs() <= 0.5 + 1e-9, "block {k}: {prev} → {c}");
        assert!(c.abs() <= 20.0 + 1e-9, "block {k}: {c}");
        reached |= (c.abs() - 20.0).abs() < 1e-9;
        prev = c;
    }
    assert!(reached, "the clamp was reached");
    assert!(lc.guard_refused() || prev.abs() <= 20.0);
}

#[test]
fn the_slope_needs_samples_spanning_a_quarter_of_the_window_and_follows_a_clock_going_back() {
    let mut d = DriftPredictor::new(WINDOW);
    let p = [1.0, 2.0, 3.0];
    for t in [-100.0, -99.0, -98.0, -97.0, -96.0] {
        d.record(p, F, t, [Some(-t), None, None]);
    }
    assert_eq!(
        d.ahead_um(-96.0, -90.0),
        [0.0; 3],
        "5 samples over 4 s < 15 s"
    );
    for t in [0.0, 10.0, 20.0] {
        d.record(p, F, t, [Some(-t), None, None]);
    }
    assert_eq!(d.ahead_um(20.0, 30.0), [0.0; 3], "3 samples over 20 s");
    d.record(p, F, 30.0, [Some(-30.0), None, None]);
    let a = d.ahead_um(30.0, 40.0);
    assert!((a[0] + 10.0).abs() < 1e-9 && a[1] == 0.0, "{a:?}");
    // Another point does not enter the series.
    d.record([0.0; 3], F, 40.0, [Some(100.0), None, None]);
    assert!((d.ahead_um(40.0, 41.0)[0] + 1.0).abs() < 1e-9);
    // The block is not in the future: nothing added.
    assert_eq!(d.ahead_um(40.0, 39.0), [0.0; 3]);
    // The clock went back: the series restarts.
    d.record(p, F, 5.0, [Some(0.0), None, None]);
    assert_eq!(d.ahead_um(5.0, 15.0), [0.0; 3]);
}

/// The engine of `tests.rs` with a 20 s lag on the spindle sensor.
fn lagged_engine() -> EngineAtPoint {
    let text = MODEL.replace("reference_C = 20.0", "reference_C = 20.0\ntau_s = 20.0");
    assert_ne!(text, MODEL, "dnc_model.toml changed");
    let model = MachineModel::from_toml_str(&text, "lagged.toml").unwrap();
    EngineAtPoint::new(engine(), Box::new(MachineModelAdapter::new(model)))
}

#[test]
fn asking_the_engine_at_a_second_point_at_one_time_changes_neither_its_lag_nor_its_faults() {
    let limits = [(100.0, 50.0), (0.0, 0.0), (0.0, 0.0)];
    // No extrapolation (horizon 0): any difference is the extra evaluation's doing.
    let twice = LiveCorrections::new(Box::new(lagged_engine()), limits).with_drift(DriftConfig {
        window_s: 4.0,
        max_horizon_s: 0.0,
    });
    let once = LiveCorrections::new(Box::new(lagged_engine()), limits);
    for k in 0..60 {
        let t = 0.5 * k as f64;
        // Warming 0.2 K/s; stale from 12 s to 16 s (no reading for 4 s > 2 s).
        if !(12.0..16.0).contains(&t) {
            for lc in [&twice, &once] {
                lc.observe(&temp(t, 25.0 + 0.2 * t));
            }
        }
        let [a, b] = [&twice, &once].map(|lc| block(lc, k, t, 5.0).1);
        assert_eq!(a.to_bits(), b.to_bits(), "t {t}: {a} vs {b}");
        let [fa, fb] = [&twice, &once].map(|lc| lc.snapshot().unwrap().active_faults);
        assert_eq!(fa, fb, "t {t}");
        assert_eq!(twice.model_fault(), once.model_fault(), "t {t}");
        if t == 15.0 {
            assert!(once.model_fault().is_some(), "the stale input was refused");
        }
    }
}

#[test]
fn the_core_asks_for_the_end_of_the_block_on_the_controls_estimated_schedule() {
    let e = super::lead::ExecEstimate::new(LeadConfig::off(5));
    assert_eq!(
        e.end_if_sent_s(1.0, 2.0),
        3.0,
        "nothing sent yet: now + duration"
    );
    let mut e = e;
    e.sent(1.0, 2.0);
    assert_eq!(e.end_if_sent_s(1.0, 2.5), 4.0, "after the line before it");
    assert_eq!(e.end_if_sent_s(1.0, 5.0), 6.0, "not before it arrives");

    // 0.5 µm/s in 0.3 µm steps. F600: each 10 mm stroke runs 1 s; held until the one before it is
    // estimated to start, so a block is sent ≈ 2 s before it ends.
    let lc = predicting(0.5, (0.0, 0.0), 100.0, 50.0);
    let mut c = cfg();
    c.max_correction_um = 100.0;
    c.lead = LeadConfig {
        lead_blocks: 1,
        ..LeadConfig::off(5)
    };
    let mut core = DncCore::new(c, &lc);
    let mut program = String::from("G90 G1 F600 X0\n");
    for k in 0..120_usize {
        program.push_str(if k.is_multiple_of(2) { "X10\n" } else { "X0\n" });
    }
    let (_, log) = drain(&mut core, &program, 0.05);
    assert_eq!(log.len(), 121);
    let mut checked = 0;
    for b in log.iter().filter(|b| b.t_s >= 60.0) {
        let a = b.applied.unwrap();
        let want = truth_um(0.5, a.pos_mm[0], b.t_s + 2.0);
        // Sent at its send time it would be 1 µm off; here the 0.3 µm steps of the drift, the
        // hold's 0.05 s tick and the block's 0.1 µm remain.
        assert!(
            (a.correction_um[0] - want).abs() <= 0.3 + 0.03 + 0.05 + 0.02,
            "{b:?}"
        );
        checked += 1;
    }
    assert!(checked > 20, "{checked}");
}
