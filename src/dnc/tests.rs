//! The DNC core in virtual time: corrections taken at send time through the guard, line length,
//! flow control and stall, resume, leader/trailer.

use retrocomp_bus::fault::FaultKind;
use retrocomp_bus::{ChannelTable, Health, Sample};
use retrocomp_model::approach::Approach;
use retrocomp_model::{Axis, MachineModel};

use super::core::{CoreConfig, DncCore, DncError, SentBlock, StallEdge, XOFF, XON};
use super::lead::LeadConfig;
use super::live::{CorrectionAt, EngineAtPoint, LiveCorrections};
use retrocomp_gateway::ChannelLimits;
use retrocomp_gateway::DirectionConfig;
use retrocomp_gateway::SafetyConfig;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_gateway::engine::{Engine, EngineAxis, EngineConfig};
use retrocomp_gateway::sinks::dnc::LineEnd;
use retrocomp_gateway::status::StatusSnapshot;

/// X correction = −(drift · t + slope · x) µm (a thermal drift and a scale error); Y, Z none.
struct Drift {
    um_per_s: f64,
    um_per_mm: f64,
    fail_after_s: f64,
}

impl CorrectionAt for Drift {
    fn correction_um(
        &mut self,
        pos_mm: [f64; 3],
        _dirs: [Approach; 3],
        now_s: f64,
    ) -> Result<[Option<f64>; 3], String> {
        if now_s > self.fail_after_s {
            return Err("no recent value of T_spindle_C".into());
        }
        Ok([
            Some(-(self.um_per_s * now_s + self.um_per_mm * pos_mm[0])),
            None,
            None,
        ])
    }
}

pub(super) fn live(um_per_s: f64, cap_um: f64) -> LiveCorrections {
    LiveCorrections::new(
        Box::new(Drift {
            um_per_s,
            um_per_mm: 0.01,
            fail_after_s: f64::INFINITY,
        }),
        [(60.0, cap_um), (0.0, 0.0), (0.0, 0.0)],
    )
}

pub(super) fn cfg() -> CoreConfig {
    CoreConfig {
        line_end: LineEnd::CrLf,
        max_line_chars: 40,
        leader_nuls: 0,
        trailer_nuls: 0,
        stall_timeout_s: 5.0,
        start_timeout_s: 10.0,
        semicolon_is_eob: false,
        diameter_x: false,
        resume_from: 1,
        max_correction_um: 60.0,
        lead: LeadConfig::off(5),
    }
}

const PROGRAM: &str = "%\nG90 G1 F100\nX10 Y0 Z0\nX20\nX30\nX40\nM30\n%";

/// Send everything, one unit every `dt_s`, never stopped; returns the bytes and the log.
pub(super) fn drain(core: &mut DncCore<'_>, program: &str, dt_s: f64) -> (String, Vec<SentBlock>) {
    let (mut out, mut log, mut t) = (Vec::new(), Vec::new(), 0.0);
    let mut lines = program.lines().enumerate();
    while !core.done() {
        if core.wants_input() {
            match lines.next() {
                Some((i, l)) => core.feed_line(i as u64 + 1, l).unwrap(),
                None => core.end_of_input(),
            }
            continue;
        }
        if let Some(b) = core.next_to_send(t).unwrap() {
            out.extend_from_slice(b);
            log.extend(core.sent(t));
        }
        t += dt_s;
    }
    (String::from_utf8(out).unwrap(), log)
}

fn x_of(line: &str) -> f64 {
    let w = line.split(' ').find(|w| w.starts_with('X')).unwrap();
    w[1..].parse().unwrap()
}

