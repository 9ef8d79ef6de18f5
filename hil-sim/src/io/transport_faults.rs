//! Transport faults on demand, scripted from `[[io.faults]]` in the sim config so a test can play a
//! run: `modbus_down` (the Modbus TCP listener closes and drops every live connection, then listens
//! again on the same port; the PLC keeps its registers, as a real controller keeps its origin shift
//! across a comms loss), `modbus_rtu_down` (the RTU slave on the pty goes mute: it still reads every
//! request off the line but answers none and applies no write, as a powered-off or unplugged slave
//! looks to the master; then it answers again with current values), `can_node_silent` (one CANopen
//! node sends nothing: PDOs, heartbeat) and `serial_garbage` (random bytes, broken lines and absurd
//! readings on the weighing-line pty).
//!
//! Sans-IO: [`Schedule`] maps simulated time (s) to the active faults and reports each start and
//! clear once; [`Garbage`] decides the bytes (seeded); [`silenced`] decides which CAN frames are
//! dropped; [`Active::rtu_answers`] decides whether the RTU slave answers. The shell (`serve.rs`,
//! `rtu_slave.rs`) only closes sockets, flips a switch and writes bytes. Sensor faults (stuck, NaN,
//! dropout, spike) are `[[faults]]` on a channel (`physics::faults`), not here.
//!
//! A window is `from_s ≤ t < to_s` (simulated seconds).

use crate::rng::Noise;
use retrocomp_bus::can::Frame;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum TransportFaultKind {
    ModbusDown,
    ModbusRtuDown,
    CanNodeSilent,
    SerialGarbage,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TransportFaultConfig {
    pub kind: TransportFaultKind,
    pub from_s: f64,
    #[serde(default = "d_inf")]
    pub to_s: f64,
    /// `can_node_silent`: the CANopen node id (1..=127) that goes silent.
    #[serde(default)]
    pub node: Option<u8>,
}
fn d_inf() -> f64 {
    f64::INFINITY
}

/// Check `[[io.faults]]`; messages name the entry and the key.
pub(crate) fn validate(faults: &[TransportFaultConfig]) -> anyhow::Result<()> {
    for (i, f) in faults.iter().enumerate() {
        anyhow::ensure!(
            f.from_s.is_finite() && f.from_s >= 0.0,
            "io.faults[{i}].from_s must be finite and >= 0, got {}",
            f.from_s
        );
        anyhow::ensure!(
            f.to_s > f.from_s,
            "io.faults[{i}].to_s must be > from_s ({} <= {})",
            f.to_s,
            f.from_s
        );
        match (f.kind, f.node) {
            (TransportFaultKind::CanNodeSilent, Some(n)) => anyhow::ensure!(
                (1..=127).contains(&n),
                "io.faults[{i}].node must be a CANopen node id 1..=127, got {n}"
            ),
            (TransportFaultKind::CanNodeSilent, None) => {
                anyhow::bail!("io.faults[{i}]: can_node_silent needs `node`")
            }
            (k, Some(_)) => {
                anyhow::bail!("io.faults[{i}]: `node` is only for can_node_silent, not {k:?}")
            }
            _ => {}
        }
    }
    Ok(())
}

/// The transport faults active at one instant.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct Active {
    pub modbus_down: bool,
    pub modbus_rtu_down: bool,
    pub silent_nodes: Vec<u8>,
    pub serial_garbage: bool,
}

impl Active {
    /// Whether the RTU slave answers requests now (it is mute while `modbus_rtu_down` is active).
    pub(crate) fn rtu_answers(&self) -> bool {
        !self.modbus_rtu_down
    }
}

/// One fault starting or clearing (logged once each by the shell).
#[derive(Clone, Debug, PartialEq)]
pub struct Transition {
    pub kind: TransportFaultKind,
    pub node: Option<u8>,
    pub started: bool,
    /// Simulated time of the step that saw the change, s.
    pub t_s: f64,
}

#[derive(Clone, Debug, Default)]
pub(crate) struct Schedule {
    faults: Vec<TransportFaultConfig>,
    was_active: Vec<bool>,
}

impl Schedule {
    pub(crate) fn new(faults: Vec<TransportFaultConfig>) -> Self {
        let was_active = vec![false; faults.len()];
        Self { faults, was_active }
    }

    /// The faults active at `t_s` (pure: no state).
    pub(crate) fn at(&self, t_s: f64) -> Active {
        let mut a = Active::default();
        for f in self
            .faults
            .iter()
            .filter(|f| t_s >= f.from_s && t_s < f.to_s)
        {
            match f.kind {
                TransportFaultKind::ModbusDown => a.modbus_down = true,
                TransportFaultKind::ModbusRtuDown => a.modbus_rtu_down = true,
                TransportFaultKind::SerialGarbage => a.serial_garbage = true,
                TransportFaultKind::CanNodeSilent => {
                    if let Some(n) = f.node
                        && !a.silent_nodes.contains(&n)
                    {
                        a.silent_nodes.push(n);
                    }
                }
            }
        }
        a
    }

