//! The `[dnc]` section of the field config: the serial link to the controller's DNC input (baud,
//! parity, data and stop bits, flow control, line end, the control's line length and buffer,
//! leader/trailer) and how the program is read (dialect, diameter X). Checked at start: a setting
//! that cannot be safe or does not fit the link is refused with its key (the caller places it at
//! file:line:key like every other key of the field file).
//!
//! Units: seconds (`_s`), characters, lines, µm (`_um`).

use retrocomp_bus::modbus::Parity;
use serde::{Deserialize, Serialize};

/// How the controller says "stop" and "go".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Flow {
    /// DC3 (XOFF, 0x13) stop / DC1 (XON, 0x11) go, read by the box from the controller's TX line.
    XonXoff,
    /// The controller drops CTS to stop (RTS/CTS handshake by the serial driver).
    RtsCts,
}

/// End of a line as the control expects it (ISO: LF; most RS-232 DNC: CR LF; some: CR).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LineEnd {
    CrLf,
    Lf,
    Cr,
}

impl LineEnd {
    pub fn bytes(self) -> &'static [u8] {
        match self {
            LineEnd::CrLf => b"\r\n",
            LineEnd::Lf => b"\n",
            LineEnd::Cr => b"\r",
        }
    }
}

fn d_baud() -> u32 {
    9600
}
fn d_data_bits() -> u8 {
    8
}
fn d_stop_bits() -> u8 {
    1
}
fn d_line_end() -> LineEnd {
    LineEnd::CrLf
}
fn d_buffer_lines() -> usize {
    5
}
fn d_stall_timeout_s() -> f64 {
    30.0
}
fn d_start_timeout_s() -> f64 {
    30.0
}
fn d_rapid_mm_min() -> f64 {
    5000.0
}
fn d_control_speed() -> f64 {
    1.0
}
fn d_drift_window_s() -> f64 {
    60.0
}
fn d_predict_max_s() -> f64 {
    30.0
}

/// `[dnc]` of the field TOML.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DncSection {
    /// The controller's DNC port (`--port` overrides).
    #[serde(default)]
    pub port: Option<String>,
    #[serde(default = "d_baud")]
    pub baud: u32,
    #[serde(default)]
    pub parity: Parity,
    /// 7 (ISO/EIA tape code, usually with even parity) or 8.
    #[serde(default = "d_data_bits")]
    pub data_bits: u8,
    #[serde(default = "d_stop_bits")]
    pub stop_bits: u8,
    pub flow: Flow,
    #[serde(default = "d_line_end")]
    pub line_end: LineEnd,
    /// Longest line the control accepts, characters without the line end. A compensated block
    /// longer than this is refused (a fault, the transfer stops), never truncated.
    pub max_line_chars: usize,
    /// Lines the control buffers (Spaan: ≤ 5): how many blocks a correction can lag its execution.
    #[serde(default = "d_buffer_lines")]
    pub buffer_lines: usize,
    /// Hold the next block while this many sent lines are estimated to wait in the control's
    /// buffer (1 … buffer_lines; default buffer_lines: never hold, XON/XOFF alone paces): a
    /// block's correction is then taken at most ≈ this many lines before it runs.
    #[serde(default)]
    pub lead_blocks: Option<usize>,
    /// The control's G0 feed, mm/min (for the estimate behind `lead_blocks`).
    #[serde(default = "d_rapid_mm_min")]
    pub rapid_mm_min: f64,
    /// How many times faster than programmed the control runs (feed override 120 % → 1.2; a
    /// simulator paced faster than real time → its speed): the estimate's durations are divided
    /// by it.
    #[serde(default = "d_control_speed")]
    pub control_speed: f64,
    /// Each block carries the correction predicted for when it is estimated to end on the control
    /// (the correction's slope over `drift_window_s`, extrapolated at most `predict_max_s`),
    /// rather than the one at its send time.
    #[serde(default)]
    pub predict_drift: bool,
    /// The past the drift's slope is fitted over, s of the sources' clock.
    #[serde(default = "d_drift_window_s")]
    pub drift_window_s: f64,
    /// The furthest ahead a correction is extrapolated, s (at most `drift_window_s`).
    #[serde(default = "d_predict_max_s")]
    pub predict_max_s: f64,
    /// NUL characters sent before the program (tape leader some controls expect) and after it.
    #[serde(default)]
    pub leader_nuls: usize,
    #[serde(default)]
    pub trailer_nuls: usize,
    /// The controller holding XOFF (or CTS low) longer than this is a stall fault, s.
    #[serde(default = "d_stall_timeout_s")]
    pub stall_timeout_s: f64,
    /// Longest wait at the start for the model's inputs (every required sensor read and judged
    /// usable), s: nothing is sent before, so no block leaves without its correction; past it the
    /// transfer is refused and nothing has been sent.
    #[serde(default = "d_start_timeout_s")]
    pub start_timeout_s: f64,
    /// `;` ends a block (Fanuc EOB) instead of starting a comment (LinuxCNC).
    #[serde(default)]
    pub semicolon_is_eob: bool,
    /// X words are diameters (lathe, cylindrical grinder).
    #[serde(default)]
    pub diameter_x: bool,
    /// Largest change of an axis' correction from one block to the next, µm. Default: the axis'
    /// `safety.max_change_um_per_cycle` (the per-write cap every sink uses).
    #[serde(default)]
    pub max_change_um_per_block: Option<f64>,
    /// A DNC sender (the shop's DNC PC) writing to the box (`--sender-port` overrides; used when
    /// neither `--program` nor `--listen` is given): its serial settings are these too.
    #[serde(default)]
    pub sender_port: Option<String>,
}

