//! The runtime core (sans-IO engine): fresh inputs → ramp in, then track −error with the F/R blend;
//! a failed temperature is replaced by its neighbour estimate (Ni 1996 §5); a silent encoder makes the
//! axis hold then ramp to zero and recover without a jump; temperatures are latched at the thermal
//! period; every fault is logged once; the status and the Prometheus text show all of it.

use std::collections::BTreeMap;
use std::path::Path;

use retrocomp::bus::{Health, Sample};
use retrocomp::gateway::config::FieldConfig;
use retrocomp::gateway::{AxisErrors, Engine, ErrorModel, FaultKind, MachineState, Mode};

/// x error: thermal growth 2 µm/K above 20 °C on T_spindle_C, plus a ±3 µm reversal (backlash).
struct TestModel;

impl ErrorModel for TestModel {
    fn required_channels(&self) -> Vec<String> {
        vec!["T_spindle_C".into()]
    }
    fn axis_errors(&mut self, s: &MachineState, out: &mut AxisErrors) -> Result<(), String> {
        let t = s.channels["T_spindle_C"];
        let thermal = 2.0 * (t - 20.0);
        out.push("x", "thermal".into(), thermal);
        // F/R blended with the latch weight: +3 forward, −3 reverse.
        out.push("x", "backlash".into(), s.weight_forward["x"] * 6.0 - 3.0);
        Ok(())
    }
}

const CFG: &str = r#"
[gateway]
name = "t"
cycle_ms = 10
thermal_period_s = 1.0
[safety]
max_correction_um = 50.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 20.0
stale_hold_s = 0.3
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
[[channel]]
name = "x_mm"
min = -1.0
max = 500.0
stale_after_s = 0.05
[[channel]]
name = "T_spindle_C"
min = 5.0
max = 70.0
stale_after_s = 2.0
max_rate_per_s = 1.0
[[channel]]
name = "T_bed_C"
min = 5.0
max = 70.0
stale_after_s = 2.0
[[recovery]]
target = "T_spindle_C"
neighbours = ["T_bed_C"]
coefficients = [0.0, 1.0]
fit_rms = 0.1
"#;

fn s(ch: &str, t: f64, v: f64) -> Sample {
    Sample {
        channel: ch.into(),
        t_s: t,
        value: v,
        health: Health::Ok,
    }
}

#[test]
fn closed_loop_core_behaviour() {
    let cfg = FieldConfig::parse(CFG, Path::new("t.toml")).unwrap();
    let mut e = Engine::new(&cfg, &BTreeMap::from([("x".to_string(), 4.0)])).unwrap();
    let mut m = TestModel;
    let dt = 0.01;
    let mut t = 0.0;
    let mut x = 100.0;
    let mut last = 4.0;
    let mut run = |e: &mut Engine,
                   t: &mut f64,
                   x: &mut f64,
                   n: usize,
                   v_mm_s: f64,
                   temp: Option<f64>,
                   pos_alive: bool| {
        let mut outs = Vec::new();
        for _ in 0..n {
            *t += dt;
            *x += v_mm_s * dt;
            if pos_alive {
                e.ingest(&s("x_mm", *t, *x));
            }
            if let Some(tc) = temp {
                e.ingest(&s("T_spindle_C", *t, tc));
            }
            e.ingest(&s("T_bed_C", *t, 30.0));
            let o = e.cycle(*t, &mut m)[0].1;
            outs.push(o);
        }
        outs
    };
    // Moving forward at 30 °C: error = 20 + 3 µm → target −23 µm; starts from the 4 µm held in the
    // controller and ramps (20 µm/s = 0.2 µm per cycle), never jumping.
    let outs = run(&mut e, &mut t, &mut x, 300, 10.0, Some(30.0), true);
    for o in &outs {
        assert!((o - last).abs() <= 0.5 + 1e-9, "jump {last} → {o}");
        last = *o;
    }
    assert!((last + 23.0).abs() < 1e-6, "tracks −error: {last}");
    assert_eq!(e.axis_mode("x"), Some(Mode::Tracking));
    let snap = e.snapshot();
    assert!((snap.axes[0].terms_um["thermal"] + 20.0).abs() < 1e-9);
    assert!((snap.axes[0].terms_um["backlash"] + 3.0).abs() < 1e-9);

    // Reverse: the backlash term swaps sign over the sin² blend, at most the dosing cap per cycle.
    let outs = run(&mut e, &mut t, &mut x, 100, -10.0, Some(30.0), true);
    for o in &outs {
        assert!((o - last).abs() <= 0.5 + 1e-9);
        last = *o;
    }
    assert!(
        (last + 17.0).abs() < 1e-6,
        "reverse: −(20 − 3) = −17, got {last}"
    );

    // Temperature sensor goes NaN: the neighbour estimate (T_bed_C = 30) takes over; no change.
    let outs = run(&mut e, &mut t, &mut x, 50, -10.0, Some(f64::NAN), true);
    assert!(outs.iter().all(|o| (o + 17.0).abs() < 1e-6));
    let snap = e.snapshot();
    assert!(snap.channels["T_spindle_C"].substituted);
    assert!(
        snap.prometheus()
            .contains("retrocomp_channel_substituted{channel=\"T_spindle_C\"} 1")
    );

    // Encoder silent: hold for 0.3 s (after the 50 ms staleness), then ramp to zero.
    let outs = run(&mut e, &mut t, &mut x, 150, -10.0, Some(30.0), false);
    assert!(
        outs[..30].iter().all(|o| (o + 17.0).abs() < 1e-6),
        "holds first"
    );
    for o in &outs {
        assert!((o - last).abs() <= 0.2 + 1e-9, "ramps, does not jump");
        last = *o;
    }
    assert!(last > -17.0 + 1.0, "ramped towards zero: {last}");
    let faults = e.snapshot().active_faults;
    assert!(faults.iter().any(|(s, _, _)| s == "x_mm"));
    // Encoder back: ramps back in without a jump.
    let outs = run(&mut e, &mut t, &mut x, 200, -10.0, Some(30.0), true);
    for o in &outs {
        assert!((o - last).abs() <= 0.5 + 1e-9);
        last = *o;
    }
    assert!((last + 17.0).abs() < 1e-6);
    assert!(
        e.snapshot().active_faults.is_empty(),
        "faults clear when the source returns"
    );
}

