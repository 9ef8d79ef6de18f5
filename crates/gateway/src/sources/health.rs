//! Source links as faults: each bus source (the CAN backend, a Modbus poller, a serial line) owns a
//! [`SourceReporter`] that turns what its shell saw (link lost/back, CAN error frames, Modbus
//! exceptions) into [`SourceStatus`] and source-level faults. Each fault is logged once when it
//! starts and once when it clears ([`FaultLog`]); the status goes on a shared [`SourceBoard`] that the
//! runtime copies into every status snapshot (`/status` `sources`, `/metrics` `retrocomp_source_*`).
//!
//! Sans-IO: time is passed in (seconds on the gateway's clock); nothing here sleeps or reads a clock.
//! The fault-log source of a link is its status name: `can`, `modbus.<name>`, `serial.<name>`.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use crate::engine::health::{BUS_ERROR_HOLD_S, FaultEvent, FaultKind, FaultLog};
use crate::status::{CanBusStatus, ModbusCounters, SourceStatus};
use retrocomp_bus::can::{BusErrors, BusState};
use retrocomp_bus::fault::FaultSource;
use retrocomp_bus::modbus::PollCounters;

/// Every source's latest status, shared between the source tasks (writers) and the cycle (reader).
#[derive(Clone, Debug, Default)]
pub struct SourceBoard(Arc<Mutex<BTreeMap<String, SourceStatus>>>);

impl SourceBoard {
    fn put(&self, st: &SourceStatus) {
        // A poisoned lock means a source task panicked while writing: the panic itself ends the
        // process (see `supervise`); the status is still usable.
        let mut m = self.0.lock().unwrap_or_else(|p| p.into_inner());
        match m.get_mut(&st.name) {
            Some(old) => old.clone_from(st),
            None => {
                m.insert(st.name.clone(), st.clone());
            }
        }
    }

    /// All sources, by name.
    pub fn snapshot(&self) -> Vec<SourceStatus> {
        let m = self.0.lock().unwrap_or_else(|p| p.into_inner());
        m.values().cloned().collect()
    }

    /// Copy into `dst`, reusing its buffers when the set of sources is unchanged.
    pub fn copy_into(&self, dst: &mut Vec<SourceStatus>) {
        let m = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if dst.len() != m.len() {
            dst.clear();
            dst.extend(m.values().cloned());
            return;
        }
        for (d, s) in dst.iter_mut().zip(m.values()) {
            d.clone_from(s);
        }
    }
}

/// One source's link state and faults. Call the `handle_*` methods as things happen, then
/// [`SourceReporter::publish`]: it logs fault transitions and updates the board when anything changed.
#[derive(Debug)]
pub(crate) struct SourceReporter {
    status: SourceStatus,
    published: Option<SourceStatus>,
    /// `status.name` as the fault log's source (built once).
    source: FaultSource,
    log: FaultLog,
    board: SourceBoard,
    /// Error-frame count at the last check and when it last grew (gateway clock, s).
    error_frames_seen: u64,
    last_error_frame_s: Option<f64>,
    /// The last Modbus poll got at least one exception reply.
    exception_now: bool,
    /// The link was up at least once (the first connection is not a reconnect).
    ever_connected: bool,
}

impl SourceReporter {
    /// A source whose link is up (`connected`) or not yet (a Modbus peer that is down at start).
    pub(crate) fn new(name: &str, connected: bool, board: SourceBoard) -> Self {
        SourceReporter {
            status: SourceStatus {
                name: name.to_string(),
                connected,
                ..Default::default()
            },
            published: None,
            source: FaultSource::named(name),
            log: FaultLog::default(),
            board,
            error_frames_seen: 0,
            last_error_frame_s: None,
            exception_now: false,
            ever_connected: connected,
        }
    }

    pub(crate) fn name(&self) -> &str {
        &self.status.name
    }

    pub(crate) fn is_connected(&self) -> bool {
        self.status.connected
    }

