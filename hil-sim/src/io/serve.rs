//! The async shell of `hil-sim serve`: runs the world on the simulation clock (real time, or as fast
//! as possible) and moves the publisher's bytes onto the configured transports; client writes to the
//! Modbus holding registers reach the PLC window before every step. Transport faults
//! (`[[io.faults]]`, decided by `super::transport_faults`) are acted on here: the Modbus TCP server
//! goes down and comes back, the RTU slave goes mute and answers again (`super::rtu_slave`), a CAN
//! node's frames are dropped, garbage goes on the weighing pty. Each
//! fault's start and clear is printed once on stderr (`hil-sim: fault modbus_down started at t = 4.000 s`).
//!
//! The PLC's scan runs on the register image under its lock ([`RegisterBank::update_holding`]): client
//! words in, step, the PLC's words (ack; the shifts while its watchdog has tripped) out, with no
//! client write in between. Every change of the applied shift and every watchdog edge goes to
//! `plc_latches.csv` (`t_s,event,x_um,y_um,z_um`: latch | ramp | trip | at_zero | rearm, shifts after
//! it in µm); the watchdog's edges are also printed (`hil-sim: plc watchdog trip at t = …`).
//!
//! Pace (issue 18.5): in real time the lag behind the wall clock is measured after every batch
//! ([`LagMeter`]: "behind real time" episodes printed at start and clear) and, with the weighing
//! lines that could not be written, printed once at the end and kept in [`Status`].

use super::dnc_port::{DncPort, DwellLog};
use super::plc_server::{PlcServer, SimClock, WriteEvent};
use super::pty_link::{PtyLink, pty_pair};
use super::publish::Publisher;
use super::rtu_slave::{self, RtuMute};
use super::transport_faults::{Active, Garbage, Schedule, Transition, silenced};
use crate::clock::{LagEdge, LagMeter, RealtimePacer};
use crate::recording::Recorder;
use crate::{SimConfig, World};
use retrocomp_bus::can::{AnyCanBus, CanBus, MemBus, open as open_can};
use retrocomp_bus::modbus::RegisterBank;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use tokio::io::AsyncWriteExt;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio_serial::SerialStream;

/// Live state for observers (tests, the CLI).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Status {
    pub t_s: f64,
    pub shift_counts: [i64; 3],
    pub encoder_counts: [i64; 3],
    /// Nominal (interpolator) position, mm.
    pub setpoint_mm: [f64; 3],
    pub done: bool,
    /// Weighing lines not written because nobody read the pty.
    pub dropped_lines: u64,
    /// Real-time pacing: how far the simulation runs behind the wall clock now and at worst, s
    /// (0 when not paced; see [`LagMeter`]).
    pub lag_s: f64,
    pub max_lag_s: f64,
}

#[derive(Debug)]
pub struct Running {
    pub modbus_tcp: Option<SocketAddr>,
    /// Device path of the RTU pty (open it with any serial client, 8N1; baud is ignored on a pty).
    pub rtu_pty: Option<PathBuf>,
    pub weighing_pty: Option<PathBuf>,
    /// The register image served on Modbus (the holding block mirrors the PLC window).
    pub bank: RegisterBank,
    pub status: watch::Receiver<Status>,
    task: JoinHandle<anyhow::Result<u64>>,
    _rtu: Option<JoinHandle<std::io::Result<()>>>,
    _keep_open: Vec<SerialStream>,
    /// Dropped after the ptys' users: the links go when the simulation does.
    _links: Vec<PtyLink>,
}

impl Running {
    /// Wait until the program ends; returns the number of steps.
    pub async fn join(mut self) -> anyhow::Result<u64> {
        let r = (&mut self.task)
            .await
            .map_err(|e| anyhow::anyhow!("simulation task: {e}"))?;
        if let Some(h) = self._rtu.take() {
            h.abort();
        }
        r
    }

    pub fn abort(&self) {
        self.task.abort();
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.task.abort();
        if let Some(h) = &self._rtu {
            h.abort();
        }
    }
}