#[test]
fn each_block_carries_the_correction_at_its_send_time_at_its_end_point() {
    let lc = live(0.1, 50.0);
    let mut core = DncCore::new(cfg(), &lc);
    let (out, log) = drain(&mut core, PROGRAM, 10.0);
    let moves: Vec<&SentBlock> = log.iter().filter(|b| b.applied.is_some()).collect();
    assert_eq!(moves.len(), 4, "{log:?}");
    for b in &moves {
        let a = b.applied.unwrap();
        let want = -(0.1 * b.t_s + 0.01 * a.pos_mm[0]);
        assert!((a.correction_um[0] - want).abs() <= 0.05 + 1e-9, "{b:?}");
        // The line sent ends at nominal + correction.
        let x = x_of(&b.text);
        assert!(
            (x - (a.pos_mm[0] + a.correction_um[0] / 1000.0)).abs() < 1e-9,
            "{b:?}"
        );
    }
    // Later blocks were sent later and carry more drift.
    assert!(
        moves[3].applied.unwrap().correction_um[0]
            < moves[0].applied.unwrap().correction_um[0] - 2.0
    );
    assert!(out.ends_with("%\r\n") && out.contains("M30\r\n"), "{out:?}");
    assert_eq!(log.len(), 8, "every block sent once");
}

#[test]
fn the_change_between_two_blocks_is_capped_by_the_guard() {
    let lc = live(0.0, 0.5);
    let mut core = DncCore::new(cfg(), &lc);
    let (_, log) = drain(&mut core, "G1 X100 F100\nX200\nX300\nX400", 1.0);
    let c: Vec<f64> = log
        .iter()
        .map(|b| b.applied.unwrap().correction_um[0])
        .collect();
    // Wanted −1, −2, −3, −4 µm; the controller held 0 before the first block.
    assert_eq!(c, vec![-0.5, -1.0, -1.5, -2.0]);
    assert!(!lc.guard_refused());
}