    /// Move to `t_s`: the faults active now and the starts/clears since the previous call.
    pub(crate) fn advance(&mut self, t_s: f64) -> (Active, Vec<Transition>) {
        let mut changes = Vec::new();
        for (f, was) in self.faults.iter().zip(&mut self.was_active) {
            let now = t_s >= f.from_s && t_s < f.to_s;
            if now != *was {
                *was = now;
                changes.push(Transition {
                    kind: f.kind,
                    node: f.node,
                    started: now,
                    t_s,
                });
            }
        }
        (self.at(t_s), changes)
    }
}

/// CANopen node id of a frame: the low 7 bits of an 11-bit COB-ID whose function code carries one
/// (EMCY, PDOs, SDOs, heartbeat: 0x081..=0x7FF); `None` for NMT (0x000), SYNC (0x080), TIME (0x100)
/// and extended frames.
pub(crate) fn canopen_node(frame: &Frame) -> Option<u8> {
    let id = frame.raw_id();
    if id > 0x7FF || id == 0x100 {
        return None;
    }
    let node = (id & 0x7F) as u8;
    (id >= 0x080 && node != 0).then_some(node)
}

/// True when `frame` comes from a node that is silent now.
pub(crate) fn silenced(frame: &Frame, active: &Active) -> bool {
    canopen_node(frame).is_some_and(|n| active.silent_nodes.contains(&n))
}

/// Line noise for the weighing pty (seeded): bursts at Poisson times, between and into the regular
/// lines (an unterminated burst glues onto the next line and breaks it).
#[derive(Clone, Debug)]
pub(crate) struct Garbage {
    noise: Noise,
    mean_interval_s: f64,
    next_s: Option<f64>,
}

/// What a garbage burst is (for tests and docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BurstKind {
    /// Random bytes with no line end: they glue onto the next line and break it.
    Unterminated,
    /// Random bytes ending in CR LF: a line that parses as nothing.
    JunkLine,
    /// A line cut short (`ST,GS,+00`).
    Truncated,
    /// A well-formed line with an absurd reading (a flipped digit: 90 kN).
    Absurd,
}

/// The absurd reading of [`BurstKind::Absurd`], N.
pub(crate) const ABSURD_FORCE_N: f64 = 90_000.0;

impl Garbage {
    /// Bursts every `mean_interval_s` on average while the fault is active.
    pub(crate) fn new(seed: u64, mean_interval_s: f64) -> Self {
        Self {
            noise: Noise::new(seed, "io/serial_garbage"),
            mean_interval_s,
            next_s: None,
        }
    }

    /// The bursts due at `t_s` while the fault is active (call every step; `active = false` resets
    /// the schedule so the next window starts afresh).
    pub(crate) fn poll(&mut self, t_s: f64, active: bool) -> Vec<u8> {
        let mut out = Vec::new();
        if !active {
            self.next_s = None;
            return out;
        }
        let mut next = match self.next_s {
            Some(n) => n,
            None => t_s + self.noise.exp_wait(self.mean_interval_s),
        };
        while next <= t_s {
            out.extend(self.burst().1);
            next += self.noise.exp_wait(self.mean_interval_s);
        }
        self.next_s = Some(next);
        out
    }

    fn below(&mut self, n: usize) -> usize {
        retrocomp_analysis::numeric::trunc_usize(self.noise.uniform() * n as f64).min(n - 1)
    }