/// Log each fault edge once, bring the Modbus TCP server down or up and mute or unmute the RTU
/// slave to match the schedule (idempotent, so overlapping windows are one outage).
async fn apply_transport_faults(
    changes: &[Transition],
    active: &Active,
    tcp: Option<&mut PlcServer>,
    rtu: Option<&RtuMute>,
) -> anyhow::Result<()> {
    for c in changes {
        let what = match c.node {
            Some(n) => format!("{:?} (node {n})", c.kind),
            None => format!("{:?}", c.kind),
        };
        let edge = if c.started { "started" } else { "cleared" };
        eprintln!("hil-sim: fault {what} {edge} at t = {:.3} s", c.t_s);
    }
    if let Some(m) = rtu {
        m.set(!active.rtu_answers());
    }
    if let Some(srv) = tcp {
        if active.modbus_down && srv.is_up() {
            srv.stop();
        } else if !active.modbus_down && !srv.is_up() {
            srv.restart().await.map_err(|e| {
                anyhow::anyhow!("modbus tcp: listening again on {}: {e}", srv.local_addr())
            })?;
        }
    }
    Ok(())
}

/// Log the PLC's events of the last step (stamped with the simulated time after it); print the
/// watchdog's edges.
fn log_plc_events(
    world: &mut World,
    csv: Option<&mut std::io::BufWriter<std::fs::File>>,
) -> anyhow::Result<()> {
    use crate::controller::plc::PlcEventKind;
    let events = world.plc_mut().take_events();
    if events.is_empty() {
        return Ok(());
    }
    let (t, lsb) = (world.t_s(), world.plc().config().lsb_um);
    let mut csv = csv;
    for e in events {
        let [x, y, z] = e.shift_counts.map(|c| c as f64 * lsb);
        if !matches!(e.kind, PlcEventKind::Latch | PlcEventKind::Ramp) {
            eprintln!(
                "hil-sim: plc watchdog {} at t = {t:.3} s, applied [{x}, {y}, {z}] µm",
                e.kind.name()
            );
        }
        if let Some(f) = csv.as_deref_mut() {
            let row = format!("{t:.4},{},{x},{y},{z}\n", e.kind.name());
            std::io::Write::write_all(f, row.as_bytes())?;
        }
    }
    Ok(())
}

/// One step's frames (those of silenced nodes left out); on socketcand in one write, not one
/// syscall per frame.
async fn send_frames(
    bus: &mut AnyCanBus,
    frames: &[retrocomp_bus::can::Frame],
    active: &Active,
) -> anyhow::Result<()> {
    let due: Vec<_> = frames
        .iter()
        .filter(|f| !silenced(f, active))
        .copied()
        .collect();
    if due.is_empty() {
        return Ok(());
    }
    if let AnyCanBus::Socketcand(b) = bus {
        return b
            .send_all(&due)
            .await
            .map_err(|e| anyhow::anyhow!("CAN send: {e}"));
    }
    for f in &due {
        bus.send(f)
            .await
            .map_err(|e| anyhow::anyhow!("CAN send: {e}"))?;
    }
    Ok(())
}

/// Print a "behind real time" episode's edges (once at start, once at clear).
fn report_lag(edge: Option<LagEdge>, t_s: f64) {
    match edge {
        Some(LagEdge::Started { lag_s }) => eprintln!(
            "hil-sim: behind real time started at t = {t_s:.3} s (lag {:.1} ms)",
            lag_s * 1e3
        ),
        Some(LagEdge::Cleared {
            lasted_s,
            max_lag_s,
        }) => eprintln!(
            "hil-sim: behind real time cleared at t = {t_s:.3} s (lasted {lasted_s:.3} s; max lag \
             so far {:.1} ms)",
            max_lag_s * 1e3
        ),
        None => {}
    }
}

/// Start the simulation and its buses. `mem` is the in-process CAN bus for `backend = "mem"`;
/// `out` optionally receives recording.csv + manifest.json.
pub async fn start(
    cfg: SimConfig,
    mem: Option<MemBus>,
    out: Option<&Path>,
) -> anyhow::Result<Running> {
    let io = cfg.io.clone();
    let world = World::new(cfg)?;
    let bank = RegisterBank::new();
    let (n, ack) = serve_plc_window(&world, &bank)?;
    let clock = SimClock::default();
    let (write_log_tx, write_log) = tokio::sync::mpsc::unbounded_channel::<WriteEvent>();
    let tr = open_transports(&io, &world, &bank, n, &clock, &write_log_tx, mem.as_ref()).await?;
    let outputs = open_outputs(out, &world, tr.tcp.is_some())?;
    let dnc = match &io.dnc {
        Some(d) => Some(DncPort::open(d, out)?),
        None => None,
    };
    drop(write_log_tx);
    let modbus_tcp = tr.tcp.as_ref().map(|srv| srv.local_addr());
    let schedule = Schedule::new(io.faults.clone());
    // Mean 30 ms between bursts: about one and a half per weighing line at 50 lines/s.
    let garbage = Garbage::new(world.config().seed, 0.03);
    let publisher = Publisher::new(io, &world);
    let (status_tx, status) = watch::channel(Status::default());
    let sim = SimTask {
        world,
        bank: bank.clone(),
        n,
        ack,
        clock,
        tcp: tr.tcp,
        rtu_mute: tr.rtu_mute,
        can: tr.can,
        weigh: tr.weigh,
        outputs,
        write_log,
        schedule,
        garbage,
        publisher,
        status_tx,
        dropped: 0,
        dnc,
        dwells: DwellLog::new(out),
    };
    let task = tokio::spawn(sim.run());
    Ok(Running {
        modbus_tcp,
        rtu_pty: tr.rtu_pty,
        weighing_pty: tr.weighing_pty,
        bank,
        status,
        task,
        _rtu: tr.rtu,
        _keep_open: tr.keep,
        _links: tr.links,
    })
}

