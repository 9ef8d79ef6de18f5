//! The status snapshot: what the gateway's runtime publishes at ≤ 10 Hz and every consumer reads
//! (`/status` and `/metrics` in `gateway::http`, the live page, OPC UA, the Sparkplug publisher in
//! `telemetry`). Per axis the applied correction, its breakdown by term and the safety mode; every
//! channel's health; the active faults; the sink's, the sources' and the publisher's state.
//!
//! Plain data, below the gateway and `telemetry`: the engine builds it (`gateway::engine`), the
//! Prometheus text form is `gateway::status`, and `telemetry` reads it without importing the
//! gateway (imports go one way: gateway → telemetry → this).
//!
//! Units: µm for corrections (correction = −error), mm for positions, channel units for channel
//! values, s for times on the gateway's clock.

use std::collections::BTreeMap;

use serde::Serialize;

pub use crate::sinks::SinkStatus;
use retrocomp_bus::Health;
use retrocomp_bus::can::BusState;
use retrocomp_bus::fault::FaultKind;
use retrocomp_model::approach::Approach;

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct AxisStatus {
    pub axis: String,
    pub position_mm: Option<f64>,
    /// Latched direction of approach; serialised `unknown` / `forward` / `reverse`.
    #[serde(serialize_with = "retrocomp_model::approach::serialize_latched")]
    pub direction: Option<Approach>,
    pub weight_forward: f64,
    /// Correction the model asks for (before safety), µm; None while inputs are stale/faulty.
    pub target_um: Option<f64>,
    /// Correction actually applied (after clamp, dosing and ramps), µm.
    pub applied_um: f64,
    pub mode: Mode,
    /// Breakdown of the target by model term (corrections, µm).
    pub terms_um: BTreeMap<String, f64>,
    /// Cycles whose model target was beyond the clamp (`max_correction_um`), since start.
    pub clamp_hits: u64,
    /// Cycles whose step was cut by the dosing cap (`max_change_um_per_cycle`), since start.
    pub cap_hits: u64,
}

/// The model in use: its name, the SHA-256 of its canonical TOML (the same model written by any
/// tool gives the same hash) and when the gateway loaded it (Unix time, s).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ModelIdentity {
    pub name: String,
    pub sha256: String,
    pub loaded_unix_s: f64,
    /// Term name → `geometric`, `thermal`, `load` or `other` (the OPC UA space groups terms by it).
    pub term_groups: BTreeMap<String, &'static str>,
}

/// One bus source's link (the CAN backend, a Modbus poller, a serial line): what `/status` shows
/// under `sources` and `/metrics` as `retrocomp_source_*`. `name` is also its fault-log source.
#[derive(Clone, Debug, PartialEq, Serialize, Default)]
pub struct SourceStatus {
    /// `can`, `modbus.<name>` or `serial.<name>`.
    pub name: String,
    pub connected: bool,
    /// Links re-established after a loss.
    pub reconnects: u64,
    /// Active source-level faults (`disconnected`, `bus_off`, `error_passive`, `bus_errors`,
    /// `exception`), each with the time it started, s.
    pub faults: Vec<(FaultKind, f64)>,
    pub last_error: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub can: Option<CanBusStatus>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modbus: Option<ModbusCounters>,
}

/// CAN controller state from error frames (see `bus::can::bus_state`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Default)]
pub struct CanBusStatus {
    pub state: BusState,
    pub error_frames: u64,
    pub bus_off_events: u64,
    pub tx_error_count: Option<u8>,
    pub rx_error_count: Option<u8>,
}

/// A Modbus poller's request outcomes since start.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Default)]
pub struct ModbusCounters {
    pub requests: u64,
    pub exceptions: u64,
    pub timeouts: u64,
    pub transport_errors: u64,
    pub connect_failures: u64,
}