impl DncSection {
    /// The checks of a config that cannot be safe or is inconsistent: `(key, what was expected)`.
    pub fn validate(&self, max_correction_um: f64) -> Result<(), (String, String)> {
        let bad = |k: &str, what: &str| Err((format!("dnc.{k}"), what.to_string()));
        const BAUDS: [u32; 12] = [
            110, 300, 600, 1200, 2400, 4800, 9600, 19_200, 38_400, 57_600, 115_200, 230_400,
        ];
        if !BAUDS.contains(&self.baud) {
            return bad("baud", "a standard rate (110 … 230400)");
        }
        if !matches!(self.data_bits, 7 | 8) {
            return bad("data_bits", "7 or 8");
        }
        if self.data_bits == 7 && self.parity == Parity::None {
            return bad(
                "parity",
                "even or odd with 7 data bits (ISO tape code is 7E; 7N would drop the 8th bit the control checks)",
            );
        }
        if !matches!(self.stop_bits, 1 | 2) {
            return bad("stop_bits", "1 or 2");
        }
        // A control whose lines are shorter than a block with one axis word cannot take a
        // compensated block at all.
        if !(16..=256).contains(&self.max_line_chars) {
            return bad("max_line_chars", "16 … 256 characters");
        }
        if !(1..=256).contains(&self.buffer_lines) {
            return bad("buffer_lines", "1 … 256 lines");
        }
        if let Some(n) = self.lead_blocks
            && !(1..=self.buffer_lines).contains(&n)
        {
            return bad("lead_blocks", "1 … dnc.buffer_lines lines");
        }
        if !(self.rapid_mm_min.is_finite() && self.rapid_mm_min > 0.0)
            || self.rapid_mm_min > 100_000.0
        {
            return bad("rapid_mm_min", "finite, > 0 and at most 100000 mm/min");
        }
        if !(self.control_speed.is_finite() && (0.1..=100.0).contains(&self.control_speed)) {
            return bad(
                "control_speed",
                "0.1 … 100 (1 on a machine at 100 % feed override)",
            );
        }
        if !(self.drift_window_s.is_finite() && (1.0..=3600.0).contains(&self.drift_window_s)) {
            return bad("drift_window_s", "1 … 3600 s");
        }
        // Extrapolating further ahead than the past the slope was fitted over is guessing.
        if !(self.predict_max_s.is_finite()
            && (0.0..=self.drift_window_s).contains(&self.predict_max_s))
        {
            return bad("predict_max_s", "0 … dnc.drift_window_s s");
        }
        if self.leader_nuls > 10_000 || self.trailer_nuls > 10_000 {
            return bad("leader_nuls", "at most 10000 NULs of leader and of trailer");
        }
        if !(self.stall_timeout_s.is_finite() && self.stall_timeout_s > 0.0)
            || self.stall_timeout_s > 3600.0
        {
            return bad("stall_timeout_s", "finite, > 0 and at most 3600 s");
        }
        if !(self.start_timeout_s.is_finite() && self.start_timeout_s > 0.0)
            || self.start_timeout_s > 3600.0
        {
            return bad("start_timeout_s", "finite, > 0 and at most 3600 s");
        }
        if let Some(c) = self.max_change_um_per_block
            && !(c.is_finite() && c > 0.0 && c <= max_correction_um)
        {
            return bad(
                "max_change_um_per_block",
                "finite, > 0 and at most safety.max_correction_um",
            );
        }
        if self.sender_port.is_some() && self.sender_port == self.port {
            return bad("sender_port", "a different device than dnc.port");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(extra: &str) -> Result<DncSection, String> {
        let text = format!("flow = \"xon_xoff\"\nmax_line_chars = 64\n{extra}");
        toml::from_str::<DncSection>(&text).map_err(|e| e.to_string())
    }

    #[test]
    fn defaults_are_the_common_rs232_dnc_settings() {
        let s = section("").unwrap();
        assert_eq!((s.baud, s.data_bits, s.stop_bits), (9600, 8, 1));
        assert_eq!(s.line_end, LineEnd::CrLf);
        assert_eq!(s.buffer_lines, 5);
        assert_eq!(s.lead_blocks, None, "no hold unless asked");
        assert!(!s.predict_drift, "no prediction unless asked");
        assert!(s.validate(60.0).is_ok());
    }

    #[test]
    fn unsafe_or_inconsistent_settings_are_refused_with_their_key() {
        let key = |extra: &str| section(extra).unwrap().validate(60.0).unwrap_err().0;
        assert_eq!(key("baud = 9601"), "dnc.baud");
        assert_eq!(key("data_bits = 7"), "dnc.parity");
        assert_eq!(key("stop_bits = 3"), "dnc.stop_bits");
        assert_eq!(key("stall_timeout_s = 0.0"), "dnc.stall_timeout_s");
        assert_eq!(key("start_timeout_s = -1.0"), "dnc.start_timeout_s");
        assert_eq!(key("lead_blocks = 0"), "dnc.lead_blocks");
        assert_eq!(key("buffer_lines = 3\nlead_blocks = 4"), "dnc.lead_blocks");
        assert_eq!(key("rapid_mm_min = -1.0"), "dnc.rapid_mm_min");
        assert_eq!(key("control_speed = 0.0"), "dnc.control_speed");
        assert_eq!(key("drift_window_s = 0.5"), "dnc.drift_window_s");
        assert_eq!(key("drift_window_s = nan"), "dnc.drift_window_s");
        assert_eq!(key("predict_max_s = -1.0"), "dnc.predict_max_s");
        assert_eq!(
            key("drift_window_s = 10.0\npredict_max_s = 11.0"),
            "dnc.predict_max_s"
        );
        assert_eq!(
            key("max_change_um_per_block = 61.0"),
            "dnc.max_change_um_per_block"
        );
        assert_eq!(
            key("port = \"/dev/a\"\nsender_port = \"/dev/a\""),
            "dnc.sender_port"
        );
        let short = toml::from_str::<DncSection>("flow = \"rts_cts\"\nmax_line_chars = 8")
            .unwrap()
            .validate(60.0)
            .unwrap_err();
        assert_eq!(short.0, "dnc.max_line_chars");
        assert!(section("flow_control = 1").is_err(), "unknown keys refused");
    }
}
