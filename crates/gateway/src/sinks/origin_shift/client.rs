//! tokio-modbus shell for the origin-shift registers: connects over TCP or RTU, runs [`WriteCycle`]s,
//! wraps every request in a timeout (tokio-modbus has none: issue #113) and reconnects with exponential
//! backoff after a transport failure (tokio-modbus has no reconnect: #219/#309).
//!
//! On start, [`OriginShiftClient::read_current`] reads what the controller already holds so the safety
//! layer ramps from there instead of jumping after a restart.

use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::time::Instant;
use tokio_modbus::client::{Context, Writer};
use tokio_modbus::prelude::Slave;

use super::cycle::{Action, Outcome, Reply, WriteCycle};
use super::map::{MapError, RegisterMap};
use super::sink::SinkCore;
use retrocomp_bus::modbus::{RegisterTable, read_registers};
use retrocomp_model::Axis;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Transport {
    /// Modbus TCP, e.g. `127.0.0.1:5020`.
    Tcp { address: String },
    /// Modbus RTU on a serial device (8N1).
    Rtu { path: String, baud: u32 },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClientConfig {
    pub transport: Transport,
    #[serde(default = "one")]
    pub unit_id: u8,
    /// Per-request timeout, ms.
    #[serde(default = "default_timeout_ms")]
    pub request_timeout_ms: u64,
    /// Reconnect backoff: first wait and cap, ms.
    #[serde(default = "default_backoff_min_ms")]
    pub reconnect_min_ms: u64,
    #[serde(default = "default_backoff_max_ms")]
    pub reconnect_max_ms: u64,
}

/// Spelled out (no `flatten`) so unknown keys are rejected; [`OriginShiftSink::client`] builds the
/// client settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OriginShiftSink {
    pub transport: Transport,
    #[serde(default = "one")]
    pub unit_id: u8,
    #[serde(default = "default_timeout_ms")]
    pub request_timeout_ms: u64,
    #[serde(default = "default_backoff_min_ms")]
    pub reconnect_min_ms: u64,
    #[serde(default = "default_backoff_max_ms")]
    pub reconnect_max_ms: u64,
    /// Write period, ms (a PLC scan takes 10–100 ms; writing faster only loads the bus).
    #[serde(default = "default_write_period_ms")]
    pub write_period_ms: u64,
    pub map: RegisterMap,
}

fn default_write_period_ms() -> u64 {
    50
}

impl OriginShiftSink {
    pub fn client(&self) -> ClientConfig {
        ClientConfig {
            transport: self.transport.clone(),
            unit_id: self.unit_id,
            request_timeout_ms: self.request_timeout_ms,
            reconnect_min_ms: self.reconnect_min_ms,
            reconnect_max_ms: self.reconnect_max_ms,
        }
    }
}

fn one() -> u8 {
    1
}
fn default_timeout_ms() -> u64 {
    200
}
fn default_backoff_min_ms() -> u64 {
    100
}
fn default_backoff_max_ms() -> u64 {
    5_000
}

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("origin_shift: not connected (next attempt in {0:?}): {1}")]
    Disconnected(Duration, String),
    #[error("origin_shift: {0}")]
    Map(#[from] MapError),
    #[error("origin_shift: reading {axis} at {address}: {reason}")]
    Read {
        axis: String,
        address: u16,
        reason: String,
    },
}

pub struct OriginShiftClient {
    cfg: ClientConfig,
    map: RegisterMap,
    ctx: Option<Context>,
    backoff: retrocomp_bus::Backoff,
    next_attempt: Instant,
    last_error: String,
    strobe: u16,
    epoch: Instant,
    /// Connections made so far (the first one included): for status and tests.
    pub connects: u64,
}

// By hand: tokio-modbus' client context has no Debug.
impl std::fmt::Debug for OriginShiftClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OriginShiftClient")
            .field("cfg", &self.cfg)
            .field("connected", &self.ctx.is_some())
            .field("last_error", &self.last_error)
            .finish_non_exhaustive()
    }
}

impl OriginShiftClient {
    pub fn new(cfg: ClientConfig, map: RegisterMap) -> Result<Self, MapError> {
        map.validate()?;
        Ok(Self {
            backoff: retrocomp_bus::Backoff::from_millis(
                cfg.reconnect_min_ms,
                cfg.reconnect_max_ms,
            ),
            cfg,
            map,
            ctx: None,
            next_attempt: Instant::now(),
            last_error: "never connected".into(),
            strobe: 0,
            epoch: Instant::now(),
            connects: 0,
        })
    }

    pub fn map(&self) -> &RegisterMap {
        &self.map
    }

    pub fn is_connected(&self) -> bool {
        self.ctx.is_some()
    }

    fn timeout(&self) -> Duration {
        Duration::from_millis(self.cfg.request_timeout_ms)
    }

    /// Connect unless connected; respects the backoff after failures (never blocks on it).
    pub async fn ensure_connected(&mut self) -> Result<(), ClientError> {
        if self.ctx.is_some() {
            return Ok(());
        }
        let now = Instant::now();
        if now < self.next_attempt {
            return Err(ClientError::Disconnected(
                self.next_attempt - now,
                self.last_error.clone(),
            ));
        }
        let slave = Slave(self.cfg.unit_id);
        let attempt = async {
            match &self.cfg.transport {
                Transport::Tcp { address } => {
                    let addr = tokio::net::lookup_host(address)
                        .await?
                        .next()
                        .ok_or_else(|| {
                            std::io::Error::other(format!("no address for {address}"))
                        })?;
                    tokio_modbus::client::tcp::connect_slave(addr, slave).await
                }
                Transport::Rtu { path, baud } => {
                    let port = tokio_serial::SerialStream::open(&tokio_serial::new(path, *baud))
                        .map_err(std::io::Error::other)?;
                    Ok(tokio_modbus::client::rtu::attach_slave(port, slave))
                }
            }
        };
        match tokio::time::timeout(self.timeout(), attempt).await {
            Ok(Ok(ctx)) => {
                self.ctx = Some(ctx);
                self.connects += 1;
                self.backoff.reset();
                tracing::info!(transport = ?self.cfg.transport, "origin_shift connected");
                Ok(())
            }
            Ok(Err(e)) => Err(self.failed(e.to_string())),
            Err(_) => Err(self.failed("connect timed out".into())),
        }
    }

