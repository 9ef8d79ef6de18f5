//! The served image's last step against reports from any writer: a report beyond the clamp or far
//! from what was served withdraws the axis (a fault) and is never served or ramped from.

use std::collections::BTreeMap;

use super::*;

/// x: clamp 50 µm, cap 1 µm per update (also the served sink's tests').
pub(crate) fn limits() -> Vec<AxisLimits> {
    vec![AxisLimits {
        axis: "x".into(),
        max_correction_um: 50.0,
        max_change_um_per_write: 1.0,
    }]
}

/// x: int16 correction at 0 (0.1 µm per count), heartbeat at 1, position at 10 (10 µm per
/// count), held value at 11.
pub(crate) fn map() -> ServerMap {
    toml::from_str(
        r#"
        heartbeat_address = 1
        axis = [ { axis = "x", address = 0, kind = "int16", lsb_um = 0.1, sign = 1 } ]
        position = [ { channel = "x_mm", address = 10, kind = "int16", lsb_um = 10.0 } ]
        held = [ { axis = "x", address = 11 } ]
        "#,
    )
    .unwrap()
}

fn report(c: &mut ServerCore, held_counts: u16) {
    let image: BTreeMap<u16, u16> = [(10, 15000), (11, held_counts)].into();
    c.handle_controller_write(|a, n| (a..a + n).map(|k| image.get(&k).copied()).collect());
}

#[test]
fn a_rogue_held_value_beyond_the_clamp_is_never_served_from() {
    let mut c = ServerCore::new(map(), &limits(), &mut ChannelTable::default());
    report(&mut c, 0);
    let u = c.poll_update(&[(Axis::X, -34.5)]).unwrap();
    assert_eq!(u.exposed_um, vec![(Axis::X, -1.0)]);
    // A second client writes 0x7FFF (3276.7 µm) into the held register.
    report(&mut c, 0x7FFF);
    for _ in 0..50 {
        let u = c.poll_update(&[(Axis::X, -34.5)]).unwrap();
        assert!(u.exposed_um.is_empty(), "{u:?}");
        assert_eq!(u.withdrawn, vec![(0, 1)]);
        assert_eq!(c.faults().beyond_clamp, vec![true]);
    }
    let (_, held_um) = c.held_um().next().unwrap();
    assert!(
        (held_um - 3276.7).abs() < 1e-9,
        "status shows the held value: {held_um}"
    );
    // The controller's own report (the −1.0 µm it applies) is the truth again.
    report(&mut c, (-10i16).cast_unsigned());
    let u = c.poll_update(&[(Axis::X, -34.5)]).unwrap();
    assert_eq!(u.exposed_um, vec![(Axis::X, -2.0)]);
    assert_eq!(c.faults().beyond_clamp, vec![false]);
}

#[test]
fn a_report_far_from_the_served_value_is_uncertain_then_the_next_is_the_truth() {
    let mut c = ServerCore::new(map(), &limits(), &mut ChannelTable::default());
    report(&mut c, 200); // 20 µm
    c.poll_update(&[(Axis::X, 25.0)]).unwrap();
    report(&mut c, 210);
    assert_eq!(
        c.poll_update(&[(Axis::X, 25.0)]).unwrap().exposed_um[0].1,
        22.0
    );
    // The controller restarted and reports 0: it may hold 0 or 21 µm; nothing is served.
    report(&mut c, 0);
    let u = c.poll_update(&[(Axis::X, 25.0)]).unwrap();
    assert!(
        u.exposed_um.is_empty() && c.faults().uncertain == vec![true],
        "{u:?}"
    );
    report(&mut c, 0);
    let u = c.poll_update(&[(Axis::X, 25.0)]).unwrap();
    assert_eq!(u.exposed_um, vec![(Axis::X, 1.0)]);
}

#[test]
fn stop_ramps_out_within_the_cap_until_the_controller_reports_zero() {
    let mut c = ServerCore::new(map(), &limits(), &mut ChannelTable::default());
    report(&mut c, 25); // 2.5 µm
    c.begin_ramp_out();
    let mut served = 2.5f64;
    for _ in 0..10 {
        let u = c.poll_update(&[(Axis::X, 40.0)]).unwrap();
        let v = u.exposed_um[0].1;
        assert!(
            (v - served).abs() <= 1.0 + 1e-9 && v.abs() <= served.abs(),
            "{v}"
        );
        served = v;
        #[allow(
            clippy::cast_possible_truncation,
            reason = "the served value in 0.1 µm words: |v| ≤ the 50 µm clamp, well inside i16"
        )]
        let word = (v * 10.0).round() as i16;
        report(&mut c, word.cast_unsigned());
        if c.is_ramped_out() {
            break;
        }
    }
    assert!(c.is_ramped_out() && served == 0.0, "{served}");
}

#[test]
fn a_start_value_beyond_the_clamp_is_not_one() {
    let mut c = ServerCore::new(map(), &limits(), &mut ChannelTable::default());
    report(&mut c, 600); // 60 µm > 50
    assert!(c.is_seeded());
    assert!(c.start_values().is_empty());
    assert!(c.poll_update(&[]).unwrap().exposed_um.is_empty());
    assert_eq!(c.faults().beyond_clamp, vec![true]);
}