    /// The next burst and its kind.
    pub(crate) fn burst(&mut self) -> (BurstKind, Vec<u8>) {
        let u = self.noise.uniform();
        let kind = match u {
            u if u < 0.35 => BurstKind::Unterminated,
            u if u < 0.6 => BurstKind::JunkLine,
            u if u < 0.8 => BurstKind::Truncated,
            _ => BurstKind::Absurd,
        };
        let bytes = match kind {
            BurstKind::Unterminated | BurstKind::JunkLine => {
                let len = 1 + self.below(48);
                let mut b: Vec<u8> = (0..len)
                    .map(|_| u8::try_from(self.below(256)).expect("below 256"))
                    // A stray CR/LF would end the burst early: keep the kind what it says.
                    .map(|c| if c == b'\r' || c == b'\n' { b'~' } else { c })
                    .collect();
                if kind == BurstKind::JunkLine {
                    b.extend_from_slice(b"\r\n");
                }
                b
            }
            BurstKind::Truncated => b"ST,GS,+00\r\n".to_vec(),
            BurstKind::Absurd => format!("ST,GS,{ABSURD_FORCE_N:+08.1}N\r\n").into_bytes(),
        };
        (kind, bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(
        kind: TransportFaultKind,
        from_s: f64,
        to_s: f64,
        node: Option<u8>,
    ) -> TransportFaultConfig {
        TransportFaultConfig {
            kind,
            from_s,
            to_s,
            node,
        }
    }

    #[test]
    fn schedule_maps_time_to_active_faults_and_reports_each_edge_once() {
        use TransportFaultKind::*;
        let mut s = Schedule::new(vec![
            f(ModbusDown, 1.0, 2.0, None),
            f(CanNodeSilent, 1.5, 3.0, Some(2)),
            f(SerialGarbage, 4.0, f64::INFINITY, None),
        ]);
        assert_eq!(s.at(0.5), Active::default());
        assert!(s.at(1.0).modbus_down, "from_s is inside the window");
        assert!(!s.at(2.0).modbus_down, "to_s is outside");
        assert_eq!(s.at(1.7).silent_nodes, vec![2]);
        assert!(s.at(1e6).serial_garbage);
        let mut starts = 0;
        let mut clears = 0;
        let mut seen = Vec::new();
        for k in 0..5000 {
            let (_, ch) = s.advance(f64::from(k) * 0.001);
            for c in ch {
                if c.started {
                    starts += 1;
                } else {
                    clears += 1;
                }
                seen.push((
                    c.kind,
                    c.started,
                    retrocomp_analysis::numeric::round_i64(c.t_s * 1000.0),
                ));
            }
        }
        assert_eq!((starts, clears), (3, 2));
        assert_eq!(
            seen,
            vec![
                (ModbusDown, true, 1000),
                (CanNodeSilent, true, 1500),
                (ModbusDown, false, 2000),
                (CanNodeSilent, false, 3000),
                (SerialGarbage, true, 4000),
            ]
        );
    }

    #[test]
    fn modbus_rtu_down_mutes_only_the_rtu_slave_inside_its_window_and_edges_once() {
        use TransportFaultKind::*;
        // Two overlapping RTU windows are one outage on the line, but each logs its own edges.
        let mut s = Schedule::new(vec![
            f(ModbusRtuDown, 2.0, 4.0, None),
            f(ModbusRtuDown, 3.5, 5.0, None),
            f(ModbusDown, 6.0, 7.0, None),
        ]);
        assert!(s.at(1.999).rtu_answers());
        assert!(!s.at(2.0).rtu_answers(), "from_s is inside the window");
        assert!(!s.at(4.2).rtu_answers(), "the second window holds it down");
        assert!(s.at(5.0).rtu_answers(), "to_s is outside: answering again");
        let tcp_only = s.at(6.5);
        assert!(
            tcp_only.modbus_down && tcp_only.rtu_answers(),
            "TCP down is not RTU down"
        );
        assert!(!s.at(3.0).modbus_down, "RTU down is not TCP down");
        let mut answering = Vec::new();
        let mut edges = Vec::new();
        for k in 0..8000 {
            let t = f64::from(k) * 0.001;
            let (active, ch) = s.advance(t);
            if answering.last().map(|(_, a)| *a) != Some(active.rtu_answers()) {
                answering.push((k, active.rtu_answers()));
            }
            edges.extend(ch.iter().map(|c| {
                (
                    c.kind,
                    c.started,
                    retrocomp_analysis::numeric::round_i64(c.t_s * 1000.0),
                )
            }));
        }
        assert_eq!(answering, vec![(0, true), (2000, false), (5000, true)]);
        assert_eq!(
            edges,
            vec![
                (ModbusRtuDown, true, 2000),
                (ModbusRtuDown, true, 3500),
                (ModbusRtuDown, false, 4000),
                (ModbusRtuDown, false, 5000),
                (ModbusDown, true, 6000),
                (ModbusDown, false, 7000),
            ]
        );
        let e = validate(&[f(ModbusRtuDown, 1.0, 2.0, Some(1))])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("io.faults[0]") && e.contains("only for can_node_silent"),
            "{e}"
        );
        let e = validate(&[f(ModbusRtuDown, 3.0, 3.0, None)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("io.faults[0].to_s"), "{e}");
    }

    #[test]
    fn validation_names_the_entry_and_key() {
        use TransportFaultKind::*;
        let e = validate(&[
            f(ModbusDown, 1.0, 2.0, None),
            f(CanNodeSilent, 1.0, 2.0, None),
        ])
        .unwrap_err()
        .to_string();
        assert!(e.contains("io.faults[1]") && e.contains("node"), "{e}");
        let e = validate(&[f(ModbusDown, 2.0, 1.0, None)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("io.faults[0].to_s"), "{e}");
        let e = validate(&[f(SerialGarbage, 0.0, 1.0, Some(3))])
            .unwrap_err()
            .to_string();
        assert!(e.contains("only for can_node_silent"), "{e}");
        assert!(validate(&[f(CanNodeSilent, 0.0, 1.0, Some(128))]).is_err());
        assert!(validate(&[f(CanNodeSilent, 0.0, 1.0, Some(5))]).is_ok());
    }

    #[test]
    fn parses_from_toml() {
        #[derive(Deserialize)]
        struct W {
            faults: Vec<TransportFaultConfig>,
        }
        let w: W = toml::from_str(
            "[[faults]]\nkind = \"can_node_silent\"\nnode = 1\nfrom_s = 2.0\nto_s = 3.5\n\
             [[faults]]\nkind = \"modbus_down\"\nfrom_s = 1.0\n\
             [[faults]]\nkind = \"modbus_rtu_down\"\nfrom_s = 4.0\nto_s = 7.0\n",
        )
        .unwrap();
        assert_eq!(w.faults[0].node, Some(1));
        assert_eq!(w.faults[1].to_s, f64::INFINITY);
        assert_eq!(
            w.faults[2],
            f(TransportFaultKind::ModbusRtuDown, 4.0, 7.0, None)
        );
        assert!(toml::from_str::<W>("[[faults]]\nkind = \"modbus_up\"\nfrom_s = 1.0\n").is_err());
    }

    #[test]
    fn only_frames_of_silent_nodes_are_dropped() {
        let active = Active {
            silent_nodes: vec![1],
            ..Default::default()
        };
        let tpdo1_node1 = Frame::standard(0x181, &[0; 4]).unwrap();
        let tpdo1_node2 = Frame::standard(0x182, &[0; 4]).unwrap();
        let heartbeat_node1 = Frame::standard(0x701, &[5]).unwrap();
        let nmt = Frame::standard(0x000, &[1, 1]).unwrap();
        let sync = Frame::standard(0x080, &[]).unwrap();
        assert!(silenced(&tpdo1_node1, &active));
        assert!(silenced(&heartbeat_node1, &active));
        assert!(!silenced(&tpdo1_node2, &active));
        assert!(!silenced(&nmt, &active) && !silenced(&sync, &active));
        assert!(!silenced(&tpdo1_node1, &Active::default()));
        assert_eq!(
            canopen_node(&Frame::standard(0x100, &[0; 6]).unwrap()),
            None
        );
    }

    #[test]
    fn garbage_is_seeded_and_never_a_valid_plausible_reading() {
        use retrocomp_bus::serial::LineFramer;
        let (mut a, mut b) = (Garbage::new(7, 0.03), Garbage::new(7, 0.03));
        let mut kinds = std::collections::BTreeMap::new();
        for _ in 0..2000 {
            let (ka, ba) = a.burst();
            assert_eq!((ka, ba.clone()), b.burst(), "same seed, same bytes");
            *kinds.entry(format!("{ka:?}")).or_insert(0) += 1;
            let ends = ba.ends_with(b"\r\n");
            assert_eq!(ends, ka != BurstKind::Unterminated, "{ka:?}");
            let body = &ba[..ba.len() - if ends { 2 } else { 0 }];
            assert!(
                !body.contains(&b'\n') && !body.contains(&b'\r'),
                "one line at most"
            );
            // Whatever parses as a weighing reading is the absurd one (a range check catches it).
            let mut parsed = Vec::new();
            LineFramer::new(256).push(&ba, |line| {
                if let Ok(r) = retrocomp_bus::serial::parse_weighing(line, Some("N")) {
                    parsed.push(r.value);
                }
            });
            if ka == BurstKind::Absurd {
                assert_eq!(parsed, vec![ABSURD_FORCE_N]);
            } else {
                assert!(parsed.is_empty(), "{ka:?} parsed as {parsed:?}");
            }
        }
        assert_eq!(kinds.len(), 4, "every kind occurs: {kinds:?}");
        // Poisson bursts only inside the window: ≈ 1 s / 30 ms = 33 in one second.
        let mut g = Garbage::new(7, 0.03);
        let mut bursts = 0;
        for k in 0..3000 {
            let t = f64::from(k) * 0.001;
            let b = g.poll(t, (1.0..2.0).contains(&t));
            if !(1.0..2.0).contains(&t) {
                assert!(b.is_empty());
            } else if !b.is_empty() {
                bursts += 1;
            }
        }
        assert!((15..60).contains(&bursts), "{bursts} bursts");
    }
}