    fn failed(&mut self, reason: String) -> ClientError {
        self.ctx = None;
        let wait = self.backoff.next_delay();
        self.next_attempt = Instant::now() + wait;
        self.last_error = reason.clone();
        ClientError::Disconnected(wait, reason)
    }

    /// One request with the timeout. Transport failures drop the connection (reconnect next time);
    /// Modbus exceptions keep it.
    pub async fn request(&mut self, action: &Action) -> Reply {
        let timeout = self.timeout();
        let Some(ctx) = self.ctx.as_mut() else {
            return Reply::Failed("not connected".into());
        };
        let result = match action {
            Action::Write(b) => {
                if let Err(e) = self.map.check_write(b.address, b.words.len()) {
                    return Reply::Failed(e.to_string());
                }
                tokio::time::timeout(timeout, ctx.write_multiple_registers(b.address, &b.words))
                    .await
                    .map(|r| r.map(|r| r.map(|()| Reply::Written)))
            }
            Action::Read {
                address,
                count,
                not_before_s,
            } => {
                let at = self.epoch + Duration::from_secs_f64(not_before_s.max(0.0));
                // Only a deadline still ahead is waited for: tokio's timer rounds a deadline up to
                // its next 1 ms tick, so sleeping until "now" (the read of what the controller
                // holds, before every write) cost up to a whole millisecond per write period.
                if at > Instant::now() {
                    tokio::time::sleep_until(at).await;
                }
                let read = read_registers(ctx, RegisterTable::Holding, *address, *count);
                tokio::time::timeout(timeout, read)
                    .await
                    .map(|r| r.map(|r| r.map(|w| Reply::Read(w.into()))))
            }
            Action::Done(_) => return Reply::Failed("no request for Done".into()),
        };
        match result {
            Ok(Ok(Ok(reply))) => reply,
            Ok(Ok(Err(exception))) => Reply::Failed(format!("Modbus exception {exception:?}")),
            Ok(Err(e)) => {
                let reason = format!("transport: {e}");
                self.failed(reason.clone());
                Reply::Failed(reason)
            }
            Err(_) => {
                let reason = format!("no reply within {} ms", self.cfg.request_timeout_ms);
                self.failed(reason.clone());
                Reply::Failed(reason)
            }
        }
    }

    fn now_s(&self) -> f64 {
        self.epoch.elapsed().as_secs_f64()
    }

    /// Read the corrections the controller holds now, per axis, µm.
    pub async fn read_current(&mut self) -> Result<Vec<(String, f64)>, ClientError> {
        self.ensure_connected().await?;
        let mut out = Vec::new();
        for r in self.map.axes.clone() {
            let action = Action::Read {
                address: r.address,
                count: r.data_type.words(),
                not_before_s: 0.0,
            };
            match self.request(&action).await {
                Reply::Read(words) => out.push((r.axis.clone(), self.map.decode(&r.axis, &words)?)),
                other => {
                    return Err(ClientError::Read {
                        axis: r.axis.clone(),
                        address: r.address,
                        reason: format!("{other:?}"),
                    });
                }
            }
        }
        Ok(out)
    }

    /// One write period of the sink core (read what the controller holds, guard, write cycle) for
    /// these wanted corrections (µm). The gateway's sink uses this; every value it sends passed the
    /// core's [`super::WriteGuard`].
    pub async fn run_period(&mut self, core: &mut SinkCore, wants_um: &[(Axis, f64)]) -> Outcome {
        if let Err(e) = self.ensure_connected().await {
            core.not_connected(&e.to_string());
            return Outcome::RequestFailed {
                step: "connect",
                address: 0,
                reason: e.to_string(),
            };
        }
        let mut action = core.begin_at(wants_um, self.now_s());
        loop {
            if let Action::Done(outcome) = action {
                return outcome;
            }
            let reply = self.request(&action).await;
            action = core.handle_reply(reply, self.now_s());
        }
    }

    /// Encode and write one set of corrections (µm), with handshake and read-back as configured.
    /// Unguarded and with a remembered strobe: for tests and tools; the gateway uses
    /// [`Self::run_period`].
    pub async fn write(&mut self, corrections_um: &[(Axis, f64)]) -> Result<Outcome, ClientError> {
        let blocks = self.map.encode(corrections_um)?;
        self.ensure_connected().await?;
        let strobe = WriteCycle::next_strobe(self.strobe);
        let (mut cycle, mut action) = WriteCycle::start(&self.map, blocks, strobe);
        loop {
            if let Action::Done(outcome) = action {
                if self.map.handshake.is_some()
                    && !matches!(outcome, Outcome::RequestFailed { step: "write", .. })
                {
                    self.strobe = cycle.strobe_value();
                }
                return Ok(outcome);
            }
            let reply = self.request(&action).await;
            action = cycle.handle_reply(reply, self.now_s());
        }
    }
}