#[test]
fn temperatures_are_latched_at_the_thermal_period() {
    let cfg = FieldConfig::parse(CFG, Path::new("t.toml")).unwrap();
    let mut e = Engine::new(&cfg, &BTreeMap::new()).unwrap();
    let mut m = TestModel;
    let mut t = 0.0;
    let mut targets = Vec::new();
    for k in 0..250 {
        t += 0.01;
        e.ingest(&s("x_mm", t, 10.0 + k as f64 * 0.1));
        // Temperature rises 0.5 °C/s (within the 1 °C/s rate limit).
        e.ingest(&s("T_spindle_C", t, 25.0 + 0.5 * t));
        e.ingest(&s("T_bed_C", t, 25.0));
        e.cycle(t, &mut m);
        targets.push(e.snapshot().axes[0].terms_um["thermal"]);
    }
    let distinct: std::collections::BTreeSet<i64> =
        targets.iter().map(|v| (v * 1e6) as i64).collect();
    assert_eq!(
        distinct.len(),
        3,
        "2.5 s at a 1 s period → 3 latched values: {distinct:?}"
    );
}

#[test]
fn a_bad_reading_replaced_before_the_cycle_is_logged_once_and_never_used() {
    let cfg = FieldConfig::parse(CFG, Path::new("t.toml")).unwrap();
    let mut e = Engine::new(&cfg, &BTreeMap::new()).unwrap();
    let mut m = TestModel;
    let mut t = 0.0;
    let feed = |e: &mut Engine, t: f64, temp: f64| {
        e.ingest(&s("x_mm", t, 100.0));
        e.ingest(&s("T_bed_C", t, 30.0));
        e.ingest(&s("T_spindle_C", t, temp));
    };
    for _ in 0..200 {
        t += 0.01;
        feed(&mut e, t, 30.0);
        e.cycle(t, &mut m);
    }
    let settled = e.cycle(t, &mut m)[0].1;
    // Within one 10 ms cycle: a NaN, then a good reading, before the engine looks.
    t += 0.01;
    e.ingest(&s("T_spindle_C", t - 0.005, f64::NAN));
    feed(&mut e, t, 30.0);
    let out = e.cycle(t, &mut m)[0].1;
    let faults = e.snapshot().active_faults;
    assert!(
        faults
            .iter()
            .any(|(src, k, _)| src == "T_spindle_C" && *k == FaultKind::NotFinite),
        "the replaced NaN is logged: {faults:?}"
    );
    assert!((out - settled).abs() < 1e-9, "the NaN was never used");
    t += 0.01;
    feed(&mut e, t, 30.0);
    e.cycle(t, &mut m);
    assert!(
        e.snapshot().active_faults.is_empty(),
        "cleared the next cycle: {:?}",
        e.snapshot().active_faults
    );
}
