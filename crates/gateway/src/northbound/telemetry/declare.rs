//! The metric set a box declares in its NBIRTH, known before the first cycle: every metric the box
//! can publish for its field config and model (each axis, channel, model term and the sink), so a
//! session has one NBIRTH however the channels, terms and sink show up in the first snapshots. A
//! metric outside the declaration (a model switch adding a term) is appended at the next birth:
//! one rebirth.
//!
//! Units (`engUnit`, from the name's suffix as everywhere in the box): corrections µm (correction =
//! −error; `applied_um` has the axis clamp ±`max_correction_um` as `engLow`/`engHigh`), positions
//! mm, the gateway clock s, a channel's value in its name's unit with the configured `min`/`max`
//! as its range; counters in what they count (`cycles`, `faults`, `writes`).
//!
//! The text states are enumerations with the spellings `/status` uses: [`HEALTH_STATES`],
//! [`MODE_STATES`]; `Sink/kind` is `origin_shift`, `origin_shift_server` or `quadrature`.

use super::sparkplug::{DataType, MetricSpec, NamedValue};

/// `Channel/<name>/health`: a channel's health (`retrocomp_bus::Health`, snake_case).
pub const HEALTH_STATES: [&str; 4] = ["ok", "stale", "out_of_range", "decode_error"];
/// `Axis/<axis>/mode`: the safety mode (`status::Mode`, snake_case).
pub const MODE_STATES: [&str; 4] = ["tracking", "ramping_in", "holding", "ramping_out"];

/// One compensated axis and its clamp.
#[derive(Clone, Debug, PartialEq)]
pub struct DeclaredAxis {
    /// `x`, `y` or `z`.
    pub name: String,
    /// The axis' `max_correction_um` (its override or `[safety]`), µm.
    pub clamp_um: f64,
}

/// One channel and its configured physical range (channel units); None: a channel only a source
/// or a recovery names, with no `[[channel]]` limits.
#[derive(Clone, Debug, PartialEq)]
pub struct DeclaredChannel {
    pub name: String,
    pub range: Option<(f64, f64)>,
}

/// What the field config and the model say the box can publish. Empty (`Default`): nothing
/// declared, every metric announced as it first appears.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Declaration {
    pub axes: Vec<DeclaredAxis>,
    pub channels: Vec<DeclaredChannel>,
    /// The model's terms (each axis may carry each).
    pub terms: Vec<String>,
    /// A sink is configured (`Sink/*` will appear).
    pub sink: bool,
}

impl Declaration {
    /// The NBIRTH table: names in the order `super::metrics::snapshot_metrics` produces them,
    /// with datatype, unit and range.
    pub fn specs(&self) -> Vec<MetricSpec> {
        use DataType::{Boolean, Double, String as Text, UInt32, UInt64};
        let mut out = vec![
            spec("Gateway/cycles", UInt64),
            spec("Gateway/t_s", Double),
            spec("Gateway/enabled", Boolean),
            spec("Gateway/active_faults", UInt32),
            spec("Gateway/faults", Text),
            spec("Gateway/model_error", Text),
            spec("Model/identity", Text),
        ];
        let mut terms = self.terms.clone();
        terms.sort();
        terms.dedup();
        for a in &self.axes {
            let p = format!("Axis/{}", a.name);
            out.push(spec(&format!("{p}/applied_um"), Double).range(-a.clamp_um, a.clamp_um));
            out.push(spec(&format!("{p}/target_um"), Double));
            out.push(spec(&format!("{p}/position_mm"), Double));
            out.push(spec(&format!("{p}/mode"), Text));
            for t in &terms {
                out.push(spec(&format!("{p}/term/{t}_um"), Double));
            }
        }
        let mut channels = self.channels.clone();
        channels.sort_by(|a, b| a.name.cmp(&b.name));
        channels.dedup_by(|a, b| a.name == b.name);
        for c in &channels {
            let mut v = spec(&format!("Channel/{}/value", c.name), Double);
            if let Some((lo, hi)) = c.range {
                v = v.range(lo, hi);
            }
            out.push(v);
            out.push(spec(&format!("Channel/{}/health", c.name), Text));
        }
        if self.sink {
            out.push(spec("Sink/kind", Text));
            out.push(spec("Sink/connected", Boolean));
            out.push(spec("Sink/writes_ok", UInt64));
            out.push(spec("Sink/writes_failed", UInt64));
        }
        out
    }
}

/// The NBIRTH table for what is known now: the declaration, then every metric with a value that
/// it does not name (declared by its value's type and its name's unit).
pub(crate) fn birth_table(declared: &[MetricSpec], current: &[NamedValue]) -> Vec<MetricSpec> {
    let mut table = declared.to_vec();
    for (n, v) in current {
        if !table.iter().any(|m| m.name == *n) {
            table.push(spec(n, v.datatype()));
        }
    }
    table
}

