//! The lead hold in virtual time: durations from the modal state, the hold released when the
//! estimate says, the controller's XOFF above the estimate, `lead_blocks = buffer_lines` as before.

use retrocomp_analysis::nc::parser::parse_line;

use super::core::{DncCore, XOFF, XON};
use super::lead::{ExecEstimate, LeadConfig};
use super::live::LiveCorrections;
use super::tests::{cfg, drain, live};

fn lead(lead_blocks: usize) -> LeadConfig {
    LeadConfig {
        lead_blocks,
        ..LeadConfig::off(5)
    }
}

/// F600 = 10 mm/s: each 10 mm stroke runs 1 s.
const STROKES: &str = "G90 G1 F600\nX10\nX20\nX30\nM30";

#[test]
fn durations_follow_feed_rapid_dwell_units_and_the_control_speed() {
    let mut e = ExecEstimate::new(LeadConfig {
        rapid_mm_min: 6000.0,
        ..lead(1)
    });
    let mut d = |src: &str| {
        let b = parse_line("t", 1, src, false).unwrap().remove(0);
        e.duration_s(&b)
    };
    let got = [
        d("G0 X100"),        // 100 mm at 6000 mm/min
        d("G1 F3000 X50"),   // 50 mm at 3000 mm/min
        d("G4 P2"),          // seconds
        d("G91 X10 F600"),   // incremental 10 mm
        d("G90 G20 X1 F60"), // to 25.4 mm from 60 mm: 34.6 mm at 1524 mm/min
        d("M5"),
    ];
    let want = [1.0, 1.0, 2.0, 1.0, 34.6 / 1524.0 * 60.0, 0.0];
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-9, "{got:?} vs {want:?}");
    }
    let mut fanuc = ExecEstimate::new(LeadConfig {
        control_speed: 2.0,
        dwell_p_ms: true,
        ..lead(1)
    });
    let b = parse_line("t", 1, "G4 P2000", true).unwrap().remove(0);
    assert!((fanuc.duration_s(&b) - 1.0).abs() < 1e-12, "2 s at speed 2");
}

#[test]
fn the_next_block_is_held_until_the_estimate_says_the_one_before_runs() {
    let lc = live(0.1, 50.0);
    let mut c = cfg();
    c.lead = lead(1);
    let mut core = DncCore::new(c, &lc);
    let (_, log) = drain(&mut core, STROKES, 0.125);
    let t: Vec<f64> = log.iter().map(|b| b.t_s).collect();
    // G1 F600 (0 s) at 0, X10 at 0.125 (runs 0.125 … 1.125), X20 as soon as X10 runs (0.25,
    // runs 1.125 … 2.125), X30 when X20 starts (1.125), M30 when X30 starts (2.125).
    assert_eq!(t, vec![0.0, 0.125, 0.25, 1.125, 2.125], "{log:?}");
    // X30's correction is the one at its (later) send time.
    let a = log[3].applied.unwrap();
    assert!((a.correction_um[0] + (0.1 * 1.125 + 0.01 * 30.0)).abs() <= 0.05 + 1e-9);
}

/// A core with `lead` and all of `STROKES` read, nothing sent.
fn fed(lc: &LiveCorrections, lead: LeadConfig) -> DncCore<'_> {
    let mut c = cfg();
    c.lead = lead;
    let mut core = DncCore::new(c, lc);
    for (i, l) in STROKES.lines().enumerate() {
        core.feed_line(i as u64 + 1, l).unwrap();
    }
    core.end_of_input();
    core
}

#[test]
fn the_release_time_is_the_estimated_start_of_the_line_that_frees_the_lead() {
    let lc = live(0.0, 50.0);
    let mut core = fed(&lc, lead(1));
    for t in [0.0, 0.125, 0.25] {
        assert!(core.next_to_send(t).unwrap().is_some());
        core.sent(t);
    }
    assert!(core.next_to_send(1.0).unwrap().is_none(), "held");
    assert_eq!(core.lead_release_s(), Some(1.125));
    assert!(core.next_to_send(1.125).unwrap().is_some(), "released");
}

#[test]
fn xoff_stops_the_transfer_even_when_the_estimate_says_the_control_is_idle() {
    let lc = live(0.0, 50.0);
    let mut core = fed(&lc, lead(2));
    assert!(core.next_to_send(0.0).unwrap().is_some());
    core.sent(0.0);
    core.on_bytes(&[XOFF], 0.1);
    // The estimate has the control idle long before t = 4 s; XOFF still rules.
    for k in 1..40 {
        assert!(core.next_to_send(f64::from(k) * 0.1).unwrap().is_none());
    }
    core.on_bytes(&[XON], 4.0);
    assert!(core.next_to_send(4.0).unwrap().is_some());
}

#[test]
fn lead_blocks_equal_to_the_buffer_changes_nothing() {
    let run = |l: LeadConfig| {
        let lc = live(0.1, 50.0);
        let mut c = cfg();
        c.lead = l;
        let mut core = DncCore::new(c, &lc);
        drain(&mut core, STROKES, 0.125)
    };
    let before = run(LeadConfig::off(5));
    let same = run(LeadConfig {
        rapid_mm_min: 100.0,
        control_speed: 0.5,
        ..lead(5)
    });
    assert_eq!(before, same);
    assert_ne!(before.1, run(lead(1)).1, "a lead below the buffer holds");
}