    /// The link failed (closed, I/O error, open failed). `why` is kept as `last_error`.
    pub(crate) fn handle_link_down(&mut self, why: &str) {
        self.status.connected = false;
        if self.status.last_error.as_deref() != Some(why) {
            self.status.last_error = Some(why.to_string());
        }
    }

    /// The link works again (data arrived after a reopen).
    pub(crate) fn handle_link_up(&mut self) {
        if !self.status.connected {
            self.status.connected = true;
            if self.ever_connected {
                self.status.reconnects += 1;
            }
            self.ever_connected = true;
        }
    }

    /// The CAN backend's error-frame state. A new backend (after a reopen) starts its counters at
    /// zero; the totals shown keep counting across reopens.
    pub(crate) fn handle_can_bus(&mut self, now: BusErrors, base: &BusErrors, now_s: f64) {
        let frames = base.error_frames + now.error_frames;
        if frames > self.error_frames_seen {
            self.error_frames_seen = frames;
            self.last_error_frame_s = Some(now_s);
        }
        self.status.can = Some(CanBusStatus {
            state: now.state(),
            error_frames: frames,
            bus_off_events: base.bus_off_events + now.bus_off_events,
            tx_error_count: now.tx_error_count,
            rx_error_count: now.rx_error_count,
        });
    }

    /// A Modbus poll finished: `before` and `after` are the poller's counters around it.
    pub(crate) fn handle_modbus_poll(
        &mut self,
        before: &PollCounters,
        after: &PollCounters,
        connected: bool,
    ) {
        self.exception_now = after.exceptions > before.exceptions;
        self.status.modbus = Some(ModbusCounters {
            requests: after.requests,
            exceptions: after.exceptions,
            timeouts: after.timeouts,
            transport_errors: after.transport_errors,
            connect_failures: after.connect_failures,
        });
        if connected {
            self.handle_link_up();
        } else if after.timeouts > before.timeouts {
            self.handle_link_down("request timed out");
        } else if after.transport_errors > before.transport_errors {
            self.handle_link_down("transport error");
        } else if after.connect_failures > before.connect_failures {
            self.handle_link_down("connect failed");
        } else {
            self.status.connected = false;
        }
        if self.exception_now {
            self.status.last_error = Some("exception reply".into());
        }
    }

    fn faults(&self, now_s: f64) -> Vec<FaultKind> {
        let mut f = Vec::new();
        if !self.status.connected {
            f.push(FaultKind::Disconnected);
        }
        if let Some(c) = &self.status.can {
            match c.state {
                BusState::BusOff => f.push(FaultKind::BusOff),
                BusState::Passive => f.push(FaultKind::ErrorPassive),
                BusState::Active | BusState::Warning => {}
            }
        }
        if self
            .last_error_frame_s
            .is_some_and(|t| now_s < t + BUS_ERROR_HOLD_S)
        {
            f.push(FaultKind::BusErrors);
        }
        if self.exception_now {
            f.push(FaultKind::Exception);
        }
        f
    }

    /// When [`Self::publish`] next has a change to report without new input (s, the gateway
    /// clock): the `bus_errors` fault clearing [`BUS_ERROR_HOLD_S`] after the last error frame.
    pub(crate) fn poll_timeout(&self) -> Option<f64> {
        let t = self.last_error_frame_s?;
        let holding = self
            .status
            .faults
            .iter()
            .any(|(k, _)| *k == FaultKind::BusErrors);
        holding.then_some(t + BUS_ERROR_HOLD_S)
    }