/// Serve the PLC window as the holding block: its current words, client-writable except the ack
/// register (which belongs to the PLC). Returns the window length and the ack register.
fn serve_plc_window(world: &World, bank: &RegisterBank) -> anyhow::Result<(u16, Option<u16>)> {
    let n = u16::try_from(world.plc().len())
        .map_err(|_| anyhow::anyhow!("a PLC window of more than 65535 registers"))?;
    let ack = world
        .plc()
        .config()
        .handshake
        .as_ref()
        .map(|h| h.ack_register);
    bank.set_holding(0, world.plc().read(0, n as usize)?);
    for a in 0..n {
        if Some(a) != ack {
            bank.allow_writes(a, 1);
        }
    }
    Ok((n, ack))
}

/// The configured transports, open: what the simulation task feeds and what [`Running`] keeps.
struct Transports {
    tcp: Option<PlcServer>,
    rtu: Option<JoinHandle<std::io::Result<()>>>,
    rtu_mute: Option<RtuMute>,
    rtu_pty: Option<PathBuf>,
    weigh: Option<SerialStream>,
    weighing_pty: Option<PathBuf>,
    can: Option<AnyCanBus>,
    /// The pty slaves, kept open so the ptys stay up while no client has them open.
    keep: Vec<SerialStream>,
    /// The ptys' symlinks, removed with them.
    links: Vec<PtyLink>,
}

/// Open the transports of `io`, in order: Modbus TCP, the RTU pty, the weighing pty, CAN.
async fn open_transports(
    io: &crate::io::IoConfig,
    world: &World,
    bank: &RegisterBank,
    n: u16,
    clock: &SimClock,
    write_log_tx: &tokio::sync::mpsc::UnboundedSender<WriteEvent>,
    mem: Option<&MemBus>,
) -> anyhow::Result<Transports> {
    let (mut tcp, mut rtu, mut rtu_pty, mut keep) = (None, None, None, Vec::new());
    let mut links = Vec::new();
    let mut rtu_mute = None;
    if let Some(mb) = &io.modbus {
        if let Some(b) = &mb.tcp_bind {
            let addr: SocketAddr = b
                .parse()
                .map_err(|e| anyhow::anyhow!("io.modbus.tcp_bind `{b}`: {e}"))?;
            tcp = Some(
                PlcServer::start(
                    addr,
                    bank.clone(),
                    world.plc().config().clone(),
                    n,
                    clock.clone(),
                    write_log_tx.clone(),
                )
                .await
                .map_err(|e| anyhow::anyhow!("io.modbus.tcp_bind {addr}: {e}"))?,
            );
        }
        if let Some(link) = &mb.rtu_pty_link {
            let (master, slave, link) = pty_pair(link)?;
            let (task, mute) = rtu_slave::spawn(master, bank.clone(), mb.rtu_slave);
            rtu = Some(task);
            rtu_mute = Some(mute);
            keep.push(slave);
            rtu_pty = Some(link.dev.clone());
            links.push(link);
        }
    }
    let (mut weigh, mut weighing_pty) = (None, None);
    if let Some(w) = &io.weighing {
        let (master, slave, link) = pty_pair(&w.pty_link)?;
        weigh = Some(master);
        keep.push(slave);
        weighing_pty = Some(link.dev.clone());
        links.push(link);
    }
    let can: Option<AnyCanBus> = match &io.can {
        Some(c) => Some(
            open_can(&c.backend, mem)
                .await
                .map_err(|e| anyhow::anyhow!("io.can: {e}"))?,
        ),
        None => None,
    };
    Ok(Transports {
        tcp,
        rtu,
        rtu_mute,
        rtu_pty,
        weigh,
        weighing_pty,
        can,
        keep,
        links,
    })
}

