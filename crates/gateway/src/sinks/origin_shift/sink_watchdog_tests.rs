//! The sink core's heartbeat, late-write refusal and stop ramp-out, in virtual time against a
//! register-level fake controller that latches on each strobe flip (the PLC of hil-sim, minus I/O).

use super::*;

/// x and y int32 at 0..4, strobe 4, ack 5, heartbeat 6; the controller's timeout 400 ms.
fn map() -> RegisterMap {
    toml::from_str(
        "heartbeat_address = 6\nheartbeat_timeout_ms = 400\n\
         [[axis]]\naxis = \"x\"\naddress = 0\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
         [[axis]]\naxis = \"y\"\naddress = 2\nkind = \"int32\"\nlsb_um = 0.1\nsign = 1\n\
         [handshake]\nstrobe_address = 4\nack_address = 5\ntimeout_ms = 100\npoll_ms = 10\n",
    )
    .unwrap()
}

fn core() -> SinkCore {
    let ax = |a: &str| SinkAxis {
        axis: a.into(),
        max_correction_um: 60.0,
        max_change_um_per_write: 0.5,
    };
    SinkCore::new(map(), vec![ax("x"), ax("y")])
}

/// Registers 0..7; a strobe write is latched and acknowledged at once.
struct Controller {
    regs: [u16; 7],
    /// Every request in order: (address, words) for writes.
    writes: Vec<(u16, Vec<u16>)>,
}

impl Controller {
    fn holding(x_um: f64, y_um: f64) -> Self {
        let mut regs = [0u16; 7];
        let m = map();
        for (k, v) in [x_um, y_um].into_iter().enumerate() {
            let w = super::super::map::encode_value(&m.axes[k], v).unwrap();
            regs[2 * k..2 * k + 2].copy_from_slice(&w);
        }
        Self {
            regs,
            writes: Vec::new(),
        }
    }

    fn um(&self, axis: usize) -> f64 {
        decode_value(&map().axes[axis], &self.regs[2 * axis..2 * axis + 2]).unwrap()
    }

    fn reply(&mut self, a: &Action) -> Reply {
        match a {
            Action::Write(b) => {
                let at = b.address as usize;
                self.regs[at..at + b.words.len()].copy_from_slice(&b.words);
                if b.address == 4 {
                    self.regs[5] = self.regs[4];
                }
                self.writes.push((b.address, b.words.to_vec()));
                Reply::Written
            }
            Action::Read { address, count, .. } => {
                let at = *address as usize;
                Reply::Read(self.regs[at..at + *count as usize].to_vec().into())
            }
            Action::Done(_) => unreachable!(),
        }
    }

    /// One period at `now_s` (every reply at the same instant): the outcome.
    fn period(&mut self, c: &mut SinkCore, wants: &[(Axis, f64)], now_s: f64) -> Outcome {
        let mut a = c.begin_at(wants, now_s);
        loop {
            if let Action::Done(o) = a {
                return o;
            }
            let r = self.reply(&a);
            a = c.handle_reply(r, now_s);
        }
    }
}

fn wants(x: f64, y: f64) -> Vec<(Axis, f64)> {
    vec![(Axis::X, x), (Axis::Y, y)]
}

#[test]
fn the_heartbeat_goes_out_first_every_period_and_counts_up() {
    let mut c = core();
    let mut plc = Controller::holding(0.0, 0.0);
    for k in 1..=3u16 {
        let before = plc.writes.len();
        assert_eq!(
            plc.period(&mut c, &wants(1.0, 1.0), f64::from(k) * 0.05),
            Outcome::Ok
        );
        assert_eq!(
            plc.writes[before],
            (6, vec![k]),
            "period {k} starts with the heartbeat"
        );
        assert_eq!(plc.regs[6], k);
    }
    assert_eq!(c.heartbeat(), 3);
    // A period without a connection writes no heartbeat, so the controller's rule sees it stop.
    c.not_connected("refused");
    assert_eq!(plc.regs[6], 3);
}

