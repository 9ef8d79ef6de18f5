//! The faults of a DNC transfer and what `/status` and `/metrics` show of it: each fault starts
//! and clears once in the log (`retrocomp_bus::fault::FaultLog`, as every gateway sink's), and the
//! status snapshot is the engine's (channels, their faults, the targets at the last block) with
//! the transfer as its sink (`kind = "dnc"`: blocks sent, the correction the control holds, the
//! transfer's faults), served by the gateway's own HTTP endpoint (`northbound/http.rs`).
//!
//! Fault sources and kinds:
//! - `sink.dnc` `disconnected`: a stall (held by XOFF/CTS longer than `stall_timeout_s`);
//! - `sink.dnc.model` `decode`: blocks sent with the held correction (an input the engine refused,
//!   a model failure: the engine's own channel fault says which);
//! - `sink.dnc.guard` `write_failed`: the last-step guard refused the wanted correction;
//! - `sink.dnc.line` `out_of_range`: a compensated line longer than the control's
//!   `max_line_chars` was refused (the transfer stops there);
//! - `sink.dnc.inputs` `stale`: the model's inputs did not arrive within `start_timeout_s`, so the
//!   transfer was refused before its first byte.
//!
//! Units: corrections µm (= −error), time s on the sources' clock.

use std::collections::BTreeMap;
use std::sync::Arc;

use retrocomp_bus::fault::{FaultKind, FaultLog, FaultSource};
use retrocomp_gateway::sinks::SinkStatus;
use retrocomp_gateway::status::StatusSnapshot;
use retrocomp_model::Axis;
use tokio::sync::watch;

use super::core::StallEdge;
use super::live::LiveCorrections;
use super::shell::DncSummary;

/// Where the snapshots go (the HTTP endpoint's receiver).
pub type StatusTx = watch::Sender<Option<Arc<StatusSnapshot>>>;

/// A snapshot at most this often while nothing changes, s (every fault edge publishes at once).
const PUBLISH_PERIOD_S: f64 = 0.2;

/// The transfer's fault state, its log and its status publisher.
#[derive(Debug)]
pub(crate) struct DncFaults {
    log: FaultLog,
    sources: [FaultSource; 5],
    active: [bool; 5],
    status: Option<StatusTx>,
    last_publish_s: f64,
}

const KINDS: [FaultKind; 5] = [
    FaultKind::Disconnected,
    FaultKind::Decode,
    FaultKind::WriteFailed,
    FaultKind::OutOfRange,
    FaultKind::Stale,
];
const STALL: usize = 0;
const MODEL: usize = 1;
const GUARD: usize = 2;
const LINE: usize = 3;
const INPUTS: usize = 4;

impl DncFaults {
    pub(crate) fn new(status: Option<StatusTx>) -> Self {
        Self {
            log: FaultLog::default(),
            sources: [
                "sink.dnc",
                "sink.dnc.model",
                "sink.dnc.guard",
                "sink.dnc.line",
                "sink.dnc.inputs",
            ]
            .map(FaultSource::named),
            active: [false; 5],
            status,
            last_publish_s: f64::NEG_INFINITY,
        }
    }

    /// Set fault `k` as it is now; a change is logged and published.
    fn set(&mut self, k: usize, on: bool, now_s: f64) {
        if self.active[k] == on {
            return;
        }
        self.active[k] = on;
        let kinds: &[FaultKind] = if on { &KINDS[k..=k] } else { &[] };
        self.log.update(&self.sources[k], kinds, now_s);
        self.last_publish_s = f64::NEG_INFINITY;
    }

    /// A stall's edge: counted, said with the block that waits, and its fault set.
    pub(crate) fn stall(&mut self, edge: Option<StallEdge>, sum: &mut DncSummary, now_s: f64) {
        match edge {
            Some(StallEdge::Started { since_s, line }) => {
                sum.stalls += 1;
                tracing::warn!(
                    "dnc: the controller has held the transfer since {since_s:.1} s (no XON / CTS); block of line {line} waits, not lost"
                );
                self.set(STALL, true, now_s);
            }
            Some(StallEdge::Cleared { after_s }) => {
                tracing::info!("dnc: the controller resumed at {after_s:.1} s");
                self.set(STALL, false, now_s);
            }
            None => {}
        }
    }

    /// A block left the box: whether it carried the live correction, and the guard's verdict.
    pub(crate) fn block(
        &mut self,
        live: &LiveCorrections,
        sum: &mut DncSummary,
        line: u64,
        now_s: f64,
    ) {
        let refused = live.guard_refused();
        if refused {
            sum.guard_limited += 1;
        }
        self.set(GUARD, refused, now_s);
        match (live.model_fault(), self.active[MODEL]) {
            (Some(why), false) => {
                sum.model_faults += 1;
                tracing::warn!("dnc: line {line} sent with the held correction: {why}");
                self.set(MODEL, true, now_s);
            }
            (None, true) => {
                tracing::info!("dnc: line {line} carries the live correction again");
                self.set(MODEL, false, now_s);
            }
            _ => {}
        }
    }

    /// A compensated line was too long for the control: refused, the transfer stops.
    pub(crate) fn line_refused(&mut self, now_s: f64) {
        self.set(LINE, true, now_s);
    }

    /// The model's inputs never became ready at the start: refused, nothing was sent.
    pub(crate) fn inputs_refused(&mut self, now_s: f64) {
        self.set(INPUTS, true, now_s);
    }

    /// Publish a snapshot when a fault changed or the period passed (no endpoint: nothing).
    pub(crate) fn publish(&mut self, live: &LiveCorrections, sum: &DncSummary, now_s: f64) {
        let Some(tx) = &self.status else { return };
        if now_s - self.last_publish_s < PUBLISH_PERIOD_S {
            return;
        }
        self.last_publish_s = now_s;
        let mut s = live.snapshot().unwrap_or_default();
        s.t_s = now_s;
        let faults = self.log.active_by_name();
        s.active_faults.extend(faults.iter().cloned());
        let held = live.held_um();
        let held_um: BTreeMap<String, f64> = s
            .axes
            .iter()
            .filter_map(|a| Some((a.axis.clone(), held[Axis::from_name(&a.axis)?.index()])))
            .collect();
        s.sink = Some(SinkStatus {
            kind: "dnc".into(),
            connected: !self.active[STALL],
            writes_ok: sum.blocks_sent,
            writes_failed: sum.guard_limited,
            last_error: live.model_fault(),
            held_um,
            faults,
        });
        tx.send_replace(Some(Arc::new(s)));
    }
}