/// The files written into `out`: the recording (after manifest.json), the PLC's latch log and,
/// with a Modbus TCP server, its client-write log.
struct Outputs {
    rec: Option<Recorder<std::io::BufWriter<std::fs::File>>>,
    latches_csv: Option<std::io::BufWriter<std::fs::File>>,
    writes_csv: Option<std::io::BufWriter<std::fs::File>>,
}

/// Create the output files in `out` (nothing without it) with their headers and first rows.
fn open_outputs(out: Option<&Path>, world: &World, has_tcp: bool) -> anyhow::Result<Outputs> {
    let rec = match out {
        Some(dir) => {
            std::fs::create_dir_all(dir)?;
            std::fs::write(
                dir.join("manifest.json"),
                serde_json::to_string_pretty(&world.manifest())? + "\n",
            )?;
            let f = std::io::BufWriter::new(std::fs::File::create(dir.join("recording.csv"))?);
            let mut r = Recorder::new(f, world)?;
            r.write(world.readings())?;
            Some(r)
        }
        None => None,
    };
    let latches_csv = match out {
        Some(dir) => {
            let mut f =
                std::io::BufWriter::new(std::fs::File::create(dir.join("plc_latches.csv"))?);
            std::io::Write::write_all(&mut f, b"t_s,event,x_um,y_um,z_um\n")?;
            Some(f)
        }
        None => None,
    };
    // Every client write to the PLC window, for observers (tests assert clamp/cap/no-jump on it).
    let writes_csv = match (out, has_tcp) {
        (Some(dir), true) => {
            let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("plc_writes.csv"))?);
            std::io::Write::write_all(&mut f, WriteEvent::CSV_HEADER.as_bytes())?;
            Some(f)
        }
        _ => None,
    };
    Ok(Outputs {
        rec,
        latches_csv,
        writes_csv,
    })
}

/// The simulation task: owns the world and everything it feeds each step.
struct SimTask {
    world: World,
    bank: RegisterBank,
    /// Length of the PLC window (the holding block).
    n: u16,
    ack: Option<u16>,
    clock: SimClock,
    tcp: Option<PlcServer>,
    rtu_mute: Option<RtuMute>,
    can: Option<AnyCanBus>,
    weigh: Option<SerialStream>,
    outputs: Outputs,
    write_log: tokio::sync::mpsc::UnboundedReceiver<WriteEvent>,
    schedule: Schedule,
    garbage: Garbage,
    publisher: Publisher,
    status_tx: watch::Sender<Status>,
    /// Weighing lines not written because nobody read the pty.
    dropped: u64,
    dnc: Option<DncPort>,
    dwells: DwellLog,
}

impl SimTask {
    /// Run the program to its end, paced to the wall clock or in batches of 50 steps; returns the
    /// number of steps.
    async fn run(mut self) -> anyhow::Result<u64> {
        let dt = self.world.config().dt_s();
        let realtime = self.world.config().clock.realtime;
        // Paced at `speed` simulated seconds per wall second: one step is dt / speed of wall time.
        let speed = self.world.config().clock.speed;
        let pacer = RealtimePacer::new(dt / speed);
        let mut steps = 0u64;
        let mut lag = LagMeter::default();
        while !self.world.done() {
            let due = if realtime { pacer.steps_due(steps) } else { 50 };
            if due == 0 {
                tokio::time::sleep(pacer.until_next(steps)).await;
                continue;
            }
            for _ in 0..due.min(500) {
                self.scan()?;
                steps += 1;
                self.after_step().await?;
                if self.world.done() {
                    break;
                }
            }
            if realtime {
                report_lag(
                    lag.observe(pacer.elapsed_s(), steps as f64 * dt / speed),
                    self.world.t_s(),
                );
            }
            self.publish_status(&lag);
            if !realtime {
                tokio::task::yield_now().await;
            }
        }
        self.finish(realtime, &lag)?;
        Ok(steps)
    }

    /// Client writes → PLC window (the ack register belongs to the PLC), step, the PLC's window →
    /// image: one critical section, like a PLC's scan.
    fn scan(&mut self) -> anyhow::Result<()> {
        if let Some(d) = self.dnc.as_mut() {
            d.pump_in(&mut self.world);
        }
        let (world, n, ack) = (&mut self.world, self.n, self.ack);
        self.bank
            .update_holding(0, n, |words| -> anyhow::Result<()> {
                if let Some(a) = ack {
                    words[a as usize] = world.plc().read(a, 1)?[0];
                }
                world.plc_mut().write(0, words)?;
                world.tick();
                words.copy_from_slice(world.plc().read(0, n as usize)?);
                Ok(())
            })
            .unwrap_or_else(|| {
                world.tick();
                Ok(())
            })
    }

