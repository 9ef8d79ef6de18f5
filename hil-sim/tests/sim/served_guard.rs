//! The server mode's last step in virtual time, through the gateway's own sans-IO core
//! (`GatewayCore::start_served`: the register bank and the `ServedSink` the server's shell
//! drives) with the LinuxCNC sim kit's shipped field file (`deploy/linuxcnc/sim/retrocomp-sim.toml`:
//! clamp 50 µm = 500 counts, cap 1 µm = 10 counts per 20 ms update) and its model. The twin of
//! `tests/real_peers/gateway_server_guard.rs` (real binary, real pymodbus clients):
//!
//! 1. nothing is readable and no cycle runs until the controller reports what it holds; then a
//!    second writer puts 0x7FFF (3276.7 µm) into X's held register with FC06: every read of every
//!    correction register, before and after, is an exception or within 500 counts, X is withdrawn
//!    and `sink.origin_shift_server.x` has one `beyond_clamp` episode;
//! 2. an mb2hal-like controller (every 20 ms: read each correction, an exception keeps what it
//!    applies; apply; write back position, held and marker) brings X back: every value it reads
//!    is within the clamp and one cap from what it applied;
//! 3. a stop serves a ramp to 0 within the cap until the controller reports holding 0;
//! 4. a register the controller has not written is not a report (of 0).

use std::path::Path;

use retrocomp_bus::fault::FaultKind;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_gateway::gateway_core::GatewayCore;
use retrocomp_gateway::sinks::origin_shift::StopEnd;
use retrocomp_model::{Axis, MachineModel};
use tokio_modbus::prelude::{ExceptionCode, Request, Response};

const CLAMP_COUNTS: i16 = 500;
const CAP_COUNTS: i16 = 10;
const MARKER: u16 = 0x55AA;
/// Positions of X/Y/Z in 25 µm counts (150, 100, 100 mm).
const POSITIONS: [u16; 3] = [6000, 4000, 4000];

fn gateway() -> GatewayCore {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let field = FieldConfig::load(&root.join("deploy/linuxcnc/sim/retrocomp-sim.toml"))
        .expect("the sim kit's field file");
    let model = MachineModel::from_toml_path(&root.join("deploy/field/vmc-geometry.toml"))
        .expect("its model");
    GatewayCore::start_served(field, Box::new(MachineModelAdapter::new(model)), 0.0).expect("start")
}

/// FC03 of one correction register: its counts, or the exception.
fn read(gw: &mut GatewayCore, axis: u16, t: f64) -> Result<i16, ExceptionCode> {
    match gw.handle_server_request(&Request::ReadHoldingRegisters(axis, 1), t)? {
        Response::ReadHoldingRegisters(w) => Ok(w[0].cast_signed()),
        other => panic!("{other:?}"),
    }
}

/// The controller's FC16 at 10: positions, what it applies (counts), the marker.
fn report(gw: &mut GatewayCore, held: [i16; 3], t: f64) {
    let mut words = POSITIONS.to_vec();
    words.extend(held.map(i16::cast_unsigned));
    words.push(MARKER);
    let r = gw.handle_server_request(&Request::WriteMultipleRegisters(10, words.into()), t);
    assert!(r.is_ok(), "{r:?}");
}

/// One millisecond of the box: a cycle every 5 ms, an update every 20 ms (the field file's).
fn step_box(gw: &mut GatewayCore, ms: u64) -> Option<StopEnd> {
    let t = ms as f64 / 1e3;
    if ms.is_multiple_of(5) {
        gw.poll_cycle(t);
    }
    if ms.is_multiple_of(20) {
        gw.poll_served(t)
    } else {
        None
    }
}

