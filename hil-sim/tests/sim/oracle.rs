//! Item 7: an oracle that writes the truth's own static error into the origin-shift registers drives
//! the residual to quantization level (register LSB/2 + one encoder count); the same through the
//! quadrature feedback input (whole counts).

#![allow(clippy::needless_range_loop)] // per-axis loops over several [f64; 3]

use crate::sim_common;
use hil_sim::World;
use hil_sim::compensators::Oracle;
use sim_common::cfg;

const PROGRAM: &str = r#"
[program]
tool_mm = 150.0
gcode = """
G1 F3000 X150 Y40 Z-50
G4 P1.0
G1 X20 Y180 Z-10
G4 P1.0
G1 X250 Y120 Z-80
G4 P1.0
M30
"""
[servo]
kv_per_s = 30.0
count_um = 1.0
[truth.builtin]
exx_ppm = 60.0
eyy_ppm = -40.0
ezz_ppm = 120.0
ec0y_urad = 50.0
eb0z_urad = -30.0
ea0z_urad = 25.0
eyx_um_per_m2 = 400.0
ebx_urad_per_m = 100.0
"#;

/// |error| per axis at the end of each dwell (last 100 ms), for a closed-loop hook.
fn dwell_errors(toml: &str, mut hook: impl FnMut(&mut World)) -> Vec<[f64; 3]> {
    let mut w = World::new(cfg(toml)).unwrap();
    let mut out = Vec::new();
    let mut still_ms = 0;
    let mut last = w.setpoint().pos_mm;
    while !w.done() {
        w.tick();
        hook(&mut w);
        let sp = w.setpoint().pos_mm;
        still_ms = if sp == last { still_ms + 1 } else { 0 };
        last = sp;
        // Dwell is 1 s: sample from 0.9 s on (the loop has settled: kv = 30/s).
        if still_ms >= 900 {
            out.push(w.truth_error().total_um);
        }
    }
    out
}

fn max_abs(v: &[[f64; 3]]) -> [f64; 3] {
    let mut m = [0.0f64; 3];
    for e in v {
        for k in 0..3 {
            m[k] = m[k].max(e[k].abs());
        }
    }
    m
}

#[test]
fn oracle_drives_residual_to_quantization_level() {
    let uncompensated = max_abs(&dwell_errors(PROGRAM, |_| {}));
    assert!(
        uncompensated.iter().all(|e| *e > 5.0),
        "the machine has errors to remove: {uncompensated:?}"
    );
    for plc in [
        "[plc]\nscan_s = 0.010\nlsb_um = 1.0\n",
        "[plc]\nscan_s = 0.016\nword = \"int32\"\nword_order = \"low_first\"\nlsb_um = 0.5\nfirst_register = 100\nhandshake = { strobe_register = 0, ack_register = 1 }\n",
    ] {
        let toml = format!("{PROGRAM}{plc}");
        let lsb = if plc.contains("0.5") { 0.5 } else { 1.0 };
        let mut oracle = Oracle::new(0.010);
        let errs = dwell_errors(&toml, |w| oracle.update(w).unwrap());
        assert!(errs.len() > 200, "{} dwell samples", errs.len());
        let residual = max_abs(&errs);
        let bound = lsb / 2.0 + 1.0 + 0.05; // register LSB/2 + one encoder count
        assert!(
            residual.iter().all(|r| *r <= bound),
            "{plc}: residual {residual:?} > {bound} (was {uncompensated:?})"
        );
    }
}

#[test]
fn quadrature_injection_moves_the_slide_by_whole_counts() {
    // Inject counts = round(error / count): the servo moves the slide by −counts·count.
    let mut injected = [0i64; 3];
    let errs = dwell_errors(PROGRAM, |w| {
        if w.ticks() % 10 == 0 {
            let e = w.static_error_um(w.setpoint().pos_mm);
            for k in 0..3 {
                let want = e[k].round() as i64;
                w.inject_counts(k, want - injected[k]);
                injected[k] = want;
            }
        }
    });
    let residual = max_abs(&errs);
    assert!(
        residual.iter().all(|r| *r <= 0.5 + 1.0 + 0.05),
        "residual {residual:?}"
    );
}