#[test]
fn a_block_that_would_grow_past_the_line_length_is_refused_not_truncated() {
    let lc = live(1.0, 50.0);
    let mut c = cfg();
    c.max_line_chars = 18;
    let mut core = DncCore::new(c, &lc);
    core.feed_line(1, "G1 X1 Y2 Z3 F100").unwrap();
    match core.next_to_send(30.0) {
        Err(DncError::LineTooLong { line, chars, max }) => {
            assert_eq!((line, max), (1, 18));
            assert!(chars > 18);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(core.blocks_sent(), 0);
    assert_eq!(core.resume_point(), 1);
}

#[test]
fn xoff_holds_the_next_line_and_a_long_hold_is_one_stall_fault_without_loss() {
    let lc = live(0.0, 50.0);
    let mut core = DncCore::new(cfg(), &lc);
    for (i, l) in ["G1 X1 F100", "X2", "X3"].iter().enumerate() {
        core.feed_line(i as u64 + 1, l).unwrap();
    }
    core.end_of_input();
    assert!(core.next_to_send(0.0).unwrap().is_some());
    assert_eq!(core.sent(0.0).map(|b| b.line), Some(1));
    core.on_bytes(&[b'x', XOFF], 0.5);
    assert!(core.next_to_send(1.0).unwrap().is_none());
    assert_eq!(core.poll_stall(5.4), None, "within the timeout");
    assert_eq!(
        core.poll_stall(5.6),
        Some(StallEdge::Started {
            since_s: 0.5,
            line: 2
        })
    );
    assert_eq!(core.poll_stall(100.0), None, "one edge per episode");
    assert!(core.stalled());
    assert_eq!(core.resume_point(), 2);
    core.on_bytes(&[XON], 101.0);
    assert_eq!(
        core.poll_stall(101.0),
        Some(StallEdge::Cleared { after_s: 101.0 })
    );
    let mut sent = vec![];
    while let Some(b) = core.next_to_send(102.0).unwrap() {
        sent.push(String::from_utf8(b.to_vec()).unwrap());
        core.sent(102.0);
    }
    assert_eq!(sent.len(), 2, "blocks 2 and 3, each once: {sent:?}");
    assert!(
        sent[0].starts_with("X2") && sent[1].starts_with("X3"),
        "{sent:?}"
    );
    assert!(core.done());
}

#[test]
fn resume_sends_from_the_chosen_block_with_the_modal_state_of_the_ones_before() {
    let lc = live(0.0, 50.0);
    let mut c = cfg();
    c.resume_from = 4;
    let mut core = DncCore::new(c, &lc);
    let (out, log) = drain(&mut core, "G90 G1 X0 F100\nG91\nX10\nX10\nX10", 1.0);
    assert_eq!(log.iter().map(|b| b.line).collect::<Vec<_>>(), vec![4, 5]);
    // Incremental from line 2: block 4 ends at 20 mm nominal (0 + 10 + 10).
    assert!((log[0].applied.unwrap().pos_mm[0] - 20.0).abs() < 1e-9);
    assert!(out.starts_with("X"), "{out:?}");
}

/// −0.01 µm per mm of X, and no model value after 1.5 s.
fn failing_after_1_5_s() -> LiveCorrections {
    LiveCorrections::new(
        Box::new(Drift {
            um_per_s: 0.0,
            um_per_mm: 0.01,
            fail_after_s: 1.5,
        }),
        [(60.0, 50.0), (0.0, 0.0), (0.0, 0.0)],
    )
}

#[test]
fn a_model_without_fresh_inputs_holds_the_last_correction() {
    let lc = failing_after_1_5_s();
    let mut core = DncCore::new(cfg(), &lc);
    let (_, log) = drain(&mut core, "G1 X100 F100\nX300", 2.0);
    assert_eq!(log[0].applied.unwrap().correction_um[0], -1.0);
    assert_eq!(
        log[1].applied.unwrap().correction_um[0],
        -1.0,
        "held, not −3"
    );
    assert!(lc.model_fault().is_some());
}

#[test]
fn leader_and_trailer_frame_the_program() {
    let lc = live(0.0, 50.0);
    let mut c = cfg();
    (c.leader_nuls, c.trailer_nuls, c.line_end) = (3, 2, LineEnd::Lf);
    let mut core = DncCore::new(c, &lc);
    let (out, _) = drain(&mut core, "%\nM30\n%", 1.0);
    assert_eq!(out, "\0\0\0%\nM30\n%\n\0\0");
}

#[test]
fn a_lathe_in_diameter_mode_gets_the_radial_correction_twice_in_its_x_word() {
    // 10 µm per 100 mm of radius, so a diameter taken for a radius shows.
    let scale = Drift {
        um_per_s: 0.0,
        um_per_mm: 0.1,
        fail_after_s: f64::INFINITY,
    };
    let lc = LiveCorrections::new(Box::new(scale), [(60.0, 50.0), (0.0, 0.0), (0.0, 0.0)]);
    let mut c = cfg();
    c.diameter_x = true;
    let mut core = DncCore::new(c, &lc);
    let (_, log) = drain(&mut core, "G1 X100 Z0 F100\nX60", 1.0);
    let (a, b) = (log[0].applied.unwrap(), log[1].applied.unwrap());
    // Ø100 is 50 mm from the axis: the model is asked there, −5 µm in radius.
    assert_eq!((a.pos_mm[0], b.pos_mm[0]), (50.0, 30.0));
    assert!((a.correction_um[0] + 5.0).abs() < 1e-9, "{a:?}");
    assert!((b.correction_um[0] + 3.0).abs() < 1e-9, "{b:?}");
    // The diameter word carries twice the radial correction: Ø100 − 10 µm, Ø60 − 6 µm.
    assert!((x_of(&log[0].text) - 99.99).abs() < 1e-9, "{:?}", log[0]);
    assert!((x_of(&log[1].text) - 59.994).abs() < 1e-9, "{:?}", log[1]);
}

/// The model of tests/real_peers/dnc_peers.rs: EXX forward 0 → 8 µm, reverse −3 → 5 µm over 0…400 mm, and
/// 2 µm/K of spindle temperature above 20 °C.
pub(super) const MODEL: &str = include_str!("../../tests/peers/dnc_model.toml");

const T_LIMITS: ChannelLimits = ChannelLimits {
    min: 0.0,
    max: 80.0,
    stale_after_s: 2.0,
    max_rate_per_s: Some(1.0),
    stuck_after_s: None,
};

/// The engine's channels: every table built here gives the same ids (one fixed order).
fn channels() -> ChannelTable {
    let mut table = ChannelTable::default();
    table.resolve("x_mm");
    table.resolve("T_spindle_C");
    table
}

pub(super) fn engine() -> Engine {
    let table = channels();
    let safety = SafetyConfig {
        max_correction_um: 100.0,
        max_change_um_per_cycle: 0.5,
        ramp_um_per_s: 20.0,
        stale_hold_s: 2.0,
    };
    Engine::from_config(
        &EngineConfig {
            axes: vec![EngineAxis {
                axis: Axis::X,
                position: table.get("x_mm").unwrap(),
                safety,
            }],
            channels: vec![(table.get("T_spindle_C").unwrap(), T_LIMITS)],
            recoveries: vec![],
            direction: DirectionConfig {
                deadband_mm: 0.005,
                switch_time_s: 0.1,
            },
            thermal_period_s: 1.0,
            enabled: true,
        },
        table,
        &[],
    )
    .unwrap()
}

fn model() -> Box<MachineModelAdapter> {
    Box::new(MachineModelAdapter::new(
        MachineModel::from_toml_str(MODEL, "dnc_model.toml").unwrap(),
    ))
}

pub(super) fn temp(t_s: f64, value: f64) -> Sample {
    Sample {
        channel: channels().get("T_spindle_C").unwrap(),
        t_s,
        value,
        health: Health::Ok,
    }
}

/// The DNC side: the engine at each block's end point, through the guard.
fn dnc_live() -> LiveCorrections {
    LiveCorrections::new(
        Box::new(EngineAtPoint::new(engine(), model())),
        [(100.0, 50.0), (0.0, 0.0), (0.0, 0.0)],
    )
}

/// The gateway's own cycle, fed the same temperatures as the DNC side.
struct Gateway {
    engine: Engine,
    model: Box<MachineModelAdapter>,
}

fn gateway() -> Gateway {
    Gateway {
        engine: engine(),
        model: model(),
    }
}

fn feed(lc: &LiveCorrections, gw: &mut Gateway, s: Sample) {
    lc.observe(&s);
    gw.engine.handle_sample(&s);
}

#[derive(Debug)]
struct Judged {
    cx_um: f64,
    /// The faults of T_spindle_C as the DNC engine and the gateway's cycle judge them.
    dnc: Vec<FaultKind>,
    gateway: Vec<FaultKind>,
    model_fault: Option<String>,
}

/// Send `line` at `t_s` while the gateway cycles at the same time.
fn block(
    core: &mut DncCore<'_>,
    lc: &LiveCorrections,
    gw: &mut Gateway,
    (n, line): (u64, &str),
    t_s: f64,
) -> Judged {
    core.feed_line(n, line).unwrap();
    assert!(core.next_to_send(t_s).unwrap().is_some());
    let b = core.sent(t_s).unwrap();
    gw.engine.cycle(t_s, gw.model.as_mut());
    let faults = |s: StatusSnapshot| -> Vec<FaultKind> {
        s.active_faults
            .into_iter()
            .filter(|(src, _, _)| src == "T_spindle_C")
            .map(|(_, k, _)| k)
            .collect()
    };
    Judged {
        cx_um: b.applied.unwrap().correction_um[0],
        dnc: faults(lc.snapshot().unwrap()),
        gateway: faults(gw.engine.snapshot()),
        model_fault: lc.model_fault(),
    }
}

/// 25 °C at 0 s, then the first block at `t_s`: X350 approached forward, EXX 8·350/400 = 7 µm +
/// 5 K × 2 µm/K = 17 µm → −17 µm, no fault on either side.
fn first_block_at_x350(core: &mut DncCore<'_>, lc: &LiveCorrections, gw: &mut Gateway, t_s: f64) {
    feed(lc, gw, temp(0.0, 25.0));
    let j = block(core, lc, gw, (1, "G90 G1 X350 F100"), t_s);
    assert!((j.cx_um + 17.0).abs() < 0.05 + 1e-9, "{j:?}");
    assert!(j.dnc.is_empty() && j.gateway.is_empty(), "{j:?}");
}

#[test]
fn a_stale_temperature_is_refused_as_the_gateway_refuses_it_and_the_block_holds() {
    let (lc, mut gw) = (dnc_live(), gateway());
    let mut core = DncCore::new(cfg(), &lc);
    first_block_at_x350(&mut core, &lc, &mut gw, 0.5);
    // No temperature for 4 s (stale after 2 s): refused, the block carries −17 µm again.
    let j = block(&mut core, &lc, &mut gw, (2, "X50"), 4.0);
    assert_eq!(j.cx_um, -17.0, "{j:?}");
    assert_eq!(j.dnc, vec![FaultKind::Stale]);
    assert_eq!(j.dnc, j.gateway, "judged as the gateway judges it");
    let why = j.model_fault.unwrap();
    assert!(why.contains("T_spindle_C (stale)"), "{why}");
    // A fresh reading is used from the next thermal latch on (1 s period, as in the gateway):
    // X50 reverse, −3 + 8·50/400 = −2 µm, + 10 µm = 8 µm → −8 µm.
    feed(&lc, &mut gw, temp(4.1, 25.0));
    let j = block(&mut core, &lc, &mut gw, (3, "X50.0"), 4.2);
    assert_eq!(j.cx_um, -17.0, "{j:?}");
    let why = j.model_fault.unwrap();
    assert!(why.contains("next thermal latch"), "{why}");
    feed(&lc, &mut gw, temp(5.0, 25.0));
    let j = block(&mut core, &lc, &mut gw, (4, "X50.00"), 5.1);
    assert!((j.cx_um + 8.0).abs() < 0.05 + 1e-9, "{j:?}");
    assert!(j.dnc.is_empty() && j.gateway.is_empty(), "{j:?}");
    assert!(j.model_fault.is_none());
}

#[test]
fn an_out_of_range_or_too_fast_temperature_is_refused_as_the_gateway_refuses_it() {
    let (lc, mut gw) = (dnc_live(), gateway());
    let mut core = DncCore::new(cfg(), &lc);
    first_block_at_x350(&mut core, &lc, &mut gw, 0.2);
    // 500 °C is beyond the channel's 0…80: never used, the block holds −17 µm.
    feed(&lc, &mut gw, temp(0.5, 500.0));
    let j = block(&mut core, &lc, &mut gw, (2, "X350.0"), 0.6);
    assert_eq!(j.cx_um, -17.0, "{j:?}");
    assert_eq!(j.dnc, vec![FaultKind::OutOfRange]);
    assert_eq!(j.dnc, j.gateway);
    // 25 → 45 °C in 1 s, beyond 1 K/s: a rate fault, refused the same way.
    feed(&lc, &mut gw, temp(1.0, 45.0));
    let j = block(&mut core, &lc, &mut gw, (3, "X350.00"), 1.1);
    assert_eq!(j.cx_um, -17.0, "{j:?}");
    assert_eq!(j.dnc, vec![FaultKind::RateOfChange]);
    assert_eq!(j.dnc, j.gateway);
    // Plausible again (25.5 °C): live, 17 + 0.5 K × 2 µm/K = 18 µm → −18 µm.
    feed(&lc, &mut gw, temp(1.5, 25.5));
    let j = block(&mut core, &lc, &mut gw, (4, "X350.000"), 2.2);
    assert!((j.cx_um + 18.0).abs() < 0.05 + 1e-9, "{j:?}");
    assert!(j.dnc.is_empty() && j.gateway.is_empty(), "{j:?}");
}

#[test]
fn the_transfers_faults_start_and_clear_in_the_published_status_and_metrics() {
    use super::faults::DncFaults;
    use super::shell::DncSummary;
    let (tx, rx) = tokio::sync::watch::channel(None);
    let mut faults = DncFaults::new(Some(tx));
    let mut sum = DncSummary::default();
    let lc = failing_after_1_5_s();
    let sink_faults = || {
        let s = rx.borrow().clone().unwrap();
        let k = s.sink.clone().unwrap();
        assert_eq!(k.kind, "dnc");
        assert_eq!(
            s.active_faults, k.faults,
            "the transfer's faults are the box's"
        );
        (
            k.faults
                .into_iter()
                .map(|(src, kind, _)| (src, kind))
                .collect::<Vec<_>>(),
            s.prometheus(),
        )
    };
    faults.stall(
        Some(StallEdge::Started {
            since_s: 0.5,
            line: 2,
        }),
        &mut sum,
        5.6,
    );
    faults.publish(&lc, &sum, 5.6);
    let (f, metrics) = sink_faults();
    assert_eq!(f, vec![("sink.dnc".to_string(), FaultKind::Disconnected)]);
    assert!(
        metrics.contains(r#"retrocomp_sink_fault_active{source="sink.dnc",kind="disconnected"} 1"#),
        "{metrics}"
    );
    faults.stall(Some(StallEdge::Cleared { after_s: 7.0 }), &mut sum, 7.0);
    faults.publish(&lc, &sum, 7.0);
    assert_eq!(sink_faults().0, vec![], "cleared at XON");
    // Two blocks, the second one after the model's inputs failed: sent with the held value.
    let mut core = DncCore::new(cfg(), &lc);
    let (_, log) = drain(&mut core, "G1 X100 F100\nX300", 2.0);
    faults.block(&lc, &mut sum, log[1].line, 8.0);
    faults.line_refused(8.0);
    faults.inputs_refused(8.0);
    faults.publish(&lc, &sum, 8.0);
    let (f, metrics) = sink_faults();
    assert_eq!(
        f,
        vec![
            ("sink.dnc.inputs".to_string(), FaultKind::Stale),
            ("sink.dnc.line".to_string(), FaultKind::OutOfRange),
            ("sink.dnc.model".to_string(), FaultKind::Decode),
        ]
    );
    assert!(metrics.contains("retrocomp_faults_active 3"), "{metrics}");
    assert!(
        metrics.contains(r#"retrocomp_sink_fault_active{source="sink.dnc.inputs",kind="stale"} 1"#),
        "{metrics}"
    );
    assert_eq!((sum.stalls, sum.model_faults), (1, 1));
    let held = rx.borrow().clone().unwrap().sink.clone().unwrap().held_um;
    assert!(
        held.is_empty(),
        "a source without axes names none: {held:?}"
    );
}

#[test]
fn nothing_is_sent_before_the_models_inputs_are_read_and_the_first_block_carries_them() {
    let lc = dnc_live();
    let mut c = cfg();
    c.leader_nuls = 10;
    let mut core = DncCore::new(c, &lc);
    core.feed_line(1, "G90 G1 X350 F100").unwrap();
    // No temperature yet: not even the leader goes, and the core says what it waits for.
    for t_s in [0.0, 1.0, 5.0] {
        assert!(core.next_to_send(t_s).unwrap().is_none(), "at {t_s} s");
    }
    let why = core.waiting_for_inputs().unwrap();
    assert!(why.contains("T_spindle_C ("), "{why}");
    // 25 °C arrives: leader, then X350 with EXX 7 µm + 5 K × 2 µm/K → −17 µm.
    lc.observe(&temp(5.5, 25.0));
    assert_eq!(core.next_to_send(6.0).unwrap().unwrap(), &[0u8; 10][..]);
    assert!(core.sent(6.0).is_none());
    assert!(core.waiting_for_inputs().is_none());
    assert!(core.next_to_send(6.1).unwrap().is_some());
    let b = core.sent(6.1).unwrap();
    assert!(
        (b.applied.unwrap().correction_um[0] + 17.0).abs() < 0.05 + 1e-9,
        "{b:?}"
    );
    assert!(lc.model_fault().is_none());
}

#[test]
fn a_model_whose_inputs_never_come_refuses_the_transfer_with_nothing_sent() {
    let lc = dnc_live();
    let mut core = DncCore::new(cfg(), &lc);
    core.feed_line(1, "G90 G1 X350 F100").unwrap();
    assert!(core.next_to_send(2.0).unwrap().is_none());
    assert!(core.next_to_send(11.9).unwrap().is_none());
    // 10 s (start_timeout_s) after the first try.
    match core.next_to_send(12.0) {
        Err(DncError::NoInputs { waited_s, why }) => {
            assert_eq!(waited_s, 10.0);
            assert!(why.contains("T_spindle_C"), "{why}");
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(
        core.resume_point(),
        1,
        "the first block is where it resumes"
    );
}
