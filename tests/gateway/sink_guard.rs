//! The origin-shift sink core against a simulated controller with random behaviour: requests refused
//! (Modbus exception), replies lost after the request took effect (disconnect mid-handshake), PLC
//! scans at random moments, power cycles (every register 0), foreign values (also beyond the clamp),
//! strobe/ack states from another writer. Every value the controller APPLIES (each latch) and every
//! value the box WRITES is checked: within the clamp, and within the per-write cap of what the
//! controller applied at that moment. Units: µm.

use proptest::prelude::*;
use retrocomp_gateway::sinks::origin_shift::decode_value;
use retrocomp_gateway::sinks::origin_shift::{Action, RegisterMap, Reply, SinkAxis, SinkCore};
use retrocomp_model::Axis;

const CLAMP_UM: f64 = 60.0;
const CAP_UM: f64 = 0.5;
const LSB_UM: f64 = 0.1;

fn map(handshake: bool) -> RegisterMap {
    // x: int32 ABCD at 0..2; y: int16 with sign −1 at 2; strobe 3, ack 4 (one read covers all).
    let mut s = String::from(
        "verify_readback = true\n\
         [[axis]]\naxis = \"x\"\naddress = 0\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
         [[axis]]\naxis = \"y\"\naddress = 2\nkind = \"int16\"\nlsb_um = 0.1\nsign = -1\n",
    );
    if handshake {
        s.push_str(
            "[handshake]\nstrobe_address = 3\nack_address = 4\ntimeout_ms = 60\npoll_ms = 10\n",
        );
    }
    toml::from_str(&s).unwrap()
}

/// The controller: its registers and what it applies (latched at a scan).
struct Plc {
    map: RegisterMap,
    regs: [u16; 5],
    applied_um: [f64; 2],
    latches: u64,
}

impl Plc {
    fn value(&self, axis: usize) -> f64 {
        let r = &self.map.axes[axis];
        let a = r.address as usize;
        decode_value(r, &self.regs[a..a + r.data_type.words() as usize]).unwrap()
    }

    fn set(&mut self, axis: usize, um: f64) {
        let r = &self.map.axes[axis];
        let w = retrocomp_gateway::sinks::origin_shift::encode_value(r, um).unwrap();
        let a = r.address as usize;
        self.regs[a..a + w.len()].copy_from_slice(&w);
    }

    /// One PLC scan (toggle handshake as in hil-sim's PLC and docs/gateway.md).
    fn scan(&mut self) -> Result<(), TestCaseError> {
        if self.map.handshake.is_some() {
            if self.regs[3] == self.regs[4] {
                return Ok(());
            }
            self.regs[4] = self.regs[3];
        }
        for axis in 0..2 {
            let new = self.value(axis);
            let old = self.applied_um[axis];
            if old.abs() > CLAMP_UM + LSB_UM / 2.0 {
                // Only the controller's own value may be out of range; the box never writes it.
                prop_assert!(
                    (new - old).abs() < 1e-9,
                    "axis {axis} moved from out-of-range {old} to {new}"
                );
            } else {
                prop_assert!(new.abs() <= CLAMP_UM + 1e-9, "axis {axis} applied {new}");
                prop_assert!(
                    (new - old).abs() <= CAP_UM + LSB_UM + 1e-9,
                    "axis {axis} stepped {old} → {new}"
                );
            }
            self.applied_um[axis] = new;
        }
        self.latches += 1;
        Ok(())
    }
}