/// `Default` is the empty snapshot (no cycle yet, nothing configured): tests and benches build
/// theirs with `..Default::default()`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StatusSnapshot {
    pub t_s: f64,
    pub cycles: u64,
    pub enabled: bool,
    pub axes: Vec<AxisStatus>,
    pub channels: BTreeMap<String, ChannelStatus>,
    /// (source, fault, since t_s).
    pub active_faults: Vec<(String, FaultKind, f64)>,
    pub model_error: Option<String>,
    pub sink: Option<SinkStatus>,
    /// Bus sources' links (filled by the runtime; empty when the samples come from elsewhere).
    pub sources: Vec<SourceStatus>,
    /// The model in use (filled by the runtime from `ErrorModel::identity`).
    pub model: Option<ModelIdentity>,
    /// The Sparkplug B publisher (`[telemetry.mqtt]`), when configured.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub telemetry: Option<TelemetryStatus>,
    /// How long the engine's cycles take and how many started late (filled by the cycle loop).
    pub timing: CycleTiming,
}

/// Upper bounds (s) of the cycle compute-time histogram's buckets: from the engine's sub-µs
/// steady state to a cycle that took a whole 1 ms period and more.
pub const CYCLE_BUCKETS_S: [f64; 10] = [
    1e-6, 2.5e-6, 5e-6, 1e-5, 2.5e-5, 5e-5, 1e-4, 2.5e-4, 5e-4, 1e-3,
];

/// The cycle loop's timing since start: a fixed-bucket histogram of the engine's compute time per
/// cycle (no allocation per cycle) and the cycles that started more than one period late.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct CycleTiming {
    /// Cycles per bucket of [`CYCLE_BUCKETS_S`] (not cumulative; the last slot is above the last
    /// bound).
    pub compute_buckets: [u64; CYCLE_BUCKETS_S.len() + 1],
    /// Sum of every cycle's compute time, s.
    pub compute_sum_s: f64,
    /// Cycles that started more than one period after they were due.
    pub late_cycles: u64,
}

impl CycleTiming {
    /// Count one cycle that computed for `took_s` seconds.
    pub fn observe(&mut self, took_s: f64) {
        let k = CYCLE_BUCKETS_S
            .iter()
            .position(|&b| took_s <= b)
            .unwrap_or(CYCLE_BUCKETS_S.len());
        self.compute_buckets[k] += 1;
        self.compute_sum_s += took_s;
    }

    /// Cycles counted by [`Self::observe`].
    pub fn cycles(&self) -> u64 {
        self.compute_buckets.iter().sum()
    }
}

/// Health of one channel now.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChannelStatus {
    /// Last good value (what the model may use), channel units.
    pub value: Option<f64>,
    pub health: Health,
    /// The active faults (empty when healthy).
    pub faults: Vec<FaultKind>,
    /// True when `value` is an estimate from correlated neighbours (see `recovery`).
    pub substituted: bool,
    /// Gateway clock (s, as `t_s`) of the reading `value` comes from; None without a reading or
    /// for a substituted value. The reading's age is the snapshot's `t_s` minus this.
    pub reading_t_s: Option<f64>,
}

impl ChannelStatus {
    /// No value yet, stale.
    pub fn unknown() -> Self {
        ChannelStatus {
            value: None,
            health: Health::Stale,
            faults: Vec::new(),
            substituted: false,
            reading_t_s: None,
        }
    }
}

/// The safety mode of one axis (`gateway::safety`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// Following the target within the dosing cap.
    Tracking,
    /// Ramping towards the target after start, enable, or a recovered fault/stale input.
    RampingIn,
    /// Inputs stale: holding the last output.
    Holding,
    /// Ramping to zero (disabled, fault, or stale beyond the hold time).
    RampingOut,
}

/// The publisher's state, for `/status` and `/metrics` (`retrocomp_telemetry_*`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TelemetryStatus {
    /// Connected and born (NBIRTH sent): data flows.
    pub connected: bool,
    pub bd_seq: u8,
    /// Records waiting in the store-and-forward queue (including those in flight).
    pub queued: u64,
    pub queued_bytes: u64,
    /// Records dropped because the queue or the hand-over channel was full, since start.
    pub dropped_total: u64,
    /// Records taken into the queue, since start.
    pub records_total: u64,
    /// Records the broker acknowledged, since start.
    pub acked_total: u64,
    /// NBIRTHs sent (connects and rebirths), since start.
    pub births_total: u64,
    pub last_error: Option<String>,
}
