//! Safety invariants under arbitrary input sequences: the output never leaves the clamp, never changes
//! by more than the dosing cap in one cycle, never becomes NaN, and outside steady tracking never
//! changes faster than the ramp rate.

use proptest::prelude::*;
use retrocomp_gateway::{AxisSafety, Input, Mode, SafetyConfig};

fn input() -> impl Strategy<Value = Input> {
    prop_oneof![
        4 => (-500.0f64..500.0).prop_map(Input::Fresh),
        1 => Just(Input::Fresh(f64::NAN)),
        1 => Just(Input::Fresh(f64::INFINITY)),
        2 => Just(Input::Stale),
        1 => Just(Input::Fault),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(3000))]
    #[test]
    fn clamp_cap_and_ramp_always_hold(
        start in -50.0f64..50.0,
        steps in prop::collection::vec((0.0005f64..0.2, any::<bool>(), input()), 1..200),
    ) {
        let cfg = SafetyConfig { max_correction_um: 50.0, max_change_um_per_cycle: 2.0, ramp_um_per_s: 40.0, stale_hold_s: 0.3 };
        let mut s = AxisSafety::new(cfg, start).unwrap();
        let mut t = 0.0;
        let mut prev = start;
        for (dt, enabled_bit, inp) in steps {
            // Mostly enabled; toggles exercise the enable/disable ramps.
            let enabled = enabled_bit || dt < 0.1;
            t += dt;
            let out = s.step(t, enabled, inp);
            prop_assert!(out.is_finite());
            prop_assert!(out.abs() <= 50.0, "beyond clamp: {out}");
            let d = (out - prev).abs();
            prop_assert!(d <= 2.0 + 1e-9, "change {d} beyond cap");
            if s.mode() != Mode::Tracking {
                prop_assert!(d <= 40.0 * dt + 1e-9, "change {d} beyond ramp in {:?}", s.mode());
            }
            prev = out;
        }
    }
}
