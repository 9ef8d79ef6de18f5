//! The origin-shift server's periods, sans-IO: everything [`super::server`]'s shell decides between
//! its awaits. A controller write ([`ServedSink::handle_write`]: positions out as samples, held
//! values into the [`ServerCore`] and its guard), a stop ([`ServedSink::handle_stop`]: ramp to 0
//! within the cap, with a deadline), and each update period ([`ServedSink::poll_period`]): the
//! image update through the guard, the controller-silence fault, the fault episodes (each logged
//! once when it starts and once when it clears) and whether the stop has ended. [`ServedBox`] is
//! that sink with the register bank the controller reads and writes (a plain in-memory image): a
//! write the bank accepted becomes a controller write, an update period's blocks and withdrawals
//! go into the bank. The tokio shell serves the bank over TCP or RTU and publishes the status;
//! the virtual-time gateway (`gateway_core`) answers the controller's requests from the same bank.
//!
//! Time: seconds on the gateway clock, passed in. Units: corrections µm, positions mm.

use super::map::Words;
use super::server::{SOURCE, ServerConfig};
use super::server_core::{ServerCore, Update};
use super::sink_task::{SinkSources, update_sink_faults};
use crate::sinks::guard::AxisLimits;
use retrocomp_bus::fault::{FaultEvent, FaultLog};
use retrocomp_bus::modbus::RegisterBank;
use retrocomp_bus::{ChannelId, ChannelTable};
use retrocomp_model::Axis;

/// How a stop ramp-out ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopEnd {
    /// The controller reports holding 0 on every axis.
    RampedOut,
    /// `stop_ramp_max_s` passed first: the controller keeps what it holds.
    Deadline,
}

/// What one update period did.
#[derive(Debug)]
pub struct Period {
    /// The image changed: [`ServedSink::update`] holds the blocks to set and the axes withdrawn.
    pub updated: bool,
    /// Fault edges of this period (sink link and axes).
    pub events: Vec<FaultEvent>,
    /// The controller has not written for `controller_timeout_ms` (only when it writes at all).
    pub silent_s: Option<f64>,
    /// A stop ramp-out ended in this period: the shell stops serving.
    pub stopped: Option<StopEnd>,
}

/// The server sink's state between periods: the register-image core, when the controller last
/// wrote, the fault log, the stop deadline.
#[derive(Debug)]
pub struct ServedSink {
    core: ServerCore,
    /// The map has registers the controller writes (positions or held values): its silence is
    /// a fault.
    listens: bool,
    timeout_s: f64,
    last_write_s: f64,
    faults: FaultLog,
    sources: SinkSources,
    stop_by_s: Option<f64>,
    /// The last period's update, reused: a steady server allocates nothing per period.
    update: Update,
    /// The last controller write's positions (channel, mm), reused.
    positions: Vec<(ChannelId, f64)>,
}

impl ServedSink {
    /// A server for `cfg` with `limits` (clamp and per-update cap per axis), serving from `now_s`;
    /// its position channels resolved in `channels`.
    pub fn new(
        cfg: &ServerConfig,
        limits: &[AxisLimits],
        channels: &mut ChannelTable,
        now_s: f64,
    ) -> Self {
        let core = ServerCore::new(cfg.map.clone(), limits, channels);
        let sources = SinkSources::named(SOURCE, core.axis_names());
        ServedSink {
            core,
            listens: !cfg.map.writable().is_empty(),
            timeout_s: cfg.controller_timeout_ms as f64 / 1e3,
            last_write_s: now_s,
            faults: FaultLog::default(),
            sources,
            stop_by_s: None,
            update: Update::default(),
            positions: Vec::new(),
        }
    }

    pub fn core(&self) -> &ServerCore {
        &self.core
    }

    /// The last period's image update (valid when [`Period::updated`]).
    pub fn update(&self) -> &Update {
        &self.update
    }

    /// The sink's active faults by source name (what `/status` shows).
    pub fn active_faults(&self) -> Vec<(String, retrocomp_bus::fault::FaultKind, f64)> {
        self.faults.active_by_name()
    }

    /// The controller wrote at `now_s`; `read(address, count)` reads the register image it wrote
    /// into. Returns its positions (channel, mm) to send as samples.
    pub fn handle_write(
        &mut self,
        read: impl Fn(u16, u16) -> Option<Words>,
        now_s: f64,
    ) -> &[(ChannelId, f64)] {
        self.last_write_s = now_s;
        self.core
            .handle_controller_write_into(read, &mut self.positions);
        &self.positions
    }