    /// Everything that follows a step: the clock, PLC events, transport faults, the recording, the
    /// published frames, registers and weighing lines, the client-write log.
    async fn after_step(&mut self) -> anyhow::Result<()> {
        self.clock.set(self.world.t_s());
        if let Some(d) = self.dnc.as_mut() {
            d.after_step(&mut self.world).await?;
        }
        self.dwells.after_step(&mut self.world)?;
        log_plc_events(&mut self.world, self.outputs.latches_csv.as_mut())?;
        let (active, changes) = self.schedule.advance(self.world.t_s());
        if !changes.is_empty() {
            apply_transport_faults(&changes, &active, self.tcp.as_mut(), self.rtu_mute.as_ref())
                .await?;
        }
        if let (Some(r), true) = (self.outputs.rec.as_mut(), self.world.sampled()) {
            r.write(self.world.readings())?;
        }
        let o = self.publisher.poll(&mut self.world);
        if let Some(bus) = self.can.as_mut() {
            send_frames(bus, &o.frames, &active).await?;
        }
        for (a, w) in &o.input_regs {
            self.bank.set_input(*a, w);
        }
        if let Some(p) = self.weigh.as_mut() {
            let mut chunks = vec![self.garbage.poll(self.world.t_s(), active.serial_garbage)];
            chunks.extend(o.lines.iter().map(|l| l.as_bytes().to_vec()));
            write_weighing(p, &chunks, self.world.t_s(), &mut self.dropped).await;
        }
        while let Ok(ev) = self.write_log.try_recv() {
            if let Some(f) = self.outputs.writes_csv.as_mut() {
                std::io::Write::write_all(f, ev.csv_row().as_bytes())?;
            }
        }
        Ok(())
    }

    /// Publish the live state to the observers (once per batch).
    fn publish_status(&self, lag: &LagMeter) {
        let world = &self.world;
        let enc = std::array::from_fn(|k| world.encoder_counts(k));
        self.status_tx.send_replace(Status {
            t_s: world.t_s(),
            shift_counts: world.plc().shift_counts(),
            encoder_counts: enc,
            setpoint_mm: world.setpoint().pos_mm,
            done: world.done(),
            dropped_lines: self.dropped,
            lag_s: lag.lag_s,
            max_lag_s: lag.max_lag_s,
        });
    }

    /// Print the pace summary (paced or lines dropped) and finish and flush the output files.
    fn finish(mut self, realtime: bool, lag: &LagMeter) -> anyhow::Result<()> {
        let dropped = self.dropped;
        if let Some(d) = self.dnc.take() {
            d.finish(&mut self.world)?;
        }
        self.dwells.finish()?;
        if realtime || dropped > 0 {
            eprintln!(
                "hil-sim: real time: max lag {:.1} ms, {} episode(s) behind for {:.3} s; \
                 weighing lines dropped: {dropped}",
                lag.max_lag_s * 1e3,
                lag.episodes,
                lag.behind_s
            );
        }
        if let Some(r) = self.outputs.rec {
            r.finish()?;
        }
        if let Some(mut f) = self.outputs.writes_csv {
            std::io::Write::flush(&mut f)?;
        }
        if let Some(mut f) = self.outputs.latches_csv {
            std::io::Write::flush(&mut f)?;
        }
        Ok(())
    }
}

/// Write one step's chunks (a garbage burst, the weighing lines) onto the weighing pty, empty ones
/// skipped; a chunk nobody takes within 2 ms is dropped and counted (the first drop is reported).
async fn write_weighing(p: &mut SerialStream, chunks: &[Vec<u8>], t_s: f64, dropped: &mut u64) {
    for bytes in chunks.iter().filter(|b| !b.is_empty()) {
        let wr = tokio::time::timeout(std::time::Duration::from_millis(2), p.write_all(bytes));
        if !matches!(wr.await, Ok(Ok(()))) {
            if *dropped == 0 {
                eprintln!(
                    "hil-sim: weighing line not written at t = {t_s:.3} s \
                     (nobody reads the pty?); counting them",
                );
            }
            *dropped += 1;
        }
    }
}
