//! The server mode in the closed loop (`[sink.origin_shift_server]`): the box serves its
//! corrections through the gateway's own `GatewayCore::start_served` (register bank and
//! `ServedSink`), the PLC's Modbus master (`harness/master.rs`) polls them every 8 ms into the
//! PLC's shift registers and writes back what the PLC applies. Asserted on what the PLC applies:
//! the clamp and one cap per master write, no jump (also across a box restart, which resumes from
//! the PLC's report), no sink fault, and the applied shift meeting the engine's output at a dwell.

use crate::closed_loop_support;

use closed_loop_support::*;

#[test]
fn the_served_correction_reaches_the_plc_within_the_clamp_and_cap_and_a_restart_resumes_from_it() {
    let mut h = closed_loop_served(sim_config(MOVES, true, ""));
    h.run_until(3.5);
    let before = h.applied_um();
    assert!(
        before.iter().any(|v| v.abs() >= 3.0 * CAP_UM),
        "a correction of several caps: {before:?}"
    );
    // A box restart (SIGKILL, start again): nothing readable until the PLC's master reports what
    // the PLC applies; the new box continues from it.
    let writes_before = h.writes().len();
    h.restart_gateway().expect("restart");
    h.run_to_end();
    assert!(h.writes().len() > writes_before, "the restarted box serves");
    assert_clamp_and_cap_per_write(h.writes());
    assert_no_jump(h.trace(), &[]);
    let sink_faults: Vec<_> = h
        .fault_edges()
        .iter()
        .filter(|e| e.source.starts_with("sink."))
        .collect();
    assert!(sink_faults.is_empty(), "{sink_faults:?}");
    // At the last dwell (G4 P6.0) the PLC applies the engine's output, to the register's LSB.
    let last = h.trace().last().unwrap();
    for k in 0..3 {
        assert!(
            (last.applied_um[k] - lsb_round(last.output_um[k])).abs() < 1e-9,
            "axis {k}: {last:?}"
        );
    }
    eprintln!(
        "served loop: {} master writes, applied {:?} before the restart, {:?} at the end",
        h.writes().len(),
        before,
        last.applied_um
    );
}