    /// Log fault transitions (once at start, once at clear) and update the board if anything changed.
    pub(crate) fn publish(&mut self, now_s: f64) -> Vec<FaultEvent> {
        let faults = self.faults(now_s);
        let same = faults.len() == self.status.faults.len()
            && faults
                .iter()
                .zip(&self.status.faults)
                .all(|(a, (b, _))| a == b);
        let events = if same {
            Vec::new()
        } else {
            let ev = self.log.update(&self.source, &faults, now_s);
            self.status.faults = self.log.active().map(|(_, k, t)| (k, t)).collect();
            ev
        };
        if self.published.as_ref() != Some(&self.status) {
            self.board.put(&self.status);
            match &mut self.published {
                Some(p) => p.clone_from(&self.status),
                None => self.published = Some(self.status.clone()),
            }
        }
        events
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_bus::can::{CAN_ERR_BUSOFF, ErrorFrame};

    fn starts(ev: &[FaultEvent]) -> Vec<(FaultKind, bool)> {
        ev.iter().map(|e| (e.kind, e.started)).collect()
    }

    #[test]
    fn a_lost_link_is_one_episode_and_counts_one_reconnect() {
        let board = SourceBoard::default();
        let mut r = SourceReporter::new("can", true, board.clone());
        assert!(r.publish(0.0).is_empty());
        let mut events = Vec::new();
        for k in 0..50 {
            r.handle_link_down("CAN bus closed");
            events.extend(r.publish(1.0 + f64::from(k) * 0.1));
        }
        assert_eq!(starts(&events), [(FaultKind::Disconnected, true)]);
        assert!(!board.snapshot()[0].connected);
        r.handle_link_up();
        assert_eq!(starts(&r.publish(7.0)), [(FaultKind::Disconnected, false)]);
        let st = &board.snapshot()[0];
        assert_eq!((st.connected, st.reconnects), (true, 1));
        assert_eq!(st.last_error.as_deref(), Some("CAN bus closed"));
    }

    #[test]
    fn bus_off_and_error_frames_become_faults_and_totals_survive_a_reopen() {
        let board = SourceBoard::default();
        let mut r = SourceReporter::new("can", true, board.clone());
        let mut b = BusErrors::default();
        b.handle_error_frame(&ErrorFrame::class_only(CAN_ERR_BUSOFF));
        r.handle_can_bus(b, &BusErrors::default(), 1.0);
        let ev = starts(&r.publish(1.0));
        assert!(ev.contains(&(FaultKind::BusOff, true)), "{ev:?}");
        assert!(ev.contains(&(FaultKind::BusErrors, true)), "{ev:?}");
        // The controller rejoins; a reopened backend starts from zero, the totals do not.
        let base = b;
        let fresh = BusErrors::default();
        r.handle_can_bus(fresh, &base, 1.5);
        assert_eq!(starts(&r.publish(1.5)), [(FaultKind::BusOff, false)]);
        // The shell sleeps until the hold ends: that is when the fault clears, not a tick later.
        let due = r.poll_timeout().expect("bus_errors clears with time");
        assert_eq!(due, 1.0 + BUS_ERROR_HOLD_S);
        assert!(r.publish(due - 1e-9).is_empty());
        assert_eq!(starts(&r.publish(due)), [(FaultKind::BusErrors, false)]);
        assert_eq!(r.poll_timeout(), None, "nothing left to clear");
        let can = board.snapshot()[0].can.unwrap();
        assert_eq!((can.error_frames, can.bus_off_events), (1, 1));
    }

    #[test]
    fn modbus_exceptions_are_an_episode_while_they_last() {
        let mut r = SourceReporter::new("modbus.pt100", false, SourceBoard::default());
        let mut c = PollCounters::default();
        let mut events = Vec::new();
        for k in 0..20u64 {
            let before = c;
            c.requests += 1;
            if (5..15).contains(&k) {
                c.exceptions += 1;
            }
            r.handle_modbus_poll(&before, &c, true);
            events.extend(r.publish(k as f64));
        }
        assert_eq!(
            starts(&events),
            [(FaultKind::Exception, true), (FaultKind::Exception, false)]
        );
        assert_eq!(
            r.status.reconnects, 0,
            "the first connection is not a reconnect"
        );
    }
}
