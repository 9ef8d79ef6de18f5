//! The Modbus polling client (tokio-modbus, TCP or RTU): the async shell that does the I/O its
//! sans-IO [`PollSchedule`] asks for (when to connect and read; [`PollCore`] turns outcomes into
//! samples).
//!
//! What it adds to tokio-modbus (rust-stack.md §2): a timeout on every request and on connect (#113:
//! the client has none); after a timeout or transport error the context is dropped and rebuilt with
//! exponential backoff (#219 no reconnect; #60 poor RTU recovery after a bad frame); Modbus exceptions
//! are values (→ `DecodeError` samples); on RTU a silence of t3.5 is kept between frames (#180).

#[cfg(doc)]
use super::poll_core::PollCore;
use super::poll_core::{PollCounters, ReadOutcome, rtu_silence_s};
use super::poll_schedule::{PollRequest, PollSchedule, PollStep};
use super::regmap::RegisterChannel;
use crate::{ChannelTable, Sample};
use std::time::Duration;
use tokio::time::Instant;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::{Slave, SlaveContext};

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TransportKind {
    Tcp,
    Rtu,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Parity {
    #[default]
    None,
    Even,
    Odd,
}

fn d_port() -> u16 {
    502
}
fn d_baud() -> u32 {
    9600
}
fn d_unit() -> u8 {
    1
}
fn d_period() -> f64 {
    1.0
}
fn d_timeout() -> f64 {
    0.5
}
fn d_bmin() -> f64 {
    0.2
}
fn d_bmax() -> f64 {
    10.0
}

/// One `[[modbus.source]]` of the field TOML.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusSourceConfig {
    pub name: String,
    pub transport: TransportKind,
    /// TCP: host name or IP.
    #[serde(default)]
    pub host: Option<String>,
    #[serde(default = "d_port")]
    pub port: u16,
    /// RTU: serial device path.
    #[serde(default)]
    pub device: Option<String>,
    #[serde(default = "d_baud")]
    pub baud: u32,
    #[serde(default)]
    pub parity: Parity,
    #[serde(default = "d_unit")]
    pub unit_id: u8,
    #[serde(default = "d_period")]
    pub period_s: f64,
    #[serde(default = "d_timeout")]
    pub timeout_s: f64,
    #[serde(default = "d_bmin")]
    pub backoff_min_s: f64,
    #[serde(default = "d_bmax")]
    pub backoff_max_s: f64,
    /// Largest unmapped hole merged into one read (0 = never read unmapped registers).
    #[serde(default)]
    pub max_gap: u16,
    #[serde(default)]
    pub channel: Vec<RegisterChannel>,
}

pub struct ModbusPoller {
    pub cfg: ModbusSourceConfig,
    pub schedule: PollSchedule,
    ctx: Option<Context>,
    /// The schedule's clock: seconds since the poller was made.
    epoch: Instant,
    last_io: Option<Instant>,
}

impl std::fmt::Debug for ModbusPoller {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ModbusPoller")
            .field("source", &self.cfg.name)
            .field("connected", &self.ctx.is_some())
            .field("counters", &self.schedule.core.counters)
            .finish()
    }
}

fn secs(s: f64) -> Duration {
    Duration::from_secs_f64(if s.is_finite() {
        s.clamp(0.0, 3600.0)
    } else {
        1.0
    })
}

impl ModbusPoller {
    /// The poller of `cfg`, its channels resolved in `channels` (the gateway's table).
    pub fn new(cfg: ModbusSourceConfig, channels: &mut ChannelTable) -> Self {
        ModbusPoller {
            schedule: PollSchedule::new(&cfg, channels),
            cfg,
            ctx: None,
            epoch: Instant::now(),
            last_io: None,
        }
    }

    pub fn counters(&self) -> PollCounters {
        self.schedule.counters()
    }

    pub fn is_connected(&self) -> bool {
        self.ctx.is_some()
    }

    fn now_s(&self) -> f64 {
        self.epoch.elapsed().as_secs_f64()
    }

    async fn connect(&self) -> std::io::Result<Context> {
        let slave = Slave(self.cfg.unit_id);
        match self.cfg.transport {
            TransportKind::Tcp => {
                let host = self.cfg.host.as_deref().unwrap_or("127.0.0.1");
                let addr = tokio::net::lookup_host((host, self.cfg.port))
                    .await?
                    .next()
                    .ok_or_else(|| std::io::Error::other(format!("no address for {host}")))?;
                tokio_modbus::client::tcp::connect_slave(addr, slave).await
            }
            TransportKind::Rtu => {
                let dev = self.cfg.device.as_deref().unwrap_or("");
                let parity = match self.cfg.parity {
                    Parity::None => tokio_serial::Parity::None,
                    Parity::Even => tokio_serial::Parity::Even,
                    Parity::Odd => tokio_serial::Parity::Odd,
                };
                let port = tokio_serial::SerialStream::open(
                    &tokio_serial::new(dev, self.cfg.baud).parity(parity),
                )
                .map_err(std::io::Error::other)?;
                Ok(tokio_modbus::client::rtu::attach_slave(port, slave))
            }
        }
    }

