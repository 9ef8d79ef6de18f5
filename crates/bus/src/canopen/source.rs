//! The CANopen source: turns frames into samples for the configured encoders (CiA 406) and analog
//! channels (CiA 404), watches heartbeats and PDO freshness, and says how to bring the nodes up.
//! Sans-IO ([`CanopenSource`]: `handle_frame(…, now)`, `poll(now)`, `poll_timeout()`) plus a thin
//! async loop over any [`CanBus`] ([`run`]) that sleeps until the source's next deadline.
//!
//! Staleness: a channel is reported [`Health::Stale`] by [`CanopenSource::poll`] when its node's
//! heartbeat is older than `heartbeat_timeout_s` (if heartbeats are monitored), its node is not
//! operational, or its PDO is older than `pdo_timeout_s`; the stale sample carries the last decoded
//! value (NaN if none yet). [`CanopenSource::poll_timeout`] is the moment the next channel turns
//! stale, or, while one is stale, [`STALE_REPEAT_S`] after the last poll. Times are seconds on the
//! caller's clock.

use super::cia404::AnalogChannel;
use super::cia406::{EncoderChannel, PositionDecoder};
use super::nmt::{HeartbeatMonitor, NmtCommand, encode_nmt};
use super::sdo::{CYCLIC_TIMER_6200, SdoRequest, SdoResponse};
use crate::can::{CanBus, CanError, Frame};
use crate::deadline::{sleep_for, stale_report_due_s};
use crate::{ChannelId, ChannelTable, Health, Sample};
use std::collections::{BTreeMap, BTreeSet, HashMap};

fn default_pdo_timeout_s() -> f64 {
    0.1
}

/// While a channel is stale, [`CanopenSource::poll`] reports it again this often, s. The gateway's
/// engine judges staleness on its inputs' clock (the newest sample of any source), which these
/// repeated samples keep moving while every node is silent; a sample that stops the silence is
/// handled when it arrives, not on this period.
pub(crate) const STALE_REPEAT_S: f64 = 0.01;

/// `[canopen]` section of the field TOML.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CanopenConfig {
    #[serde(default)]
    pub encoder: Vec<EncoderChannel>,
    #[serde(default)]
    pub analog: Vec<AnalogChannel>,
    /// Heartbeat consumer time per node; `None` = heartbeats not monitored.
    #[serde(default)]
    pub heartbeat_timeout_s: Option<f64>,
    /// A channel with no PDO for this long is stale.
    #[serde(default = "default_pdo_timeout_s")]
    pub pdo_timeout_s: f64,
}

/// Counters over the source's life.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CanopenCounters {
    pub frames: u64,
    /// Frames that matched no configured PDO, heartbeat or SDO reply.
    pub unmatched: u64,
    pub decode_errors: u64,
    pub out_of_range: u64,
    pub heartbeat_timeouts: u64,
    /// SDO aborts received from our nodes (e.g. the encoder refused the 6200h cyclic timer).
    pub sdo_aborts: u64,
}

#[derive(Debug, Clone, Copy)]
enum Target {
    Encoder(usize),
    Analog(usize),
}

#[derive(Debug, Clone)]
struct Freshness {
    /// The channel's id, resolved at construction.
    channel: ChannelId,
    node: u8,
    last_pdo_s: Option<f64>,
    last_value: f64,
}

#[derive(Debug)]
pub struct CanopenSource {
    cfg: CanopenConfig,
    encoders: Vec<PositionDecoder>,
    by_cob: HashMap<u16, Vec<Target>>,
    monitors: BTreeMap<u8, HeartbeatMonitor>,
    /// Index: encoders first, then analogs.
    fresh: Vec<Freshness>,
    /// When [`CanopenSource::poll`] last ran (None: never).
    last_poll_s: Option<f64>,
    pub counters: CanopenCounters,
}