    /// Stop at `now_s`: serve a ramp to 0 within the cap until the controller reports holding 0,
    /// for at most `max_s`. A second stop changes nothing.
    pub fn handle_stop(&mut self, max_s: f64, now_s: f64) {
        if self.stop_by_s.is_none() {
            self.stop_by_s = Some(now_s + max_s);
            self.core.begin_ramp_out();
        }
    }

    pub fn is_stopping(&self) -> bool {
        self.stop_by_s.is_some()
    }

    /// One update period at `now_s` toward `targets` (the engine's outputs, µm).
    pub fn poll_period(&mut self, targets: &[(Axis, f64)], now_s: f64) -> Period {
        let updated = self.core.poll_update_into(targets, &mut self.update);
        let stopped = self.stop_by_s.and_then(|by| {
            if self.core.is_ramped_out() {
                Some(StopEnd::RampedOut)
            } else if now_s >= by {
                Some(StopEnd::Deadline)
            } else {
                None
            }
        });
        let silent = now_s - self.last_write_s;
        let gone = self.listens && silent > self.timeout_s;
        let events = update_sink_faults(
            &mut self.faults,
            &self.sources,
            self.core.faults(),
            !gone,
            now_s,
        );
        Period {
            updated,
            events,
            silent_s: gone.then_some(silent),
            stopped,
        }
    }
}

/// The served register image and its sink.
#[derive(Debug)]
pub struct ServedBox {
    bank: RegisterBank,
    sink: ServedSink,
}

impl ServedBox {
    /// The server of `cfg` with `limits`, serving from `now_s`: only the position, held and marker
    /// registers take writes, and nothing is readable until the controller has reported what it
    /// holds. Position channels are resolved in `channels`.
    pub fn new(
        cfg: &ServerConfig,
        limits: &[AxisLimits],
        channels: &mut ChannelTable,
        now_s: f64,
    ) -> Self {
        let bank = RegisterBank::new();
        for (address, count) in cfg.map.writable() {
            bank.allow_writes(address, count);
        }
        ServedBox {
            bank,
            sink: ServedSink::new(cfg, limits, channels, now_s),
        }
    }

    /// The register image (a handle: the transports serve a clone of it).
    pub fn bank(&self) -> &RegisterBank {
        &self.bank
    }

    pub fn sink(&self) -> &ServedSink {
        &self.sink
    }

    pub fn sink_mut(&mut self) -> &mut ServedSink {
        &mut self.sink
    }

    /// The bank took a write of the controller at `now_s`: read what it wrote. Returns its
    /// positions (channel, mm) to send as samples. Only registers the controller has written
    /// count: a held or position register it has not written yet reads 0 in the image, which is
    /// nobody's report (taking it as "holds 0" would seed the engine, and the guard, from 0 on an
    /// axis the controller holds elsewhere, when its first write carried other registers).
    pub fn handle_bank_write(&mut self, now_s: f64) -> &[(ChannelId, f64)] {
        let bank = &self.bank;
        let read = |a: u16, n: u16| {
            let mut w = Words::from_elem(0, usize::from(n));
            bank.client_written_into(a, &mut w).then_some(w)
        };
        self.sink.handle_write(read, now_s)
    }

