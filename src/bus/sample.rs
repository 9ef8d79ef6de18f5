//! A sample is one decoded value of one channel at one time, with its health.
//!
//! Units are those of the channel (its name carries them: `x_mm`, `T_spindle_C`, `F_cut_N`); time is
//! seconds on the receiver's clock.

/// Health of a channel's latest value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Health {
    Ok,
    /// No fresh value within the channel's timeout (heartbeat lost, poll failed, line silent).
    Stale,
    /// Decoded, but outside the configured physical range, or not finite.
    OutOfRange,
    /// The bytes could not be decoded (wrong length, bad checksum, garbage line, Modbus exception).
    DecodeError,
}

/// One decoded value.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sample {
    /// Channel name as configured, with its unit suffix (`x_mm`, `T_spindle_C`).
    pub channel: String,
    pub t_s: f64,
    pub value: f64,
    pub health: Health,
}