#[derive(Clone, Copy, Debug)]
enum Event {
    None,
    PowerCycle,
    Foreign {
        axis: usize,
        um: f64,
    },
    /// Strobe and ack both set to `bit` by someone else (no latch pending).
    StrobeState {
        bit: u16,
    },
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Fate {
    Ok,
    /// Refused (Modbus exception): no effect.
    Exception,
    /// Took effect, reply lost (connection dropped after the request).
    LostReply,
    /// Connection dropped before the request: no effect.
    Dropped,
}

#[derive(Clone, Debug)]
struct Period {
    event: Event,
    want_um: [f64; 2],
    fates: Vec<Fate>,
    scans: Vec<bool>,
}

fn period() -> impl Strategy<Value = Period> {
    let event = prop_oneof![
        12 => Just(Event::None),
        1 => Just(Event::PowerCycle),
        2 => (0usize..2, prop_oneof![-70.0f64..70.0, -120.0f64..120.0])
            .prop_map(|(axis, um)| Event::Foreign { axis, um: (um * 10.0).round() / 10.0 }),
        1 => (0u16..2).prop_map(|bit| Event::StrobeState { bit }),
    ];
    let want = prop_oneof![
        6 => -80.0f64..80.0,
        1 => Just(f64::NAN),
        1 => Just(1e9),
    ];
    let fate = prop_oneof![
        20 => Just(Fate::Ok),
        1 => Just(Fate::Exception),
        1 => Just(Fate::LostReply),
        1 => Just(Fate::Dropped),
    ];
    (
        event,
        [want.clone(), want],
        prop::collection::vec(fate, 1..12),
        prop::collection::vec(any::<bool>(), 1..7),
    )
        .prop_map(|(event, want_um, fates, scans)| Period {
            event,
            want_um,
            fates,
            scans,
        })
}

fn axes() -> Vec<SinkAxis> {
    ["x", "y"]
        .into_iter()
        .map(|a| SinkAxis {
            axis: a.into(),
            max_correction_um: CLAMP_UM,
            max_change_um_per_write: CAP_UM,
        })
        .collect()
}

fn run(
    handshake: bool,
    start_um: [f64; 2],
    periods: &[Period],
) -> Result<(u64, u64), TestCaseError> {
    let map = map(handshake);
    let mut plc = Plc {
        map: map.clone(),
        regs: [0; 5],
        applied_um: start_um,
        latches: 0,
    };
    for (axis, um) in start_um.into_iter().enumerate() {
        plc.set(axis, um);
        plc.applied_um[axis] = plc.value(axis);
    }
    let mut core = SinkCore::new(map, axes());
    let mut t_s = 0.0;
    let mut k = 0usize;
    for p in periods {
        match p.event {
            Event::None => {}
            Event::PowerCycle => {
                plc.regs = [0; 5];
                plc.applied_um = [0.0; 2];
            }
            Event::Foreign { axis, um } => {
                plc.set(axis, um);
                plc.applied_um[axis] = plc.value(axis);
            }
            Event::StrobeState { bit } => {
                plc.regs[3] = bit;
                plc.regs[4] = bit;
            }
        }
        if !handshake {
            // Without a handshake the controller applies its registers every scan, and scans at
            // least once per write period (the documented assumption).
            plc.scan()?;
        }
        let wants = vec![(Axis::X, p.want_um[0]), (Axis::Y, p.want_um[1])];
        let mut action = core.begin(&wants);
        while !matches!(action, Action::Done(_)) {
            let fate = p.fates[k % p.fates.len()];
            let scan_after = p.scans[k % p.scans.len()];
            k += 1;
            t_s += 0.01;
            let effect = matches!(fate, Fate::Ok | Fate::LostReply);
            let reply = match &action {
                Action::Write(b) => {
                    core.map()
                        .check_write(b.address, b.words.len())
                        .map_err(|e| {
                            TestCaseError::fail(format!("write outside the allow-list: {e}"))
                        })?;
                    // Every value written is within the clamp and the cap of what is applied.
                    for (axis, r) in core.map().axes.iter().enumerate() {
                        let (a, n) = (r.address as usize, r.data_type.words() as usize);
                        let b0 = b.address as usize;
                        if a >= b0 && a + n <= b0 + b.words.len() {
                            let v = decode_value(r, &b.words[a - b0..a - b0 + n]).unwrap();
                            prop_assert!(v.abs() <= CLAMP_UM + 1e-9, "wrote {v} on axis {axis}");
                            let held = plc.applied_um[axis];
                            prop_assert!(
                                (v - held).abs() <= CAP_UM + LSB_UM + 1e-9,
                                "wrote {v} on axis {axis} while the controller applies {held}"
                            );
                        }
                    }
                    if effect {
                        let a = b.address as usize;
                        plc.regs[a..a + b.words.len()].copy_from_slice(&b.words);
                    }
                    Reply::Written
                }
                Action::Read { address, count, .. } => {
                    let a = *address as usize;
                    Reply::Read(plc.regs[a..a + *count as usize].to_vec().into())
                }
                Action::Done(_) => unreachable!(),
            };
            if scan_after {
                plc.scan()?;
            }
            let reply = match fate {
                Fate::Ok => reply,
                Fate::Exception => Reply::Failed("Modbus exception IllegalDataValue".into()),
                Fate::LostReply | Fate::Dropped => Reply::Failed("transport: broken pipe".into()),
            };
            action = core.handle_reply(reply, t_s);
        }
        for (axis, held) in core.take_reseeds() {
            prop_assert!(held.abs() <= CLAMP_UM, "reseed {axis} from {held}");
        }
        // Beyond-clamp faults are raised exactly when the controller held such a value at the last
        // read that got through.
        let held: Vec<Option<f64>> = core.held_um().map(|(_, v)| v).collect();
        for (i, beyond) in core.faults().beyond_clamp.iter().enumerate() {
            let out = held[i].is_some_and(|v| v.abs() > CLAMP_UM + LSB_UM / 2.0);
            prop_assert_eq!(*beyond, out, "axis {} held {:?}", i, held[i]);
        }
        plc.scan()?;
    }
    Ok((core.writes_ok, plc.latches))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]
    #[test]
    fn every_write_and_every_latch_is_within_clamp_and_cap(
        handshake in any::<bool>(),
        start in (prop_oneof![3 => -60.0f64..60.0, 1 => -100.0f64..100.0], -60.0f64..60.0),
        periods in prop::collection::vec(period(), 1..60),
    ) {
        let start = [start.0, start.1].map(|v| (v * 10.0).round() / 10.0);
        run(handshake, start, &periods)?;
    }
}