impl CanopenSource {
    /// The source of `cfg`, its channels resolved in `channels` (the gateway's table).
    pub fn new(cfg: CanopenConfig, channels: &mut ChannelTable) -> Self {
        let mut by_cob: HashMap<u16, Vec<Target>> = HashMap::new();
        let mut fresh = Vec::new();
        for (i, e) in cfg.encoder.iter().enumerate() {
            by_cob
                .entry(e.cob_id())
                .or_default()
                .push(Target::Encoder(i));
            fresh.push(Freshness {
                channel: channels.resolve(&e.channel),
                node: e.node_id,
                last_pdo_s: None,
                last_value: f64::NAN,
            });
        }
        for (i, a) in cfg.analog.iter().enumerate() {
            by_cob
                .entry(a.cob_id())
                .or_default()
                .push(Target::Analog(i));
            fresh.push(Freshness {
                channel: channels.resolve(&a.channel),
                node: a.node_id,
                last_pdo_s: None,
                last_value: f64::NAN,
            });
        }
        let monitors = match cfg.heartbeat_timeout_s {
            Some(t) => fresh
                .iter()
                .map(|f| (f.node, HeartbeatMonitor::new(f.node, t)))
                .collect(),
            None => BTreeMap::new(),
        };
        CanopenSource {
            encoders: cfg
                .encoder
                .iter()
                .cloned()
                .map(|e| PositionDecoder::new(e, channels))
                .collect(),
            cfg,
            by_cob,
            monitors,
            fresh,
            last_poll_s: None,
            counters: CanopenCounters::default(),
        }
    }

    /// Nodes that carry configured channels, ascending.
    pub fn nodes(&self) -> BTreeSet<u8> {
        self.fresh.iter().map(|f| f.node).collect()
    }

    /// Frames to send at start: SDO writes of the cyclic timer (6200h) for encoders that set one, then
    /// NMT start for every node. SDO replies arrive as frames and are counted, not required.
    pub fn bring_up(&self) -> Vec<Frame> {
        let mut out: Vec<Frame> = self
            .cfg
            .encoder
            .iter()
            .filter_map(|e| {
                e.cyclic_ms
                    .map(|ms| SdoRequest::write_u16(CYCLIC_TIMER_6200, 0, ms).encode(e.node_id))
            })
            .collect();
        out.extend(
            self.nodes()
                .into_iter()
                .map(|n| encode_nmt(NmtCommand::Start, n)),
        );
        out
    }

    /// Decode one frame received at `t_s`; samples are appended to `out`.
    pub fn handle_frame(&mut self, f: &Frame, t_s: f64, out: &mut Vec<Sample>) {
        self.counters.frames += 1;
        let mut matched = false;
        for m in self.monitors.values_mut() {
            matched |= m.handle_frame(f, t_s);
        }
        let cob = u16::try_from(f.raw_id()).ok().filter(|id| *id <= 0x7FF);
        if let Some(targets) = cob.and_then(|id| self.by_cob.get(&id)) {
            for t in targets {
                let (slot, s) = match *t {
                    Target::Encoder(i) => (i, self.encoders[i].decode(f, t_s)),
                    Target::Analog(i) => {
                        let slot = self.encoders.len() + i;
                        let id = self.fresh[slot].channel;
                        (slot, self.cfg.analog[i].decode(id, f, t_s))
                    }
                };
                let Some(s) = s else { continue };
                matched = true;
                match s.health {
                    Health::DecodeError => self.counters.decode_errors += 1,
                    Health::OutOfRange => self.counters.out_of_range += 1,
                    _ => {}
                }
                if s.health == Health::Ok {
                    self.fresh[slot].last_value = s.value;
                }
                self.fresh[slot].last_pdo_s = Some(t_s);
                out.push(s);
            }
        }
        // SDO replies from our nodes (0x580 + node) are expected traffic after bring-up.
        if let Some((node, resp)) = SdoResponse::decode(f)
            && self.nodes().contains(&node)
        {
            matched = true;
            if let SdoResponse::Abort { index, sub, code } = resp {
                self.counters.sdo_aborts += 1;
                tracing::warn!(node, "SDO abort {code:#010x} on {index:04X}h:{sub}");
            }
        }
        if !matched {
            self.counters.unmatched += 1;
        }
    }