#[test]
fn a_rogue_held_value_is_never_served_from_and_the_controller_brings_the_axis_back() {
    let mut gw = gateway();
    let mut reads: Vec<(u64, u16, Result<i16, ExceptionCode>)> = Vec::new();
    // Before the controller reports: no register, no cycle.
    for ms in 0..100 {
        step_box(&mut gw, ms);
        if ms % 20 == 7 {
            assert_eq!(
                read(&mut gw, 0, ms as f64 / 1e3),
                Err(ExceptionCode::IllegalDataAddress)
            );
        }
    }
    assert_eq!(
        gw.cycle_core().engine().snapshot().cycles,
        0,
        "no cycle before the report"
    );
    report(&mut gw, [0; 3], 0.1);
    // Phase 1: the controller only reads; at 1 s another writer sends FC06 0x7FFF to X's held.
    let mut rogue_events = Vec::new();
    for ms in 100..2000 {
        let t = ms as f64 / 1e3;
        step_box(&mut gw, ms);
        if ms == 1000 {
            let r = gw.handle_server_request(&Request::WriteSingleRegister(13, 0x7FFF), t);
            assert!(
                r.is_ok(),
                "the held register takes any writer's report: {r:?}"
            );
        }
        if ms % 20 == 7 {
            for axis in 0..3 {
                reads.push((ms, axis, read(&mut gw, axis, t)));
            }
        }
        rogue_events.extend(gw.take_edges());
    }
    assert!(gw.cycle_core().engine().snapshot().cycles > 300);
    assert!(
        reads
            .iter()
            .any(|(ms, a, r)| *ms < 1000 && *a == 0 && r.is_ok_and(|v| v != 0)),
        "a correction was served before the rogue write: {reads:?}"
    );
    for (ms, axis, r) in &reads {
        if let Ok(v) = r {
            assert!(v.abs() <= CLAMP_COUNTS, "{ms} ms, axis {axis}: {v}");
        }
        if *axis == 0 && *ms > 1020 {
            assert_eq!(
                *r,
                Err(ExceptionCode::IllegalDataAddress),
                "{ms} ms: X withdrawn"
            );
        }
    }
    let x_clamp: Vec<_> = rogue_events
        .iter()
        .filter(|e| e.source == "sink.origin_shift_server.x" && e.kind == FaultKind::BeyondClamp)
        .map(|e| e.started)
        .collect();
    assert_eq!(x_clamp, [true], "one beyond_clamp episode, still active");
    // Phase 2: the controller's own cycle; its report of what it applies is the truth again.
    let mut applied = [0i16; 3];
    let mut served_after = 0;
    for ms in 2000..4000 {
        let t = ms as f64 / 1e3;
        step_box(&mut gw, ms);
        if ms % 20 == 7 {
            for axis in 0..3u16 {
                let k = usize::from(axis);
                if let Ok(v) = read(&mut gw, axis, t) {
                    assert!(v.abs() <= CLAMP_COUNTS, "{ms} ms, axis {axis}: {v}");
                    assert!(
                        (v - applied[k]).abs() <= CAP_COUNTS,
                        "{ms} ms, axis {axis}: {v} after {}",
                        applied[k]
                    );
                    applied[k] = v;
                    served_after += usize::from(axis == 0);
                }
            }
            report(&mut gw, applied, t);
        }
    }
    assert!(served_after > 50, "X served again: {served_after} reads");
    let cleared = gw.take_edges().iter().any(|e| {
        e.source == "sink.origin_shift_server.x" && e.kind == FaultKind::BeyondClamp && !e.started
    });
    assert!(cleared, "the beyond_clamp episode ends");
    assert!(
        applied.iter().any(|v| v.abs() > CAP_COUNTS),
        "a correction of several caps: {applied:?}"
    );
    eprintln!("served guard: the controller applies {applied:?} counts before the stop");
    // Phase 3: stop; every read is one cap closer to 0, until the controller reports 0.
    gw.handle_stop();
    let mut end = None;
    for ms in 4000..8000 {
        let t = ms as f64 / 1e3;
        if let Some(e) = step_box(&mut gw, ms) {
            end = Some((e, ms));
            break;
        }
        if ms % 20 == 7 {
            for axis in 0..3u16 {
                let k = usize::from(axis);
                if let Ok(v) = read(&mut gw, axis, t) {
                    assert!(
                        v.abs() <= applied[k].abs(),
                        "{ms} ms, axis {axis}: {v} after {}",
                        applied[k]
                    );
                    assert!((v - applied[k]).abs() <= CAP_COUNTS);
                    applied[k] = v;
                }
            }
            report(&mut gw, applied, t);
        }
    }
    let (end, ms) = end.expect("the stop ended");
    eprintln!(
        "served guard: {} reads in phase 1, X served {served_after} times after the rogue write, stop ended {end:?} at {ms} ms",
        reads.len()
    );
    assert_eq!(end, StopEnd::RampedOut, "at {ms} ms: {applied:?}");
    assert_eq!(applied, [0; 3]);
    assert!(gw.is_ramped_out());
}

/// The engine starts from what the controller reports holding, as `retrocomp run` does after
/// `wait_seeded`; a value beyond the clamp is not a start value (that axis starts at 0 and is
/// not served).
#[test]
fn the_engine_starts_from_the_controllers_report_within_the_clamp() {
    let mut gw = gateway();
    report(&mut gw, [20, -30, 600], 0.0);
    let start: Vec<(Axis, f64)> = gw.outputs().to_vec();
    assert_eq!(start, [(Axis::X, 2.0), (Axis::Y, -3.0), (Axis::Z, 0.0)]);
    assert_eq!(gw.poll_served(0.02), None);
    let edges = gw.take_edges();
    assert!(
        edges
            .iter()
            .any(|e| e.source == "sink.origin_shift_server.z"
                && e.kind == FaultKind::BeyondClamp
                && e.started),
        "{edges:?}"
    );
    assert_eq!(
        read(&mut gw, 2, 0.03),
        Err(ExceptionCode::IllegalDataAddress)
    );
    let x = read(&mut gw, 0, 0.03).expect("x served");
    assert!((x - 20).abs() <= CAP_COUNTS, "{x}");
}

/// A controller that writes its registers one request at a time (a PLC's master block per
/// axis): a held register it has not written yet reads 0 in the image, and that 0 is nobody's
/// report. The engine starts once every axis was reported, from the reported values.
#[test]
fn registers_the_controller_has_not_written_are_not_reports_of_0() {
    let mut gw = gateway();
    let write = |gw: &mut GatewayCore, address: u16, value: u16| {
        let r = gw.handle_server_request(&Request::WriteSingleRegister(address, value), 0.0);
        assert!(r.is_ok(), "{r:?}");
    };
    write(&mut gw, 16, MARKER);
    write(&mut gw, 13, 20);
    assert_eq!(gw.poll_served(0.01), None);
    assert_eq!(
        read(&mut gw, 0, 0.011),
        Err(ExceptionCode::IllegalDataAddress),
        "Y and Z not reported: nothing served"
    );
    write(&mut gw, 14, (-30i16).cast_unsigned());
    write(&mut gw, 15, 40);
    let start: Vec<(Axis, f64)> = gw.outputs().to_vec();
    assert_eq!(start, [(Axis::X, 2.0), (Axis::Y, -3.0), (Axis::Z, 4.0)]);
}
