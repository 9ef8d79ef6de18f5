//! The gateway cycle allocates nothing in steady state (issue 5 item 8: the compute part of a cycle
//! must be cheap and predictable; issue 14.1: including handle_sample and sink encoding). With the demo's
//! full machine model (tables, squareness, thermal polynomial + expansion, cutting-force compliance)
//! behind `MachineModelAdapter`, moving axes with reversals (so the F/R blend evaluates the model
//! three times), changing temperatures and force:
//! - `Engine::handle_sample` + `Engine::cycle_in_place` make zero heap allocations per cycle;
//! - so does the real loop body (`CycleLoop::step`: samples from another thread through the
//!   sources' mpsc channel, engine, outputs into the sinks' watch channel) on every cycle that does
//!   not publish a status snapshot (≤ 10 Hz), also while faults stay active (a NaN sensor, a
//!   silent one, compensation dropped);
//! - so does the whole per-cycle path from the wire to the controller's words: CAN frames decoded
//!   by the CANopen source (CiA 406 encoders, CiA 404 analog inputs) → handle_sample → cycle → the
//!   origin-shift register encoding (`RegisterMap::encode_into`) and the quadrature count
//!   quantiser.
//!
//! Counted by a global allocator wrapper, per thread (the test harness runs other tests on other
//! threads).

use std::collections::BTreeMap;
use std::path::Path;

use retrocomp_bus::fault::FaultKind;
use retrocomp_bus::{Health, Sample};
use retrocomp_gateway::Engine;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::cycle::STATUS_PERIOD_S;
use retrocomp_gateway::engine::MachineModelAdapter;
use retrocomp_gateway::status::StatusSnapshot;
use retrocomp_model::Axis;
use retrocomp_model::MachineModel;

use crate::counting_alloc::allocs;

/// The origin-shift register map both sink tests encode into: three int32 axes of 0.1 µm, z's
/// register counting the other way (`sign = -1`).
const AXES_MAP: &str = r#"
[[axis]]
axis = "x"
address = 0
kind = "int32"
lsb_um = 0.1
sign = 1
[[axis]]
axis = "y"
address = 2
kind = "int32"
lsb_um = 0.1
sign = 1
[[axis]]
axis = "z"
address = 4
kind = "int32"
lsb_um = 0.1
sign = -1
"#;

const CFG: &str = r#"
[gateway]
name = "no-alloc"
cycle_ms = 1
thermal_period_s = 0.05
[safety]
max_correction_um = 200.0
max_change_um_per_cycle = 1.0
ramp_um_per_s = 400.0
stale_hold_s = 0.5
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
"#;

#[test]
fn steady_state_cycles_allocate_nothing() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = MachineModel::from_toml_path(&root.join("deploy/demo/mill-full.toml")).unwrap();
    let mut m = MachineModelAdapter::new(model);
    let cfg = FieldConfig::parse(CFG, Path::new("no-alloc.toml")).unwrap();
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let mut samples: Vec<Sample> = [
        "x_mm",
        "y_mm",
        "z_mm",
        "T_spindle_C",
        "T_xscrew_C",
        "F_cut_N",
    ]
    .iter()
    .map(|ch| Sample {
        channel: e.channels_mut().resolve(ch),
        t_s: 0.0,
        value: 0.0,
        health: Health::Ok,
    })
    .collect();
    let mut t = 0.0f64;
    let mut step = |e: &mut Engine, samples: &mut Vec<Sample>| {
        t += 1e-3;
        // X and Y reverse every ≈ 1 s and 1.6 s (F/R blend), temperatures and force drift.
        let values = [
            100.0 + 50.0 * (t * 3.0).sin(),
            60.0 + 40.0 * (t * 2.0).cos(),
            10.0 + 5.0 * t.sin(),
            25.0 + 3.0 * (t * 0.1).sin(),
            22.0 + t * 0.01,
            150.0 + 50.0 * (t * 5.0).sin(),
        ];
        for (s, v) in samples.iter_mut().zip(values) {
            s.t_s = t;
            s.value = v;
            e.handle_sample(s);
        }
        e.cycle_in_place(t, &mut m).iter().map(|o| o.1).sum::<f64>()
    };
    // Warm-up: channels appear, maps and buffers grow, compensation ramps in.
    for _ in 0..2000 {
        step(&mut e, &mut samples);
    }
    let before = allocs();
    let mut sum = 0.0;
    for _ in 0..5000 {
        sum += step(&mut e, &mut samples);
    }
    let n = allocs() - before;
    // The counter does count on this thread: the copying `cycle` allocates its output vector.
    let before_copy = allocs();
    let outs = e.cycle(t + 1e-3, &mut m);
    assert!(allocs() > before_copy && outs.len() == 3);
    // The cycles really computed something (else the cheap stale path would be measured).
    let snap = e.snapshot();
    assert!(sum.is_finite() && sum.abs() > 1.0, "outputs {sum}");
    assert!(
        snap.axes.iter().all(|a| a.target_um.is_some()),
        "{:?}",
        snap.axes
    );
    assert!(snap.axes[0].terms_um.len() >= 3, "{:?}", snap.axes[0]);
    assert_eq!(n, 0, "{n} heap allocations in 5000 steady-state cycles");
}