    /// Staleness check at `t_s`: a `Stale` sample for every channel that timed out.
    pub fn poll(&mut self, t_s: f64, out: &mut Vec<Sample>) {
        self.last_poll_s = Some(self.last_poll_s.map_or(t_s, |p| p.max(t_s)));
        let mut hb_stale = BTreeSet::new();
        for (node, m) in &mut self.monitors {
            let before = m.timeouts;
            if m.poll(t_s) == Health::Stale {
                hb_stale.insert(*node);
            }
            self.counters.heartbeat_timeouts += m.timeouts - before;
        }
        for f in &self.fresh {
            let pdo_old = f
                .last_pdo_s
                .is_none_or(|t| t_s >= t + self.cfg.pdo_timeout_s);
            if pdo_old || hb_stale.contains(&f.node) {
                out.push(Sample {
                    channel: f.channel,
                    t_s,
                    value: f.last_value,
                    health: Health::Stale,
                });
            }
        }
    }

    /// When [`Self::poll`] next has something to report (s, the caller's clock; may be in the
    /// past: poll now): the earliest moment a channel turns stale, or `STALE_REPEAT_S` after the
    /// last poll while one is. `None` with no channels configured.
    pub fn poll_timeout(&self) -> Option<f64> {
        self.fresh
            .iter()
            .map(|f| {
                let pdo = f
                    .last_pdo_s
                    .map_or(f64::NEG_INFINITY, |t| t + self.cfg.pdo_timeout_s);
                let hb = self
                    .monitors
                    .get(&f.node)
                    .map_or(f64::INFINITY, HeartbeatMonitor::stale_from_s);
                stale_report_due_s(pdo.min(hb), self.last_poll_s, STALE_REPEAT_S)
            })
            .min_by(f64::total_cmp)
    }
}

/// Run the source on a bus: send the bring-up frames, then decode until the bus fails or `out` is
/// closed, checking staleness when [`CanopenSource::poll_timeout`] says. `clock_s` gives the
/// receive time in seconds.
pub async fn run<B: CanBus>(
    bus: &mut B,
    src: &mut CanopenSource,
    clock_s: impl Fn() -> f64,
    out: tokio::sync::mpsc::Sender<Vec<Sample>>,
) -> Result<(), CanError> {
    run_observed(bus, src, clock_s, out, |_, _| None).await
}