/// The case: after a reconnect the controller holds 100 µm, beyond the 60 µm clamp. The box
/// must not write x at all (it used to write 99.5, 99.0, … capped from there), raises the fault, and
/// resumes (from the controller's value) once the controller is back in range.
#[test]
fn controller_beyond_the_clamp_after_reconnect_is_never_written_from() {
    let mut core = SinkCore::new(map(false), axes());
    let wants = vec![(Axis::X, 0.0), (Axis::Y, 0.0)];
    let period = |core: &mut SinkCore, regs: &mut [u16; 5]| {
        let mut written = Vec::new();
        let mut a = core.begin(&wants);
        loop {
            let reply = match &a {
                Action::Read { address, count, .. } => {
                    let s = *address as usize;
                    Reply::Read(regs[s..s + *count as usize].to_vec().into())
                }
                Action::Write(b) => {
                    let s = b.address as usize;
                    regs[s..s + b.words.len()].copy_from_slice(&b.words);
                    written.push(b.clone());
                    Reply::Written
                }
                Action::Done(_) => return written,
            };
            a = core.handle_reply(reply, 0.0);
        }
    };
    let mut regs = [0u16; 5];
    regs[1] = 200; // x = 20 µm
    assert_eq!(period(&mut core, &mut regs).len(), 1);
    // "Reconnect": the controller now holds 100 µm (1000 counts).
    regs[1] = 1000;
    for _ in 0..79 {
        let w = period(&mut core, &mut regs);
        assert!(w.iter().all(|b| b.address != 0), "x written: {w:?}");
        assert_eq!(core.faults().beyond_clamp, vec![true, false]);
        assert_eq!(core.held_um().next(), Some(("x", Some(100.0))));
    }
    // Brought back in range (59 µm) by the operator: the engine is told to continue from it, and the
    // next write is within the cap of it.
    regs[1] = 590;
    let w = period(&mut core, &mut regs);
    assert_eq!(core.faults().beyond_clamp, vec![false, false]);
    assert_eq!(core.take_reseeds(), vec![(Axis::X, 59.0)]);
    let x = w.iter().find(|b| b.address == 0).expect("x written again");
    assert_eq!(
        x.words[..2],
        [0, 585],
        "58.5 µm: 0.5 µm from 59 towards the engine's 0"
    );
}