/// What one run of the real cycle loop showed.
struct LoopRun {
    /// Heap allocations on the cycle thread in the counted cycles that did not publish.
    quiet_allocs: u64,
    /// Snapshots published in the counted cycles.
    publishes: u64,
    snap: StatusSnapshot,
    outs: Vec<(Axis, f64)>,
}

/// Drive the real cycle loop body (`CycleLoop::step`) for `steps` cycles of 1 ms with the samples
/// `samples(k, t_s)` gives for cycle `k` (a channel not given is silent that cycle); count the
/// cycle thread's allocations from cycle `count_from` on. The samples come from another thread
/// through the same tokio mpsc channel the sources use, in lock-step with the loop.
fn drive_cycle_loop(
    steps: u64,
    count_from: u64,
    samples: fn(u64, f64) -> Vec<(&'static str, f64)>,
) -> LoopRun {
    use retrocomp_gateway::ErrorModel;
    use retrocomp_gateway::cycle::{CycleIo, CycleLoop};
    use std::sync::Arc;
    use std::sync::atomic::{AtomicU64, Ordering};
    use tokio::sync::{mpsc, watch};

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = MachineModel::from_toml_path(&root.join("deploy/demo/mill-full.toml")).unwrap();
    let cfg = FieldConfig::parse(CFG, Path::new("no-alloc.toml")).unwrap();
    let mut engine = cfg.engine(&BTreeMap::new()).unwrap();
    let model = MachineModelAdapter::new(model);
    // The producer's ids are the engine's: every name it sends (the model's inputs and the
    // channels of the first cycle, as the sources' table holds them) is in the table before the
    // engine moves to the loop.
    for name in model.required_channels() {
        engine.channels_mut().resolve(&name);
    }
    for (name, _) in samples(1, 1e-3) {
        engine.channels_mut().resolve(name);
    }
    let table = engine.channels().clone();
    let (sample_tx, sample_rx) = mpsc::channel(16_384);
    let (_served_tx, served) = mpsc::channel(8);
    let (_reseed_tx, reseed) = mpsc::channel(8);
    let (_control_tx, control) = mpsc::channel(8);
    let (outputs, outputs_rx) = watch::channel(Vec::new());
    let (status, status_rx) = watch::channel(None);
    let (_sink_tx, sink_status) = watch::channel(Default::default());
    let io = CycleIo {
        samples: sample_rx,
        served,
        reseed,
        control,
        outputs,
        status,
        sink_status,
        board: Default::default(),
        counter: Default::default(),
        wake: Default::default(),
        telemetry: None,
    };
    let mut lp = CycleLoop::new(engine, Box::new(model), io);
    // Lock-step with the producer through two counters (no allocation to synchronise).
    let sent = Arc::new(AtomicU64::new(0));
    let done = Arc::new(AtomicU64::new(0));
    let (s2, d2) = (Arc::clone(&sent), Arc::clone(&done));
    let producer = std::thread::spawn(move || {
        for k in 1..=steps {
            let t = k as f64 * 1e-3;
            for (ch, value) in samples(k, t) {
                let s = Sample {
                    channel: table.get(ch).expect("a channel the engine knows"),
                    t_s: t,
                    value,
                    health: Health::Ok,
                };
                sample_tx.try_send(s).unwrap();
            }
            s2.store(k, Ordering::Release);
            while d2.load(Ordering::Acquire) < k {
                std::thread::yield_now();
            }
        }
    });
    let (mut quiet_allocs, mut publishes) = (0u64, 0u64);
    for k in 1..=steps {
        while sent.load(Ordering::Acquire) < k {
            assert!(!producer.is_finished(), "the producer stopped at cycle {k}");
            std::thread::yield_now();
        }
        let before = allocs();
        let published = lp.step(k as f64 * 1e-3);
        if k > count_from {
            if published {
                publishes += 1;
            } else {
                quiet_allocs += allocs() - before;
            }
        }
        done.store(k, Ordering::Release);
    }
    producer.join().unwrap();
    let snap = status_rx
        .borrow()
        .clone()
        .expect("a snapshot was published");
    let outs = outputs_rx.borrow().clone();
    LoopRun {
        quiet_allocs,
        publishes,
        snap: (*snap).clone(),
        outs,
    }
}

/// The channels of the healthy run at cycle time `t` (s): X and Y reverse every ≈ 1 s and 1.6 s
/// (F/R blend), temperatures and force drift; `T_cabinet_C` is read but not in the model.
fn healthy(t: f64) -> Vec<(&'static str, f64)> {
    vec![
        ("x_mm", 100.0 + 50.0 * (t * 3.0).sin()),
        ("y_mm", 60.0 + 40.0 * (t * 2.0).cos()),
        ("z_mm", 10.0 + 5.0 * t.sin()),
        ("T_spindle_C", 25.0 + 3.0 * (t * 0.1).sin()),
        ("T_xscrew_C", 22.0 + t * 0.01),
        ("F_cut_N", 150.0 + 50.0 * (t * 5.0).sin()),
        ("T_cabinet_C", 30.0 + (t * 0.3).sin()),
    ]
}

fn has_fault(snap: &StatusSnapshot, source: &str, kind: FaultKind) -> bool {
    snap.active_faults
        .iter()
        .any(|(s, k, _)| s == source && *k == kind)
}

/// The real cycle loop body (`CycleLoop::step`: drain the sample channel, run the engine, hand the
/// outputs to the sink's watch channel, count the cycle) allocates nothing on a cycle that does not
/// publish a status snapshot, and publishes at most 10 Hz of cycle time.
#[test]
fn the_real_cycle_loop_allocates_nothing_between_status_snapshots() {
    const WARM: u64 = 2000;
    const STEPS: u64 = 5000;
    let run = drive_cycle_loop(WARM + STEPS, WARM, |_, t| healthy(t));
    // 5 s of cycle time at ≤ 10 Hz: 50 snapshots (one more at a boundary), not one per cycle.
    let most = (STEPS as f64 * 1e-3 / STATUS_PERIOD_S).ceil() as u64 + 1;
    assert!(
        (most - 2..=most).contains(&run.publishes),
        "{} snapshots in {STEPS} cycles",
        run.publishes
    );
    let snap = &run.snap;
    assert!(snap.cycles > WARM && snap.axes.iter().all(|a| a.target_um.is_some()));
    assert!(snap.active_faults.is_empty(), "{:?}", snap.active_faults);
    assert!(
        run.outs.len() == 3 && run.outs.iter().map(|o| o.1.abs()).sum::<f64>() > 1.0,
        "{:?}",
        run.outs
    );
    assert_eq!(
        run.quiet_allocs, 0,
        "{} heap allocations in the cycles between snapshots",
        run.quiet_allocs
    );
}

/// While faults stay active the cycle allocates nothing either (issue 14.1: the fault log is keyed
/// by typed sources). From cycle 2000 on the force sensor reads NaN (an optional input: the axes
/// compensate without its terms, `compensation.<axis>.partial`) and `T_cabinet_C` falls silent
/// (stale after 1 s); counted from cycle 4000, after every episode started.
#[test]
fn the_cycle_loop_allocates_nothing_while_a_sensor_is_nan_and_another_stale() {
    let run = drive_cycle_loop(9000, 4000, |k, t| {
        let mut s = healthy(t);
        if k > 2000 {
            s.retain(|(ch, _)| *ch != "T_cabinet_C");
            s.iter_mut()
                .filter(|(ch, _)| *ch == "F_cut_N")
                .for_each(|(_, v)| *v = f64::NAN);
        }
        s
    });
    let snap = &run.snap;
    for (source, kind) in [
        ("F_cut_N", FaultKind::NotFinite),
        ("T_cabinet_C", FaultKind::Stale),
        ("compensation.x.partial", FaultKind::Stale),
    ] {
        assert!(
            has_fault(snap, source, kind),
            "{source} {kind:?} not in {:?}",
            snap.active_faults
        );
    }
    // Still compensating (without the force terms): the model ran every cycle.
    assert!(
        snap.axes.iter().all(|a| a.target_um.is_some()),
        "{:?}",
        snap.axes
    );
    assert!(run.publishes >= 45, "{} snapshots", run.publishes);
    assert_eq!(
        run.quiet_allocs, 0,
        "{} heap allocations in 5000 cycles with active faults",
        run.quiet_allocs
    );
}

/// A required input stale: compensation drops on every axis (`compensation.<axis>`, holding then
/// ramping out) and the cycle still allocates nothing.
#[test]
fn the_cycle_loop_allocates_nothing_while_compensation_is_dropped() {
    let run = drive_cycle_loop(9000, 4000, |k, t| {
        let mut s = healthy(t);
        if k > 2000 {
            s.retain(|(ch, _)| *ch != "T_xscrew_C");
        }
        s
    });
    let snap = &run.snap;
    assert!(has_fault(snap, "T_xscrew_C", FaultKind::Stale), "{snap:?}");
    for axis in ["x", "y", "z"] {
        let source = format!("compensation.{axis}");
        assert!(has_fault(snap, &source, FaultKind::Stale), "{snap:?}");
    }
    assert!(snap.axes.iter().all(|a| a.target_um.is_none()));
    assert_eq!(
        run.quiet_allocs, 0,
        "{} heap allocations in 5000 cycles with compensation dropped",
        run.quiet_allocs
    );
}

/// From CAN frames to register words and quadrature counts, one thread, every cycle counted: the
/// CANopen source decodes the encoders' and analog nodes' TPDOs into a reused batch, the engine
/// ingests them and runs the cycle, and both sinks' encodings consume the outputs.
#[test]
fn frames_to_register_words_allocate_nothing_per_cycle() {
    use retrocomp_bus::canopen::{
        AnalogChannel, AnalogType, CanopenConfig, CanopenSource, EncoderChannel,
    };
    use retrocomp_gateway::sinks::origin_shift::{RegisterMap, WriteBlock};
    use retrocomp_gateway::sinks::quadrature::CountQuantizer;

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let model = MachineModel::from_toml_path(&root.join("deploy/demo/mill-full.toml")).unwrap();
    let mut m = MachineModelAdapter::new(model);
    let cfg = FieldConfig::parse(CFG, Path::new("no-alloc.toml")).unwrap();
    let mut e = cfg.engine(&BTreeMap::new()).unwrap();
    let encoder = |channel: &str, node_id: u8| EncoderChannel::new(channel, node_id, 1000.0);
    let analog = |channel: &str, node_id: u8| AnalogChannel {
        decimal_digits: 3,
        ..AnalogChannel::new(channel, node_id, AnalogType::Int32)
    };
    let can = CanopenConfig {
        encoder: vec![encoder("x_mm", 1), encoder("y_mm", 2), encoder("z_mm", 3)],
        analog: vec![
            analog("T_spindle_C", 0x10),
            analog("T_xscrew_C", 0x11),
            analog("F_cut_N", 0x12),
        ],
        heartbeat_timeout_s: None,
        pdo_timeout_s: 0.1,
    };
    let mut src = CanopenSource::new(can.clone(), e.channels_mut());
    let map: RegisterMap = toml::from_str(AXES_MAP).unwrap();
    map.validate().unwrap();
    let mut quantisers: Vec<CountQuantizer> = (0..3)
        .map(|_| CountQuantizer::new(0.1, 1).unwrap())
        .collect();
    let mut batch = Vec::with_capacity(64);
    let mut blocks: Vec<WriteBlock> = Vec::new();
    let (mut counts, mut decoded) = (0i64, 0usize);
    let mut t = 0.0f64;
    let mut cycle = |e: &mut Engine, t: &mut f64| -> u64 {
        *t += 1e-3;
        let t = *t;
        // The nodes' side (not counted): this cycle's TPDOs.
        let positions = [
            100.0 + 50.0 * (t * 3.0).sin(),
            60.0 + 40.0 * (t * 2.0).cos(),
            10.0 + 5.0 * t.sin(),
        ];
        let analogs = [
            25.0 + 3.0 * (t * 0.1).sin(),
            22.0 + t * 0.01,
            150.0 + 50.0 * (t * 5.0).sin(),
        ];
        let mut frames = [None; 6];
        for (k, (c, p)) in can.encoder.iter().zip(positions).enumerate() {
            frames[k] = c.encode_position(p);
        }
        for (k, (c, v)) in can.analog.iter().zip(analogs).enumerate() {
            frames[3 + k] = c.encode(v);
        }
        let before = allocs();
        for f in frames.iter().flatten() {
            src.handle_frame(f, t, &mut batch);
        }
        decoded += batch.len();
        for s in batch.drain(..) {
            e.handle_sample(&s);
        }
        let outs = e.cycle_in_place(t, &mut m);
        map.encode_into(outs, &mut blocks).unwrap();
        for ((_, v), q) in outs.iter().zip(&mut quantisers) {
            counts += q.delta_counts(*v).unwrap();
        }
        allocs() - before
    };
    for _ in 0..2000 {
        cycle(&mut e, &mut t);
    }
    let mut n = 0;
    for _ in 0..5000 {
        n += cycle(&mut e, &mut t);
    }
    // Every frame decoded, the axes compensating, the words those of the last outputs.
    assert_eq!(decoded, 7000 * 6);
    let outs = e.outputs();
    assert!(
        outs.len() == 3 && outs.iter().map(|o| o.1.abs()).sum::<f64>() > 1.0,
        "{outs:?}"
    );
    assert_eq!(blocks, map.encode(&outs).unwrap());
    let emitted: i64 = quantisers.iter().map(CountQuantizer::emitted_counts).sum();
    assert!(counts == emitted && counts != 0, "{counts} vs {emitted}");
    assert!(e.snapshot().axes.iter().all(|a| a.target_um.is_some()));
    assert_eq!(
        n, 0,
        "{n} heap allocations in 5000 cycles from frames to words"
    );
}

/// One origin-shift write period through the real sans-IO sink core (`SinkCore` and its
/// `WriteCycle`) allocates nothing: heartbeat → read of the value, strobe and ack registers (one
/// FC03) → the guard against what the controller holds (clamp, per-write cap) → encode → FC16 →
/// strobe → ack → read-back, plus the sink's fault bookkeeping (`update_faults_of`). The
/// controller is an in-memory register image that latches on the strobe; only the core's thread
/// is counted, and the image's replies carry their words inline as the transport's would.
#[test]
fn an_origin_shift_write_period_allocates_nothing() {
    use retrocomp_bus::fault::FaultLog;
    use retrocomp_gateway::sinks::origin_shift::{
        Action, Outcome, RegisterMap, Reply, SinkAxis, SinkCore, Words,
    };
    use retrocomp_gateway::sinks::origin_shift::{SinkSources, update_faults_of};

    let map: RegisterMap = toml::from_str(&format!(
        "heartbeat_address = 10\nheartbeat_timeout_ms = 60000\n{AXES_MAP}\
         [handshake]\nstrobe_address = 6\nack_address = 7\ntimeout_ms = 100\npoll_ms = 1\n"
    ))
    .unwrap();
    map.validate().unwrap();
    let axes = ["x", "y", "z"]
        .map(|a| SinkAxis {
            axis: a.into(),
            max_correction_um: 100.0,
            max_change_um_per_write: 0.5,
        })
        .to_vec();
    let mut core = SinkCore::new(map.clone(), axes);
    let sources = SinkSources::of(&core);
    let mut log = FaultLog::default();
    let mut regs = [0u16; 16];
    let (mut t, mut requests) = (0.0f64, 0u64);
    let mut wants = vec![(Axis::X, 0.0), (Axis::Y, 0.0), (Axis::Z, 0.0)];
    let mut period = |core: &mut SinkCore, log: &mut FaultLog, k: u64| -> Outcome {
        let ts = k as f64 * 0.01;
        wants[0].1 = 40.0 * (ts * 0.5).sin();
        wants[1].1 = -25.0 + 10.0 * (ts * 0.3).cos();
        wants[2].1 = 15.0 * (ts * 0.7).sin();
        let mut action = core.begin_at(&wants, t);
        let outcome = loop {
            let reply = match &action {
                Action::Done(o) => break o.clone(),
                Action::Write(b) => {
                    let a = b.address as usize;
                    regs[a..a + b.words.len()].copy_from_slice(&b.words);
                    if b.address == 6 {
                        regs[7] = regs[6]; // the PLC latches and acknowledges
                    }
                    Reply::Written
                }
                Action::Read { address, count, .. } => {
                    let a = *address as usize;
                    Reply::Read(Words::from_slice(&regs[a..a + *count as usize]))
                }
            };
            requests += 1;
            t += 1e-4;
            action = core.handle_reply(reply, t);
        };
        assert!(core.take_reseeds().is_empty());
        update_faults_of(log, &sources, core, true, t);
        outcome
    };
    for k in 0..200 {
        assert_eq!(period(&mut core, &mut log, k), Outcome::Ok);
    }
    let ok_before = core.writes_ok;
    let before = allocs();
    let mut n_ok = 0;
    for k in 200..1200 {
        n_ok += u64::from(period(&mut core, &mut log, k) == Outcome::Ok);
    }
    let n = allocs() - before;
    assert_eq!(n_ok, 1000);
    assert_eq!(core.writes_ok - ok_before, 1000, "every period wrote");
    // In memory every period takes the same exchange: six requests (deterministic, no retries).
    assert_eq!(requests, 1200 * 6, "{requests} requests");
    assert_eq!(log.active().count(), 0);
    // The controller holds the last guarded values: within one cap of what was wanted.
    let held: Vec<f64> = core.held_um().map(|(_, v)| v.unwrap()).collect();
    assert!(held.iter().any(|v| v.abs() > 1.0), "{held:?}");
    let x = map.decode("x", &regs[0..2]).unwrap();
    assert!((x - wants[0].1).abs() <= 0.5 + 0.1, "{x} vs {wants:?}");
    assert_eq!(regs[10], 1200, "one heartbeat per period");
    assert_eq!(n, 0, "{n} heap allocations in 1000 write periods");
}

/// The origin-shift *server*: an update (clamp and cap against the exposed value and what the
/// controller reports holding, encode, heartbeat) reuses one `Update`, and a controller write
/// (held values and an axis position decoded from the image) reuses one positions buffer: nothing
/// per update or per write once the first of each has sized them. The controller writes back
/// what it holds, and its X position, every 10th update.
#[test]
fn an_origin_shift_server_update_allocates_nothing() {
    use retrocomp_bus::{ChannelId, ChannelTable};
    use retrocomp_gateway::sinks::guard::AxisLimits;
    use retrocomp_gateway::sinks::origin_shift::Words;
    use retrocomp_gateway::sinks::origin_shift::{ServerCore, ServerMap, Update};

    let map: ServerMap = toml::from_str(&format!(
        "heartbeat_address = 10\n{AXES_MAP}\
         [[held]]\naxis = \"x\"\naddress = 20\n[[held]]\naxis = \"y\"\naddress = 22\n\
         [[held]]\naxis = \"z\"\naddress = 24\n\
         [[position]]\nchannel = \"x_mm\"\naddress = 28\nkind = \"int32\"\nlsb_um = 1.0\n"
    ))
    .unwrap();
    map.validate(&["x", "y", "z"]).unwrap();
    let guards = ["x", "y", "z"]
        .map(|a| AxisLimits {
            axis: a.to_string(),
            max_correction_um: 30.0,
            max_change_um_per_write: 0.5,
        })
        .to_vec();
    let mut table = ChannelTable::default();
    let mut core = ServerCore::new(map, &guards, &mut table);
    let x_mm = table.get("x_mm").unwrap();
    let mut image = [0u16; 32];
    let mut update = Update::default();
    let mut positions: Vec<(ChannelId, f64)> = Vec::new();
    let mut wants = [(Axis::X, 0.0), (Axis::Y, 0.0), (Axis::Z, 0.0)];
    let mut step = |core: &mut ServerCore,
                    update: &mut Update,
                    positions: &mut Vec<(ChannelId, f64)>,
                    k: u64|
     -> bool {
        let ts = k as f64 * 0.01;
        wants[0].1 = 40.0 * (ts * 0.5).sin();
        wants[1].1 = -25.0 + 10.0 * (ts * 0.3).cos();
        wants[2].1 = 15.0 * (ts * 0.7).sin();
        if k.is_multiple_of(10) {
            // The controller applies what is served (copies it into its held registers) and
            // writes its X position in µm, high word first (the default word order).
            let (served, held) = image.split_at_mut(20);
            held[..6].copy_from_slice(&served[..6]);
            let x_um = (k as i32) * 7;
            held[8] = (x_um >> 16) as u16;
            held[9] = x_um as u16;
            let read = |a: u16, n: u16| {
                let a = usize::from(a);
                image.get(a..a + usize::from(n)).map(Words::from_slice)
            };
            core.handle_controller_write_into(read, positions);
            assert_eq!(positions.len(), 1, "{positions:?}");
            assert_eq!(positions[0].0, x_mm);
        }
        let ok = core.poll_update_into(&wants, update);
        for b in &update.blocks {
            let a = b.address as usize;
            image[a..a + b.words.len()].copy_from_slice(&b.words);
        }
        ok
    };
    assert!(
        !step(&mut core, &mut update, &mut positions, 1),
        "served before the controller reported"
    );
    for k in 0..200 {
        assert!(step(&mut core, &mut update, &mut positions, k));
    }
    let before = allocs();
    let mut n_ok = 0;
    for k in 200..1200 {
        n_ok += u64::from(step(&mut core, &mut update, &mut positions, k));
    }
    let n = allocs() - before;
    assert_eq!(n_ok, 1000);
    assert_eq!(image[10], 1200, "one heartbeat per update");
    assert!(
        (positions[0].1 - 1190.0 * 7.0 / 1000.0).abs() < 1e-9,
        "the last position written, mm: {positions:?}"
    );
    for (axis, v) in &update.exposed_um {
        assert!(v.abs() <= 30.0 + 1e-9, "{axis:?} beyond the clamp: {v}");
    }
    assert!(
        update.exposed_um.iter().any(|(_, v)| v.abs() > 10.0),
        "{update:?}"
    );
    assert_eq!(
        n, 0,
        "{n} heap allocations in 1000 server updates and 100 controller writes"
    );
}
