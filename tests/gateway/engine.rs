//! The runtime core (sans-IO engine): fresh inputs → ramp in, then track −error with the F/R blend;
//! a failed temperature is replaced by its neighbour estimate (Ni 1996 §5); a silent encoder makes the
//! axis hold then ramp to zero and recover without a jump; temperatures are latched at the thermal
//! period; every fault is logged once; the status and the Prometheus text show all of it.

use std::collections::BTreeMap;
use std::path::Path;

use retrocomp_bus::{Health, Sample};
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::{AxisErrors, Engine, ErrorModel, FaultKind, MachineState, Mode};
use retrocomp_model::Axis;

/// x error: thermal growth 2 µm/K above 20 °C on T_spindle_C, plus a ±3 µm reversal (backlash).
struct TestModel;

impl ErrorModel for TestModel {
    fn required_channels(&self) -> Vec<std::sync::Arc<str>> {
        vec!["T_spindle_C".into()]
    }
    fn axis_errors(
        &mut self,
        s: &MachineState,
        out: &mut AxisErrors,
    ) -> Result<(), retrocomp_gateway::engine::ModelError> {
        let t = s
            .input(0)
            .expect("the engine calls the model with its inputs usable");
        let thermal = 2.0 * (t - 20.0);
        out.push(Axis::X, "thermal".into(), thermal);
        // F/R blended with the latch weight: +3 forward, −3 reverse.
        out.push(
            Axis::X,
            "backlash".into(),
            s.forward_weight(Axis::X) * 6.0 - 3.0,
        );
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

/// A good sample of the channel named `ch`, its id resolved in the engine's table.
trait Feed {
    fn feed(&mut self, ch: &str, t: f64, v: f64);
}

impl Feed for Engine {
    fn feed(&mut self, ch: &str, t: f64, v: f64) {
        let channel = self.channels_mut().resolve(ch);
        self.handle_sample(&Sample {
            channel,
            t_s: t,
            value: v,
            health: Health::Ok,
        });
    }
}

#[test]
fn closed_loop_core_behaviour() {
    let cfg = FieldConfig::parse(CFG, Path::new("t.toml")).unwrap();
    let mut e = cfg
        .engine(&BTreeMap::from([("x".to_string(), 4.0)]))
        .unwrap();
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
                e.feed("x_mm", *t, *x);
            }
            if let Some(tc) = temp {
                e.feed("T_spindle_C", *t, tc);
            }
            e.feed("T_bed_C", *t, 30.0);
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
    assert_eq!(e.axis_mode(Axis::X), Some(Mode::Tracking));
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
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let mut m = TestModel;
    let mut t = 0.0;
    let mut targets = Vec::new();
    for k in 0..250 {
        t += 0.01;
        e.feed("x_mm", t, 10.0 + f64::from(k) * 0.1);
        // Temperature rises 0.5 °C/s (within the 1 °C/s rate limit).
        e.feed("T_spindle_C", t, 25.0 + 0.5 * t);
        e.feed("T_bed_C", t, 25.0);
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
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let mut m = TestModel;
    let mut t = 0.0;
    let feed = |e: &mut Engine, t: f64, temp: f64| {
        e.feed("x_mm", t, 100.0);
        e.feed("T_bed_C", t, 30.0);
        e.feed("T_spindle_C", t, temp);
    };
    for _ in 0..200 {
        t += 0.01;
        feed(&mut e, t, 30.0);
        e.cycle(t, &mut m);
    }
    let settled = e.cycle(t, &mut m)[0].1;
    // Within one 10 ms cycle: a NaN, then a good reading, before the engine looks.
    t += 0.01;
    e.feed("T_spindle_C", t - 0.005, f64::NAN);
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
    // The cycle's fault edges (what the log says): this one started, once.
    let edges = |e: &Engine| -> Vec<(String, FaultKind, bool)> {
        e.fault_events()
            .iter()
            .map(|ev| (ev.source.clone(), ev.kind, ev.started))
            .collect()
    };
    assert_eq!(
        edges(&e),
        [("T_spindle_C".to_string(), FaultKind::NotFinite, true)]
    );
    t += 0.01;
    feed(&mut e, t, 30.0);
    e.cycle(t, &mut m);
    assert!(
        e.snapshot().active_faults.is_empty(),
        "cleared the next cycle: {:?}",
        e.snapshot().active_faults
    );
    assert_eq!(
        edges(&e),
        [("T_spindle_C".to_string(), FaultKind::NotFinite, false)]
    );
    // A cycle with no change logs nothing.
    t += 0.01;
    feed(&mut e, t, 30.0);
    e.cycle(t, &mut m);
    assert!(e.fault_events().is_empty(), "{:?}", edges(&e));
}

/// Three axes and a cutting-force channel: the field config of the load-term tests.
const CFG3: &str = r#"
[gateway]
name = "t"
cycle_ms = 10
thermal_period_s = 0.1
[safety]
max_correction_um = 200.0
max_change_um_per_cycle = 1.0
ramp_um_per_s = 20.0
stale_hold_s = 0.3
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[[axis]]
name = "x"
position_channel = "x_mm"
[[axis]]
name = "y"
position_channel = "y_mm"
[[axis]]
name = "z"
position_channel = "z_mm"
[[channel]]
name = "F_cut_N"
min = -5000.0
max = 5000.0
stale_after_s = 0.1
"#;

/// Issue 18.5: a stale auxiliary input (the cutting force) drops only the terms that use it. With
/// the demo's full model (geometry + thermal + load) through the real adapter: the load terms leave
/// the breakdown, the axes keep tracking the geometric and thermal terms, the change is ramped
/// (the ramp rate, below the dosing cap), the episode is the fault `compensation.<axis>.partial`
/// (not `compensation.<axis>`), and the force's return ramps the terms back in.
#[test]
fn a_stale_force_drops_only_the_load_terms_ramped() {
    use retrocomp_gateway::engine::MachineModelAdapter;
    use retrocomp_model::MachineModel;
    let cfg = FieldConfig::parse(CFG3, Path::new("t.toml")).unwrap();
    let model = MachineModel::from_toml_str(retrocomp::demo::FULL_MODEL, "full").unwrap();
    let mut m = MachineModelAdapter::new(model);
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let dt = 0.01;
    let mut t = 0.0;
    let mut outs: Vec<f64> = Vec::new();
    let mut step = |e: &mut Engine, t: &mut f64, force: bool| {
        *t += dt;
        for (ch, v) in [("x_mm", 120.0), ("y_mm", 80.0), ("z_mm", -0.5)] {
            e.feed(ch, *t, v);
        }
        e.feed("T_spindle_C", *t, 25.0);
        e.feed("T_xscrew_C", *t, 24.0);
        if force {
            e.feed("F_cut_N", *t, 500.0);
        }
        e.cycle(*t, &mut m)[0].1
    };
    for _ in 0..300 {
        outs.push(step(&mut e, &mut t, true));
    }
    let full = e.snapshot();
    let x_full = full.axes[0].terms_um.clone();
    // 0.004 µm/N × 500 N on X: correction −2 µm.
    assert!((x_full["deflection_x"] + 2.0).abs() < 1e-6, "{x_full:?}");
    assert_eq!(e.axis_mode(Axis::X), Some(Mode::Tracking));
    let target_full = full.axes[0].target_um.unwrap();

    // The force goes silent: after its 0.1 s the load terms leave, the rest stays.
    let n0 = outs.len();
    for _ in 0..100 {
        outs.push(step(&mut e, &mut t, false));
    }
    let snap = e.snapshot();
    let x_part = &snap.axes[0].terms_um;
    assert!(!x_part.contains_key("deflection_x"), "{x_part:?}");
    // (The exact chain's cross term moves a little with the deflections: not compared.)
    let kept = |k: &&String| !k.starts_with("deflection") && *k != "higher_order";
    for (k, v) in x_full.iter().filter(|(k, _)| kept(k)) {
        assert!(
            (x_part[k] - v).abs() < 1e-9,
            "{k}: {v} → {:?}",
            x_part.get(k)
        );
    }
    let target_part = snap.axes[0].target_um.unwrap();
    assert!((target_part - (target_full + 2.0)).abs() < 0.01);
    assert_eq!(
        e.axis_mode(Axis::X),
        Some(Mode::Tracking),
        "reached the new target"
    );
    assert!((outs.last().unwrap() - target_part).abs() < 1e-9);
    // Ramped at 20 µm/s (0.2 µm per cycle), not dosed at the 1 µm cap.
    for w in outs[n0 - 1..].windows(2) {
        assert!(
            (w[1] - w[0]).abs() <= 0.2 + 1e-9,
            "step {} → {}",
            w[0],
            w[1]
        );
    }
    let faults: Vec<(String, FaultKind)> = snap
        .active_faults
        .iter()
        .map(|(s, k, _)| (s.clone(), *k))
        .collect();
    for axis in ["x", "y", "z"] {
        let partial = (format!("compensation.{axis}.partial"), FaultKind::Stale);
        assert!(faults.contains(&partial), "{faults:?}");
        assert!(
            !faults
                .iter()
                .any(|(s, _)| *s == format!("compensation.{axis}"))
        );
    }
    assert!(faults.contains(&("F_cut_N".to_string(), FaultKind::Stale)));
    assert!(e.compensation_partial() && !e.compensation_dropped());

    // The force returns: the load terms ramp back in, the faults clear.
    let n1 = outs.len();
    for _ in 0..100 {
        outs.push(step(&mut e, &mut t, true));
    }
    for w in outs[n1 - 1..].windows(2) {
        assert!(
            (w[1] - w[0]).abs() <= 0.2 + 1e-9,
            "step {} → {}",
            w[0],
            w[1]
        );
    }
    assert!((outs.last().unwrap() - target_full).abs() < 1e-9);
    assert!(e.snapshot().active_faults.is_empty());
    assert!(!e.compensation_partial());
}

/// An optional input no source delivers (the field check's list, handed to the engine at start)
/// is a `no_source` fault on that channel from the first cycle, and it stays active while the box
/// compensates with the other terms: the model's load terms are not left out silently.
#[test]
fn an_undelivered_optional_input_is_a_lasting_fault_naming_it() {
    use retrocomp_gateway::engine::MachineModelAdapter;
    use retrocomp_model::MachineModel;
    let cfg = FieldConfig::parse(CFG3, Path::new("t.toml")).unwrap();
    let model = MachineModel::from_toml_str(retrocomp::demo::FULL_MODEL, "full").unwrap();
    let mut m = MachineModelAdapter::new(model);
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    e.report_undelivered(&["F_cut_N".into()]);
    let no_source = ("F_cut_N".to_string(), FaultKind::NoSource);
    let mut t = 0.0;
    for k in 0..300 {
        t += 0.01;
        for (ch, v) in [("x_mm", 120.0), ("y_mm", 80.0), ("z_mm", -0.5)] {
            e.feed(ch, t, v);
        }
        e.feed("T_spindle_C", t, 25.0);
        e.feed("T_xscrew_C", t, 24.0);
        e.cycle(t, &mut m);
        let snap = e.snapshot();
        let faults: Vec<(String, FaultKind)> = snap
            .active_faults
            .iter()
            .map(|(s, k, _)| (s.clone(), *k))
            .collect();
        assert!(faults.contains(&no_source), "cycle {k}: {faults:?}");
    }
    // Compensating all the while, without the load terms.
    assert_eq!(e.axis_mode(Axis::X), Some(Mode::Tracking));
    assert!(!e.snapshot().axes[0].terms_um.contains_key("deflection_x"));
    // One episode: started at the first cycle, never cleared.
    let snap = e.snapshot();
    let since = snap
        .active_faults
        .iter()
        .find(|(s, k, _)| *s == "F_cut_N" && *k == FaultKind::NoSource)
        .map(|f| f.2);
    assert!(since.is_some_and(|s| s <= 0.01 + 1e-9), "{since:?}");
}

/// A sample whose id the engine's table did not issue (a decoder wired to another table) is
/// dropped: it is not judged under another channel's name, and the engine does not panic.
#[test]
fn a_sample_of_an_id_the_engine_did_not_issue_is_dropped() {
    let cfg = FieldConfig::parse(CFG, Path::new("t.toml")).unwrap();
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let mut m = TestModel;
    e.feed("T_spindle_C", 0.0, 25.0);
    e.cycle(0.01, &mut m);
    let known = e.channels().len();
    let before: Vec<String> = e.snapshot().channels.into_keys().collect();
    let mut other = retrocomp_bus::ChannelTable::default();
    let foreign = (0..=known)
        .map(|k| other.resolve(&format!("c{k}_mm")))
        .last()
        .unwrap();
    for k in 0..3 {
        e.handle_sample(&Sample {
            channel: foreign,
            t_s: 0.02 + f64::from(k) * 0.01,
            value: 1e9,
            health: Health::Ok,
        });
    }
    e.cycle(0.05, &mut m);
    assert_eq!(
        foreign.index(),
        known,
        "an id just beyond the engine's table"
    );
    assert_eq!(e.channels().len(), known, "the table is unchanged");
    let after: Vec<String> = e.snapshot().channels.into_keys().collect();
    assert_eq!(after, before, "no channel judged the foreign samples");
}
