//! Starts the configured bus sources and merges their samples into one channel for the runtime:
//! `[can]` + `[canopen]` (CiA 406 encoders, CiA 404 analog inputs) over any src/bus backend,
//! every `[[modbus.source]]` (TCP/RTU poller: timeouts, reconnect with backoff, exceptions as
//! `DecodeError` samples) and every `[[serial.source]]` (line framer + format parser).
//!
//! All samples are timestamped in seconds since `epoch` (the runtime's clock). A source that goes
//! silent sends nothing (or `Stale` samples): the runtime's channel health turns it `Stale` after the
//! channel's `stale_after_s`, so a dead source never stops the others.

use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::mpsc;

use super::config::FieldConfig;
use crate::bus::Sample;
use crate::bus::can::backend;
use crate::bus::canopen::source::{self as canopen, CanopenSource};
use crate::bus::modbus::poller::ModbusPoller;
use crate::bus::serial::source::{self as serial, LineSource, SerialSourceConfig};

/// Reopen delays of a serial port that closed or failed, s (doubling up to the max).
const SERIAL_REOPEN_MIN_S: f64 = 0.5;
const SERIAL_REOPEN_MAX_S: f64 = 10.0;

/// Spawn every configured source; samples (timestamped on `epoch`) arrive on the returned channel.
/// Fails at start (naming the source) if a CAN backend or a serial device cannot be opened; a Modbus
/// peer that is down at start is retried by its poller.
pub async fn spawn_sources(
    cfg: &FieldConfig,
    epoch: Instant,
) -> anyhow::Result<mpsc::Receiver<Sample>> {
    let (tx, rx) = mpsc::channel::<Sample>(16_384);
    let clock = move || epoch.elapsed().as_secs_f64();
    if let (Some(can), Some(co)) = (cfg.can.clone(), cfg.canopen.clone()) {
        let mut bus = backend::open(&can, None)
            .await
            .with_context(|| format!("opening CAN backend {can:?}"))?;
        let btx = forward(tx.clone());
        tokio::spawn(async move {
            let mut src = CanopenSource::new(co);
            if let Err(e) =
                canopen::run(&mut bus, &mut src, clock, Duration::from_millis(10), btx).await
            {
                tracing::error!(%e, "CAN source stopped");
            }
        });
    }
    for m in cfg.modbus.iter().flat_map(|m| &m.source) {
        let btx = forward(tx.clone());
        tracing::info!(source = %m.name, transport = ?m.transport, "starting Modbus poller");
        spawn_modbus(ModbusPoller::new(m.clone()), clock, btx)
            .with_context(|| format!("modbus source {:?}: cannot start its thread", m.name))?;
    }
    for s in cfg.serial.iter().flat_map(|s| &s.source) {
        let port = serial::open(s).with_context(|| {
            format!(
                "serial source {:?}: cannot open device {:?} at {} baud",
                s.name,
                s.device.as_deref().unwrap_or(""),
                s.baud
            )
        })?;
        let btx = forward(tx.clone());
        tokio::spawn(serial_loop(s.clone(), port, clock, btx));
    }
    Ok(rx)
}

/// A batch sender whose batches are unpacked into `tx` by a forwarding task.
fn forward(tx: mpsc::Sender<Sample>) -> mpsc::Sender<Vec<Sample>> {
    let (btx, mut brx) = mpsc::channel::<Vec<Sample>>(1024);
    tokio::spawn(async move {
        while let Some(batch) = brx.recv().await {
            for s in batch {
                if tx.send(s).await.is_err() {
                    return;
                }
            }
        }
    });
    btx
}

/// Run one Modbus poller on its own thread and current-thread runtime: its future is not `Send`
/// (tokio-modbus's client context is not `Sync` and the poller holds `&self` across the connect
/// await), so it cannot go on the multi-thread runtime. It ends when `out` closes.
fn spawn_modbus(
    poller: ModbusPoller,
    clock: impl Fn() -> f64 + Send + 'static,
    out: mpsc::Sender<Vec<Sample>>,
) -> std::io::Result<()> {
    let name = format!("modbus-{}", poller.cfg.name);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    std::thread::Builder::new()
        .name(name)
        .spawn(move || rt.block_on(poller.run(clock, out)))?;
    Ok(())
}

/// Run one serial source; when the port closes or fails (USB adapter unplugged), reopen it with a
/// doubling delay. Meanwhile its channels get no samples and go `Stale` in the runtime.
async fn serial_loop(
    cfg: SerialSourceConfig,
    first: tokio_serial::SerialStream,
    clock: impl Fn() -> f64 + Copy,
    out: mpsc::Sender<Vec<Sample>>,
) {
    let mut port = Some(first);
    let mut delay_s = SERIAL_REOPEN_MIN_S;
    loop {
        if let Some(p) = port.take() {
            match serial::run(p, LineSource::new(cfg.clone()), clock, out.clone()).await {
                Ok(c) => tracing::warn!(source = %cfg.name, ?c, "serial port closed"),
                Err(e) => tracing::warn!(source = %cfg.name, %e, "serial port failed"),
            }
            delay_s = SERIAL_REOPEN_MIN_S;
        }
        if out.is_closed() {
            return;
        }
        tokio::time::sleep(Duration::from_secs_f64(delay_s)).await;
        match serial::open(&cfg) {
            Ok(p) => port = Some(p),
            Err(e) => {
                tracing::debug!(source = %cfg.name, %e, "serial reopen failed");
                delay_s = (delay_s * 2.0).min(SERIAL_REOPEN_MAX_S);
            }
        }
    }
}