/// [`run`], calling `observe(bus, frames_received)` after the bring-up, on the first frame, on
/// every error frame, on a frame that changed [`CanBus::bus_errors`] (one that ended a bus-off)
/// and at every deadline, so the caller can report the link (frames flowing, the bus state) while
/// it runs. `frames_received` counts the frames this call received. `observe` returns its own next
/// deadline (s on `clock_s`), if it has one: a fault that clears with time.
pub async fn run_observed<B: CanBus>(
    bus: &mut B,
    src: &mut CanopenSource,
    clock_s: impl Fn() -> f64,
    out: tokio::sync::mpsc::Sender<Vec<Sample>>,
    mut observe: impl FnMut(&B, u64) -> Option<f64>,
) -> Result<(), CanError> {
    for f in src.bring_up() {
        bus.send(&f).await?;
    }
    let mut batch = Vec::new();
    let mut received = 0u64;
    let mut observed = bus.bus_errors();
    let mut observer_due = observe(bus, received);
    loop {
        let due = [src.poll_timeout(), observer_due]
            .into_iter()
            .flatten()
            .min_by(f64::total_cmp);
        let wait = sleep_for(due, clock_s());
        // Frames first: after a host pause the socket holds frames that arrived while this task
        // did not run; judging PDO freshness before reading them would report channels stale
        // whose data is waiting right here. The deadline is taken once the socket is drained.
        tokio::select! {
            biased;
            f = bus.recv_event() => match f {
                Ok(Some(f)) => {
                    received += 1;
                    src.handle_frame(&f, clock_s(), &mut batch);
                    if received == 1 || bus.bus_errors() != observed {
                        observed = bus.bus_errors();
                        observer_due = observe(bus, received);
                    }
                }
                // An error frame: the bus state may have changed.
                Ok(None) => {
                    observed = bus.bus_errors();
                    observer_due = observe(bus, received);
                }
                // Lost frames are not fatal: the positions come again in the next cycle.
                Err(CanError::Overrun(n)) => src.counters.decode_errors += n,
                Err(e) => return Err(e),
            },
            () = tokio::time::sleep(wait) => {
                src.poll(clock_s(), &mut batch);
                observed = bus.bus_errors();
                observer_due = observe(bus, received);
            }
        }
        if !batch.is_empty() && out.send(std::mem::take(&mut batch)).await.is_err() {
            return Ok(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::cia404::AnalogType;
    use super::super::nmt::{NodeState, encode_heartbeat};
    use super::*;

    pub(crate) fn cfg() -> CanopenConfig {
        CanopenConfig {
            encoder: vec![EncoderChannel {
                cyclic_ms: Some(10),
                ..EncoderChannel::new("x_mm", 1, 1000.0)
            }],
            analog: vec![AnalogChannel {
                decimal_digits: 1,
                ..AnalogChannel::new("T_spindle_C", 0x10, AnalogType::Int16)
            }],
            heartbeat_timeout_s: Some(0.3),
            pdo_timeout_s: 0.1,
        }
    }

    #[test]
    fn bring_up_sets_timer_then_starts_nodes() {
        let mut src = CanopenSource::new(cfg(), &mut ChannelTable::default());
        let ids: Vec<u32> = src.bring_up().iter().map(|f| f.raw_id()).collect();
        assert_eq!(ids, vec![0x601, 0x000, 0x000]);
        let mut out = Vec::new();
        let ack = SdoResponse::DownloadAck {
            index: 0x6200,
            sub: 0,
        }
        .encode(1);
        let abort = SdoResponse::Abort {
            index: 0x6200,
            sub: 0,
            code: 0x0609_0030,
        }
        .encode(1);
        src.handle_frame(&ack, 0.0, &mut out);
        src.handle_frame(&abort, 0.0, &mut out);
        assert!(out.is_empty());
        assert_eq!((src.counters.sdo_aborts, src.counters.unmatched), (1, 0));
    }

    #[test]
    fn decodes_counts_and_goes_stale() {
        let c = cfg();
        let mut table = ChannelTable::default();
        let mut src = CanopenSource::new(c.clone(), &mut table);
        let mut out = Vec::new();
        src.handle_frame(&encode_heartbeat(1, NodeState::Operational), 0.0, &mut out);
        src.handle_frame(
            &encode_heartbeat(0x10, NodeState::Operational),
            0.0,
            &mut out,
        );
        src.handle_frame(&c.encoder[0].encode_position(12.5).unwrap(), 0.01, &mut out);
        src.handle_frame(&c.analog[0].encode(21.5).unwrap(), 0.01, &mut out);
        src.handle_frame(&Frame::standard(0x123, &[]).unwrap(), 0.01, &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!((table.name(out[0].channel), out[0].value), ("x_mm", 12.5));
        assert_eq!(
            (table.name(out[1].channel), out[1].value),
            ("T_spindle_C", 21.5)
        );
        assert_eq!(src.counters.unmatched, 1);
        out.clear();
        src.poll(0.05, &mut out);
        assert!(out.is_empty(), "{out:?}");
        // PDOs stop: stale after pdo_timeout, carrying the last value.
        src.poll(0.2, &mut out);
        assert_eq!(out.len(), 2);
        assert!(out.iter().all(|s| s.health == Health::Stale));
        assert_eq!(out[0].value, 12.5);
        out.clear();
        src.handle_frame(&c.encoder[0].encode_position(12.6).unwrap(), 0.4, &mut out);
        out.clear();
        src.poll(0.41, &mut out);
        // x is fresh by PDO, but node 1's heartbeat is 0.41 s old > 0.3 s.
        assert!(out.iter().any(|s| table.name(s.channel) == "x_mm"));
        assert_eq!(src.counters.heartbeat_timeouts, 2);
    }

    /// Driven only at its own deadlines (virtual time), the source reports a channel stale at
    /// the instant its PDO times out, again every [`STALE_REPEAT_S`] while it stays silent, and a
    /// node's "not operational" heartbeat at once.
    #[test]
    fn polled_at_its_deadlines_it_reports_staleness_on_time() {
        let c = cfg();
        let mut table = ChannelTable::default();
        let mut src = CanopenSource::new(c.clone(), &mut table);
        let mut out = Vec::new();
        assert_eq!(
            src.poll_timeout(),
            Some(f64::NEG_INFINITY),
            "nothing heard: poll now"
        );
        src.poll(0.0, &mut out);
        assert_eq!(out.len(), 2, "both channels stale before any PDO");
        assert_eq!(src.poll_timeout(), Some(STALE_REPEAT_S));
        for node in [1, 0x10] {
            src.handle_frame(
                &encode_heartbeat(node, NodeState::Operational),
                0.005,
                &mut out,
            );
        }
        src.handle_frame(&c.encoder[0].encode_position(1.0).unwrap(), 0.005, &mut out);
        src.handle_frame(&c.analog[0].encode(20.0).unwrap(), 0.005, &mut out);
        out.clear();
        // Fresh now: the next deadline is the PDO timeout (0.005 + 0.1), not a tick.
        let due = src.poll_timeout().unwrap();
        assert!((due - 0.105).abs() < 1e-12, "{due}");
        src.poll(due - 1e-6, &mut out);
        assert!(out.is_empty(), "fresh just before the deadline: {out:?}");
        src.poll(due + 1e-9, &mut out);
        assert_eq!(out.len(), 2, "stale just after it");
        out.clear();
        let again = src.poll_timeout().unwrap();
        assert!(
            (again - (due + 1e-9 + STALE_REPEAT_S)).abs() < 1e-12,
            "{again}"
        );
        // One PDO brings x back; its next deadline is its own timeout, the analog's the repeat.
        src.handle_frame(&c.encoder[0].encode_position(1.0).unwrap(), 0.11, &mut out);
        out.clear();
        src.poll(again, &mut out);
        assert_eq!(
            out.iter()
                .map(|s| table.name(s.channel))
                .collect::<Vec<_>>(),
            ["T_spindle_C"]
        );
        // A node that leaves operational is stale from its heartbeat on: due at once.
        src.handle_frame(
            &encode_heartbeat(1, NodeState::PreOperational),
            0.12,
            &mut out,
        );
        assert!(src.poll_timeout().unwrap() <= 0.12);
        out.clear();
        src.poll(0.12, &mut out);
        assert!(
            out.iter()
                .any(|s| table.name(s.channel) == "x_mm" && s.health == Health::Stale)
        );
    }

    /// A bus scripted by the test: data frames and error frames, as a SocketCAN socket gives them.
    struct ScriptBus {
        rx: tokio::sync::mpsc::UnboundedReceiver<Result<Frame, u32>>,
        errors: crate::can::BusErrors,
    }

    impl CanBus for ScriptBus {
        fn bus_errors(&self) -> crate::can::BusErrors {
            self.errors
        }
        async fn send(&mut self, _: &Frame) -> Result<(), CanError> {
            Ok(())
        }
        async fn recv(&mut self) -> Result<Frame, CanError> {
            loop {
                if let Some(f) = self.recv_event().await? {
                    return Ok(f);
                }
            }
        }
        async fn recv_event(&mut self) -> Result<Option<Frame>, CanError> {
            match self.rx.recv().await {
                Some(Ok(f)) => {
                    self.errors.handle_frame();
                    Ok(Some(f))
                }
                Some(Err(class)) => {
                    self.errors
                        .handle_error_frame(&crate::can::ErrorFrame::class_only(class));
                    Ok(None)
                }
                None => Err(CanError::Closed),
            }
        }
    }

    /// With PDOs flowing there is no deadline to wake on, yet the observer sees the bus go
    /// bus-off on the error frame and come back on the next data frame, each when it happens.
    #[tokio::test(start_paused = true)]
    async fn the_observer_follows_the_bus_state_without_a_tick() {
        use crate::can::BusState;
        use crate::can::CAN_ERR_BUSOFF;
        use std::sync::{Arc, Mutex};
        let c = CanopenConfig {
            encoder: cfg().encoder,
            analog: Vec::new(),
            heartbeat_timeout_s: None,
            pdo_timeout_s: 0.1,
        };
        let pdo = c.encoder[0].encode_position(1.0).unwrap();
        let (script, rx) = tokio::sync::mpsc::unbounded_channel();
        let (tx, mut samples) = tokio::sync::mpsc::channel(1024);
        let t0 = tokio::time::Instant::now();
        let clock = move || t0.elapsed().as_secs_f64();
        let seen: Arc<Mutex<Vec<(f64, BusState)>>> = Arc::default();
        let log = seen.clone();
        let task = tokio::spawn(async move {
            let mut bus = ScriptBus {
                rx,
                errors: Default::default(),
            };
            let mut table = ChannelTable::default();
            let mut src = CanopenSource::new(c, &mut table);
            run_observed(&mut bus, &mut src, clock, tx, |b, _| {
                log.lock().unwrap().push((clock(), b.bus_errors().state()));
                None
            })
            .await
        });
        tokio::spawn(async move { while samples.recv().await.is_some() {} });
        let step = std::time::Duration::from_millis(5);
        for i in 0..40 {
            if i == 10 {
                script.send(Err(CAN_ERR_BUSOFF)).unwrap();
                tokio::time::sleep(step).await;
            }
            script.send(Ok(pdo)).unwrap();
            tokio::time::sleep(step).await;
        }
        let seen = seen.lock().unwrap().clone();
        let off = seen
            .iter()
            .position(|(_, s)| *s == BusState::BusOff)
            .expect("bus-off seen");
        let (t_off, _) = seen[off];
        let (t_back, back) = seen[off + 1];
        assert_eq!(back, BusState::Active, "{seen:?}");
        assert!((t_off - 0.050).abs() < 1e-3, "bus-off observed at {t_off}");
        assert!(
            (t_back - 0.055).abs() < 1e-3,
            "back on the bus observed at {t_back}"
        );
        assert_eq!(seen.last().unwrap().1, BusState::Active, "{seen:?}");
        task.abort();
    }

    #[tokio::test]
    async fn runs_on_the_mem_bus() {
        use crate::can::MemBus;
        let c = cfg();
        let bus = MemBus::new(64);
        let mut gw = bus.endpoint();
        let mut sim = bus.endpoint();
        let (tx, mut rx) = tokio::sync::mpsc::channel(16);
        let t0 = std::time::Instant::now();
        let mut table = ChannelTable::default();
        let mut src = CanopenSource::new(c, &mut table);
        let task = tokio::spawn(async move {
            run(&mut gw, &mut src, move || t0.elapsed().as_secs_f64(), tx).await
        });
        // The simulator sees the bring-up, then answers with a position.
        let first = sim.recv().await.unwrap();
        assert_eq!(first.raw_id(), 0x601);
        let enc = cfg().encoder[0].clone();
        sim.send(&enc.encode_position(-3.25).unwrap())
            .await
            .unwrap();
        let got = loop {
            let b = rx.recv().await.unwrap();
            if let Some(s) = b.into_iter().find(|s| s.health == Health::Ok) {
                break s;
            }
        };
        assert_eq!((table.name(got.channel), got.value), ("x_mm", -3.25));
        task.abort();
    }
}