    /// Connect within `timeout_s`.
    async fn try_connect(&mut self) -> bool {
        match tokio::time::timeout(secs(self.cfg.timeout_s), self.connect()).await {
            Ok(Ok(ctx)) => {
                self.ctx = Some(ctx);
                true
            }
            Ok(Err(e)) => {
                tracing::debug!(source = %self.cfg.name, "modbus connect failed: {e}");
                false
            }
            Err(_) => false,
        }
    }

    async fn read_block(&mut self, b: usize) -> ReadOutcome {
        let Some(ctx) = self.ctx.as_mut() else {
            return ReadOutcome::Transport("not connected".into());
        };
        if self.cfg.transport == TransportKind::Rtu {
            // tokio-modbus does not keep the inter-frame gap (#180); a multi-drop line needs it.
            if let Some(t) = self.last_io {
                tokio::time::sleep_until(t + secs(rtu_silence_s(self.cfg.baud))).await;
            }
        }
        let blk = &self.schedule.core.plan[b];
        ctx.set_slave(Slave(self.cfg.unit_id));
        let fut = async { super::read::read_registers(ctx, blk.kind, blk.start, blk.count).await };
        let r = tokio::time::timeout(secs(self.cfg.timeout_s), fut).await;
        self.last_io = Some(Instant::now());
        match r {
            Err(_) => ReadOutcome::Timeout,
            Ok(Err(e)) => ReadOutcome::Transport(e.to_string()),
            Ok(Ok(Err(exc))) => ReadOutcome::Exception(exc),
            Ok(Ok(Ok(words))) => ReadOutcome::Registers(words),
        }
    }

    /// Do what the schedule asks until the poll ends; its counters around it and the link after.
    async fn drive(
        &mut self,
        first: PollStep,
        out: &mut Vec<Sample>,
    ) -> Option<(PollCounters, PollCounters)> {
        let mut step = first;
        loop {
            step = match step {
                PollStep::Idle => return None,
                PollStep::Done { before, after, .. } => return Some((before, after)),
                PollStep::Request(PollRequest::Connect) => {
                    let ok = self.try_connect().await;
                    self.schedule.handle_connect(ok, self.now_s(), out)
                }
                PollStep::Request(PollRequest::Read(b)) => {
                    let outcome = self.read_block(b).await;
                    if matches!(outcome, ReadOutcome::Timeout | ReadOutcome::Transport(_)) {
                        // The context may hold a late reply or a half frame: rebuild it (#60, #219).
                        self.ctx = None;
                    }
                    self.schedule.handle_outcome(&outcome, self.now_s(), out)
                }
            };
        }
    }

    /// One poll over every planned read now (whatever the period); samples (timestamped `t_s`)
    /// are appended to `out`.
    pub async fn poll_once(&mut self, t_s: f64, out: &mut Vec<Sample>) {
        let first = self.schedule.begin(self.now_s(), t_s, out);
        self.drive(first, out).await;
    }

    /// Poll every `period_s` until `out` is closed.
    pub async fn run(self, clock_s: impl Fn() -> f64, out: tokio::sync::mpsc::Sender<Vec<Sample>>) {
        self.run_observed(clock_s, out, |_, _, _| {}).await;
    }

    /// [`Self::run`], calling `observe(before, after, connected)` with the counters around every
    /// poll, so the caller can turn failed polls and exception replies into faults. Samples are
    /// stamped with `clock_s()` at each poll's start.
    pub async fn run_observed(
        mut self,
        clock_s: impl Fn() -> f64,
        out: tokio::sync::mpsc::Sender<Vec<Sample>>,
        mut observe: impl FnMut(&PollCounters, &PollCounters, bool),
    ) {
        loop {
            if let Some(due_s) = self.schedule.poll_timeout() {
                let wait = due_s - self.now_s();
                if wait > 0.0 {
                    tokio::time::sleep(secs(wait)).await;
                }
            }
            let mut batch = Vec::new();
            let first = self.schedule.poll(self.now_s(), clock_s(), &mut batch);
            let Some((before, after)) = self.drive(first, &mut batch).await else {
                continue;
            };
            observe(&before, &after, self.is_connected());
            if out.send(batch).await.is_err() {
                return;
            }
        }
    }
}