    /// One update period at `now_s` toward `targets` (µm), its blocks and withdrawals applied to
    /// the bank.
    pub fn poll_period(&mut self, targets: &[(Axis, f64)], now_s: f64) -> Period {
        let period = self.sink.poll_period(targets, now_s);
        if period.updated {
            let update = self.sink.update();
            for &(address, count) in &update.withdrawn {
                self.bank.clear_holding(address, count);
            }
            for b in &update.blocks {
                self.bank.set_holding(b.address, &b.words);
            }
        }
        period
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sinks::origin_shift::server::ServerTransport;
    use crate::sinks::origin_shift::server_core::guard_tests::{limits, map};
    use retrocomp_bus::fault::FaultKind;

    /// The rogue-report tests' map and limits (`server_core_tests.rs`), updated every 10 ms,
    /// the controller gone after 0.5 s.
    fn cfg() -> ServerConfig {
        ServerConfig {
            transport: ServerTransport::Tcp {
                listen: "127.0.0.1:0".into(),
            },
            unit_id: 1,
            update_period_ms: 10,
            controller_timeout_ms: 500,
            listen_policy: Default::default(),
            map: map(),
        }
    }

    /// The controller's write: what it holds (counts of 0.1 µm) and its position (counts of 10 µm).
    fn report(held_counts: i16, x_counts: i16) -> impl Fn(u16, u16) -> Option<Words> {
        move |a, n| {
            (a..a + n)
                .map(|k| match k {
                    10 => Some(x_counts.cast_unsigned()),
                    11 => Some(held_counts.cast_unsigned()),
                    _ => None,
                })
                .collect()
        }
    }

    fn kinds(events: &[FaultEvent]) -> Vec<(&str, FaultKind, bool)> {
        events
            .iter()
            .map(|e| (e.source.as_str(), e.kind, e.started))
            .collect()
    }

    /// A silent controller is one `disconnected` episode: it starts on the first period after
    /// `controller_timeout_ms` and clears on the next write; positions go out as samples.
    #[test]
    fn a_silent_controller_is_one_episode_and_a_write_ends_it() {
        let mut table = ChannelTable::default();
        let mut s = ServedSink::new(&cfg(), &limits(), &mut table, 0.0);
        let x = [(Axis::X, 10.0)];
        let pos = s.handle_write(report(0, 12345), 0.0).to_vec();
        assert_eq!(pos, vec![(table.get("x_mm").unwrap(), 123.45)]);
        let p = s.poll_period(&x, 0.01);
        assert!(p.updated && p.events.is_empty() && p.silent_s.is_none());
        assert!(
            s.poll_period(&x, 0.5).events.is_empty(),
            "0.5 s is not yet over 0.5 s"
        );
        let p = s.poll_period(&x, 0.51);
        assert_eq!(kinds(&p.events), [(SOURCE, FaultKind::Disconnected, true)]);
        assert!(p.silent_s.is_some_and(|t| (t - 0.51).abs() < 1e-12));
        assert!(s.poll_period(&x, 0.6).events.is_empty(), "logged once");
        s.handle_write(report(10, 12345), 0.65);
        let p = s.poll_period(&x, 0.66);
        assert_eq!(kinds(&p.events), [(SOURCE, FaultKind::Disconnected, false)]);
        assert!(s.active_faults().is_empty());
    }

    /// A held value beyond the clamp, from any writer, withdraws the axis (nothing is served
    /// for it) and is one `beyond_clamp` episode of that axis.
    #[test]
    fn a_reported_value_beyond_the_clamp_withdraws_the_axis() {
        let mut s = ServedSink::new(&cfg(), &limits(), &mut ChannelTable::default(), 0.0);
        let x = [(Axis::X, 10.0)];
        s.handle_write(report(0, 0), 0.0);
        assert!(s.poll_period(&x, 0.01).updated);
        // Another writer puts 0x7FFF (3276.7 µm) into the held register.
        s.handle_write(report(0x7FFF, 0), 0.02);
        let p = s.poll_period(&x, 0.03);
        assert_eq!(
            kinds(&p.events),
            [("sink.origin_shift_server.x", FaultKind::BeyondClamp, true)]
        );
        assert!(p.updated);
        assert_eq!(s.update().withdrawn, vec![(0, 1)], "x's register withdrawn");
        assert!(s.update().exposed_um.is_empty(), "{:?}", s.update());
    }

    /// A stop ramps toward 0 within the cap; it ends when the controller reports 0, or at the
    /// deadline if it never does.
    #[test]
    #[allow(
        clippy::cast_possible_truncation,
        reason = "served values are whole counts within ±50 µm"
    )]
    fn a_stop_ends_when_the_controller_holds_0_or_at_its_deadline() {
        let x = [(Axis::X, 10.0)];
        for (reports_zero, want) in [(true, StopEnd::RampedOut), (false, StopEnd::Deadline)] {
            let mut s = ServedSink::new(&cfg(), &limits(), &mut ChannelTable::default(), 0.0);
            s.handle_write(report(20, 0), 0.0);
            s.handle_stop(0.1, 0.0);
            s.handle_stop(5.0, 0.0);
            let mut t = 0.0;
            let mut served = Vec::new();
            let end = loop {
                t += 0.01;
                let p = s.poll_period(&x, t);
                if let Some(end) = p.stopped {
                    break (end, t);
                }
                let v = s.update().exposed_um[0].1;
                served.push(v);
                // The controller applies what is served, or keeps its 2 µm.
                let held = if reports_zero {
                    (v * 10.0).round() as i16
                } else {
                    20
                };
                s.handle_write(report(held, 0), t);
            };
            assert_eq!(end.0, want, "{served:?}");
            assert_eq!(served[0], 1.0, "one cap (1 µm) toward 0 from the held 2 µm");
            if want == StopEnd::Deadline {
                assert!(
                    end.1 >= 0.1 && end.1 < 0.12,
                    "the first stop's deadline: {end:?}"
                );
            }
        }
    }
}
