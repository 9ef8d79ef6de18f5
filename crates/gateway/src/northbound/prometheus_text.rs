//! The Prometheus text format's building blocks for `/metrics` (`crate::status`): label escaping,
//! numbers, metric family headers, the cycle-time histogram, and which base-unit metric a channel
//! goes to. Units: a channel's value is divided by its quantity's channel-units-per-base-unit
//! (µm and mm to m, µm/m to a ratio, rpm to Hz); temperatures stay °C, forces N.

use std::fmt::Write as _;

use crate::status::{CYCLE_BUCKETS_S, CycleTiming};

/// µm per m: values are divided by it (a division is exact where the decimal value is, e.g.
/// −12.5 µm → −1.25e-5 m; a product with 1e-6 is not).
pub(super) const UM_PER_M: f64 = 1e6;

pub(super) fn esc(label: &str) -> String {
    label
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

pub(super) fn num(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 {
            "+Inf".into()
        } else {
            "-Inf".into()
        }
    } else {
        format!("{v}")
    }
}

/// `# HELP` and `# TYPE` lines opening a metric family.
pub(super) fn family(s: &mut String, name: &str, kind: &str, help: &str) {
    let _ = writeln!(s, "# HELP {name} {help}\n# TYPE {name} {kind}");
}

/// `retrocomp_cycle_duration_seconds` (histogram of the engine's compute time per cycle) and
/// `retrocomp_cycles_late_total`.
pub(super) fn prometheus_timing(s: &mut String, t: &CycleTiming) {
    family(
        s,
        "retrocomp_cycle_duration_seconds",
        "histogram",
        "Engine compute time per cycle, s.",
    );
    let mut cumulative = 0;
    for (bound, n) in CYCLE_BUCKETS_S.iter().zip(&t.compute_buckets) {
        cumulative += n;
        let _ = writeln!(
            s,
            "retrocomp_cycle_duration_seconds_bucket{{le=\"{bound:e}\"}} {cumulative}"
        );
    }
    let count = t.cycles();
    let _ = writeln!(
        s,
        "retrocomp_cycle_duration_seconds_bucket{{le=\"+Inf\"}} {count}"
    );
    let _ = writeln!(
        s,
        "retrocomp_cycle_duration_seconds_sum {}",
        num(t.compute_sum_s)
    );
    let _ = writeln!(s, "retrocomp_cycle_duration_seconds_count {count}");
    family(
        s,
        "retrocomp_cycles_late_total",
        "counter",
        "Cycles that started more than one period after they were due.",
    );
    let _ = writeln!(s, "retrocomp_cycles_late_total {}", t.late_cycles);
}

/// What a channel measures, from its name's unit suffix (`T_<s>_C`, `F_<f>_N`, `<a>_mm`,
/// `strain_<g>_ue`, `rpm`): one Prometheus metric per quantity, in base units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum ChannelQuantity {
    Temperature,
    Force,
    Position,
    Displacement,
    Strain,
    SpindleSpeed,
    Other,
}

impl ChannelQuantity {
    pub(super) const ALL: [Self; 7] = [
        Self::Temperature,
        Self::Force,
        Self::Position,
        Self::Displacement,
        Self::Strain,
        Self::SpindleSpeed,
        Self::Other,
    ];

    pub(super) fn of(name: &str) -> Self {
        if name == "rpm" {
            return Self::SpindleSpeed;
        }
        match name.rsplit_once('_').map(|(_, suffix)| suffix) {
            Some("C") => Self::Temperature,
            Some("N") => Self::Force,
            Some("mm") => Self::Position,
            Some("um") => Self::Displacement,
            Some("ue") => Self::Strain,
            _ => Self::Other,
        }
    }

    /// (metric, help, channel units per base unit: the value is divided by it).
    pub(super) fn metric(self) -> (&'static str, &'static str, f64) {
        match self {
            Self::Temperature => (
                "retrocomp_channel_temperature_celsius",
                "Last good (or substituted) temperature per channel, degrees Celsius.",
                1.0,
            ),
            Self::Force => (
                "retrocomp_channel_force_newtons",
                "Last good (or substituted) force per channel, N.",
                1.0,
            ),
            Self::Position => (
                "retrocomp_channel_position_meters",
                "Last good axis position per channel, m.",
                1e3,
            ),
            Self::Displacement => (
                "retrocomp_channel_displacement_meters",
                "Last good displacement per channel, m.",
                UM_PER_M,
            ),
            Self::Strain => (
                "retrocomp_channel_strain_ratio",
                "Last good strain per channel, as a ratio (1 = 1 m/m).",
                1e6,
            ),
            Self::SpindleSpeed => (
                "retrocomp_channel_rotation_hertz",
                "Last good spindle speed, revolutions per second.",
                60.0,
            ),
            Self::Other => (
                "retrocomp_channel_other_value",
                "Last good value of a channel without a known unit suffix, in its own unit.",
                1.0,
            ),
        }
    }
}