#[test]
fn the_heartbeat_wraps() {
    // Without the handshake a period is heartbeat, read, values, read-back.
    let mut m = map();
    m.handshake = None;
    let ax = |a: &str| SinkAxis {
        axis: a.into(),
        max_correction_um: 60.0,
        max_change_um_per_write: 0.5,
    };
    let mut c = SinkCore::new(m, vec![ax("x"), ax("y")]);
    let mut plc = Controller::holding(0.0, 0.0);
    for _ in 0..=u32::from(u16::MAX) {
        plc.period(&mut c, &wants(0.0, 0.0), 0.0);
    }
    assert_eq!(plc.regs[6], 0, "65 536 periods: back to 0");
    plc.period(&mut c, &wants(0.0, 0.0), 0.0);
    assert_eq!(plc.regs[6], 1);
}

#[test]
fn a_period_older_than_half_the_controllers_timeout_writes_no_value() {
    let mut c = core();
    let mut plc = Controller::holding(5.0, 0.0);
    let a = c.begin_at(&wants(6.0, 0.0), 10.0);
    let r = plc.reply(&a); // the heartbeat
    let read = c.handle_reply(r, 10.0);
    let r = plc.reply(&read);
    // The box froze after the read for 0.3 s > 0.2 s: the controller may have ramped out since.
    let a = c.handle_reply(r, 10.3);
    assert!(
        matches!(
            &a,
            Action::Done(Outcome::RequestFailed { step: "late", .. })
        ),
        "{a:?}"
    );
    assert_eq!(plc.writes.len(), 1, "only the heartbeat went out");
    assert!(c.faults().write_failed);
    // The next period reads again and writes within the cap of what the controller holds.
    assert_eq!(plc.period(&mut c, &wants(6.0, 0.0), 10.35), Outcome::Ok);
    assert!((plc.um(0) - 5.5).abs() < 1e-9, "{}", plc.um(0));

    // Frozen between the values and the strobe: the strobe is not sent either.
    let a = c.begin_at(&wants(6.0, 0.0), 11.0);
    let mut a = c.handle_reply(plc.reply(&a), 11.0);
    a = c.handle_reply(plc.reply(&a), 11.0); // read → first value write
    assert!(matches!(&a, Action::Write(b) if b.address == 0), "{a:?}");
    let a = c.handle_reply(plc.reply(&a), 11.25);
    assert!(
        matches!(a, Action::Done(Outcome::RequestFailed { step: "late", .. })),
        "{a:?}"
    );
    assert_eq!(plc.regs[4], plc.regs[5], "no strobe flip: nothing latched");
}

#[test]
fn ramp_out_moves_every_axis_to_zero_within_the_cap_then_reports_done() {
    let mut c = core();
    let mut plc = Controller::holding(7.3, -2.0);
    assert_eq!(plc.period(&mut c, &wants(7.3, -2.0), 0.0), Outcome::Ok);
    c.begin_ramp_out();
    let mut periods = 0;
    let mut last = [plc.um(0), plc.um(1)];
    while !c.is_ramped_out() {
        // The engine still asks for a correction: ignored while ramping out.
        assert_eq!(
            plc.period(&mut c, &wants(30.0, 30.0), 0.05 * f64::from(periods)),
            Outcome::Ok
        );
        let now = [plc.um(0), plc.um(1)];
        for k in 0..2 {
            assert!(
                (now[k] - last[k]).abs() <= 0.5 + 1e-9,
                "step {last:?} → {now:?}"
            );
            assert!(
                now[k].abs() <= last[k].abs() + 1e-9,
                "away from 0: {last:?} → {now:?}"
            );
        }
        last = now;
        periods += 1;
        assert!(periods < 100, "never ramped out: {last:?}");
    }
    // 7.3 µm at 0.5 µm per write: 15 writes, and one more period to read 0.
    assert_eq!(periods, 16);
    assert_eq!(last, [0.0, 0.0]);
}