/// A metric's spec from its name: the unit its name says (numbers only).
fn spec(name: &str, datatype: DataType) -> MetricSpec {
    let numeric = !matches!(datatype, DataType::Boolean | DataType::String);
    match unit_of(name).filter(|_| numeric) {
        Some(u) => MetricSpec::numeric(name, datatype, u),
        None => MetricSpec::plain(name, datatype),
    }
}

/// The engineering unit of a numeric metric, from its name.
pub(crate) fn unit_of(name: &str) -> Option<&str> {
    match name {
        "Gateway/cycles" => return Some("cycles"),
        "Gateway/t_s" => return Some("s"),
        "Gateway/active_faults" => return Some("faults"),
        "Sink/writes_ok" | "Sink/writes_failed" => return Some("writes"),
        _ => {}
    }
    let quantity = match name
        .strip_prefix("Channel/")
        .and_then(|c| c.strip_suffix("/value"))
    {
        Some(channel) => channel,
        None => name,
    };
    // The box's unit suffixes (docs/recording-csv.md).
    match quantity.rsplit_once('_')?.1 {
        "um" => Some("µm"),
        "mm" => Some("mm"),
        "s" => Some("s"),
        "C" => Some("°C"),
        "K" => Some("K"),
        "N" => Some("N"),
        "ue" => Some("µm/m"),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::status::Mode;
    use retrocomp_bus::Health;

    fn snake<T: serde::Serialize>(t: &T) -> String {
        serde_json::to_value(t)
            .unwrap()
            .as_str()
            .unwrap()
            .to_string()
    }

    #[test]
    fn the_enumerations_are_the_spellings_of_every_variant() {
        // Exhaustive matches: a new variant does not compile until it is listed here.
        let health = |h: Health| match h {
            Health::Ok | Health::Stale | Health::OutOfRange | Health::DecodeError => snake(&h),
        };
        let all_health = [
            Health::Ok,
            Health::Stale,
            Health::OutOfRange,
            Health::DecodeError,
        ];
        assert_eq!(all_health.map(health), HEALTH_STATES.map(String::from));
        let mode = |m: Mode| match m {
            Mode::Tracking | Mode::RampingIn | Mode::Holding | Mode::RampingOut => snake(&m),
        };
        let all_modes = [
            Mode::Tracking,
            Mode::RampingIn,
            Mode::Holding,
            Mode::RampingOut,
        ];
        assert_eq!(all_modes.map(mode), MODE_STATES.map(String::from));
    }

    #[test]
    fn units_and_ranges_follow_names_and_the_config() {
        let d = Declaration {
            axes: vec![DeclaredAxis {
                name: "x".into(),
                clamp_um: 40.0,
            }],
            channels: vec![
                DeclaredChannel {
                    name: "T_spindle_C".into(),
                    range: Some((-10.0, 80.0)),
                },
                DeclaredChannel {
                    name: "rpm".into(),
                    range: None,
                },
            ],
            terms: vec!["thermal_spindle".into()],
            sink: true,
        };
        let specs = d.specs();
        let get = |n: &str| specs.iter().find(|m| m.name == n).unwrap();
        let applied = get("Axis/x/applied_um");
        assert_eq!(applied.unit.as_deref(), Some("µm"));
        assert_eq!((applied.low, applied.high), (Some(-40.0), Some(40.0)));
        assert_eq!(
            get("Axis/x/term/thermal_spindle_um").unit.as_deref(),
            Some("µm")
        );
        assert_eq!(get("Axis/x/position_mm").unit.as_deref(), Some("mm"));
        let t = get("Channel/T_spindle_C/value");
        assert_eq!((t.unit.as_deref(), t.high), (Some("°C"), Some(80.0)));
        assert_eq!(get("Channel/rpm/value").unit, None, "no suffix, no unit");
        assert_eq!(get("Sink/writes_ok").unit.as_deref(), Some("writes"));
        assert_eq!(get("Axis/x/mode").unit, None, "text has no unit");
        assert_eq!(specs.len(), 7 + 5 + 4 + 4);
        // An undeclared metric is appended, by its value's type and its name's unit.
        let table = birth_table(
            &specs,
            &[(
                "Axis/x/term/load_um".into(),
                super::super::sparkplug::Value::Double(1.0),
            )],
        );
        assert_eq!(table.len(), specs.len() + 1);
        assert_eq!(table.last().unwrap().unit.as_deref(), Some("µm"));
    }
}
