//! Starts the configured bus sources and merges their samples into one channel for the runtime.
//! Today: `[can]` + `[canopen]` (CiA 406 encoders, CiA 404 analog inputs) over any src/bus backend.
//! `[modbus]` / `[serial]` are refused with a message until src/bus provides their pollers.

use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use tokio::sync::mpsc;

use super::config::FieldConfig;
use crate::bus::Sample;
use crate::bus::can::backend;
use crate::bus::canopen::source::{self as canopen, CanopenSource};

/// Spawn every configured source; samples (timestamped on `epoch`) arrive on the returned channel.
pub async fn spawn_sources(
    cfg: &FieldConfig,
    epoch: Instant,
) -> anyhow::Result<mpsc::Receiver<Sample>> {
    if cfg.modbus.is_some() || cfg.serial.is_some() {
        bail!(
            "[modbus] / [serial] sources are configured but src/bus has no Modbus poller or serial \
             source wired yet; remove them or use CAN sources"
        );
    }
    let (tx, rx) = mpsc::channel::<Sample>(16_384);
    if let (Some(can), Some(co)) = (cfg.can.clone(), cfg.canopen.clone()) {
        let mut bus = backend::open(&can, None)
            .await
            .with_context(|| format!("opening CAN backend {can:?}"))?;
        let (btx, mut brx) = mpsc::channel::<Vec<Sample>>(1024);
        tokio::spawn(async move {
            let mut src = CanopenSource::new(co);
            let clock = move || epoch.elapsed().as_secs_f64();
            if let Err(e) =
                canopen::run(&mut bus, &mut src, clock, Duration::from_millis(10), btx).await
            {
                tracing::error!(%e, "CAN source stopped");
            }
        });
        tokio::spawn(async move {
            while let Some(batch) = brx.recv().await {
                for s in batch {
                    if tx.send(s).await.is_err() {
                        return;
                    }
                }
            }
        });
    }
    Ok(rx)
}
