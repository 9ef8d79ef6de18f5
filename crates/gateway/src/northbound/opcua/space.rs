//! Sans-IO: what the OPC UA address space shows for a status snapshot. Each [`Point`] is one variable
//! by its path below the box's object (`Monitoring/Axes/X/Correction`); the server shell creates the
//! objects along the path and the variable the first time a path appears, and sets its value after.
//!
//! Layout (`<box>` = `gateway.name`, a `MachineToolType` created by `instance.rs`):
//! `Objects/Machines/<box>/Identification` (product, software, model name and hash),
//! `Monitoring/Compensation` (enabled, cycles, model error), `Monitoring/Axes/<X>` (`Correction` =
//! applied correction µm, `TargetCorrection`, `Position` mm, `Mode`, `Direction`,
//! `Terms/<Geometric|Thermal|Load|Other>/<term>` µm), `Monitoring/Sensors/<channel>` (`Value` in
//! the channel's unit, `Health`, `Healthy`, `Stale`, `Stuck`, `Substituted`), `Monitoring/Sink`
//! (writes ok/failed, last error), `Notification` (active faults).
//! Units: corrections µm (correction = −error), positions mm, sensors by channel-name suffix.
//! Quality: a sensor value's follows its channel's health ([`channel_quality`]); a number the
//! snapshot lacks is `NoData`; everything else is `Good` at the snapshot's time.

use crate::engine::health::{ChannelStatus, FaultKind};
use crate::status::ModelIdentity;
use crate::status::StatusSnapshot;
use retrocomp_bus::Health;

/// An engineering unit: UNECE Rec. 20 code (OPC UA `EUInformation.unitId` is derived from it),
/// symbol and name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Unit {
    pub code: &'static str,
    pub symbol: &'static str,
    pub name: &'static str,
}

pub(crate) const MICROMETRE: Unit = Unit {
    code: "4H",
    symbol: "µm",
    name: "micrometre",
};
pub(crate) const MILLIMETRE: Unit = Unit {
    code: "MMT",
    symbol: "mm",
    name: "millimetre",
};
pub(crate) const CELSIUS: Unit = Unit {
    code: "CEL",
    symbol: "°C",
    name: "degree Celsius",
};
pub(crate) const NEWTON: Unit = Unit {
    code: "NEW",
    symbol: "N",
    name: "newton",
};
pub(crate) const KELVIN: Unit = Unit {
    code: "KEL",
    symbol: "K",
    name: "kelvin",
};
pub(crate) const SECOND: Unit = Unit {
    code: "SEC",
    symbol: "s",
    name: "second",
};

/// OPC UA Part 8 §5.6.3: the unitId of a UNECE code is its (up to 3) ASCII bytes, big-endian.
pub(crate) fn unece_unit_id(code: &str) -> i32 {
    code.bytes().fold(0i32, |acc, b| (acc << 8) | i32::from(b))
}

/// The unit of a channel, from the suffix of its name (docs/recording-csv.md: `_mm`, `_um`, `_C`, `_N`, ...).
/// None for channels without a unit the UNECE list covers (e.g. strain `_ue`).
pub(crate) fn unit_of_channel(name: &str) -> Option<Unit> {
    let (_, suffix) = name.rsplit_once('_')?;
    match suffix {
        "mm" => Some(MILLIMETRE),
        "um" => Some(MICROMETRE),
        "C" => Some(CELSIUS),
        "N" => Some(NEWTON),
        "K" => Some(KELVIN),
        "s" => Some(SECOND),
        _ => None,
    }
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Value {
    /// None → the variable reads with a Bad status (e.g. no target while inputs are stale).
    F64(Option<f64>),
    Bool(bool),
    U64(u64),
    Str(String),
    StrArray(Vec<String>),
}

/// How far a client may trust a value: the variable's StatusCode (OPC UA Part 4 §7.39).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Quality {
    Good,
    /// The channel went stale: the value is its last good reading (`Uncertain_LastUsableValue`).
    LastUsable,
    /// An estimate from correlated channels, not a reading (`Uncertain_SubstituteValue`).
    Substituted,
    /// No value at all (`Bad_NoData`).
    NoData,
    /// The channel's readings are outside its configured range (`Bad_OutOfRange`).
    OutOfRange,
    /// The channel's bytes do not decode, or its device answers with an exception (`Bad_DeviceFailure`).
    DeviceFailure,
}

#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Point {
    /// Below the box's object, `/`-separated; the last part is the variable's browse name.
    pub path: String,
    pub value: Value,
    pub unit: Option<Unit>,
    pub quality: Quality,
    /// Gateway clock (s) of the reading the value comes from (its SourceTimestamp); None: the
    /// snapshot's own time.
    pub source_t_s: Option<f64>,
}

/// Path parts that are collections (FolderType); every other intermediate part is an object.
pub(crate) const FOLDERS: [&str; 7] = [
    "Axes",
    "Sensors",
    "Terms",
    "Geometric",
    "Thermal",
    "Load",
    "Other",
];

/// A point read at the snapshot's time: Good, or Bad_NoData for a number that is absent.
fn p(path: String, value: Value, unit: Option<Unit>) -> Point {
    let quality = match value {
        Value::F64(None) => Quality::NoData,
        _ => Quality::Good,
    };
    Point {
        path,
        value,
        unit,
        quality,
        source_t_s: None,
    }
}

/// A channel's value quality from its health: a stale channel's last reading is still usable
/// (the model holds it), a faulted one is not.
pub(crate) fn channel_quality(c: &ChannelStatus) -> Quality {
    match (c.value, c.health) {
        (None, _) => Quality::NoData,
        (Some(_), _) if c.substituted => Quality::Substituted,
        (Some(_), Health::Ok) => Quality::Good,
        (Some(_), Health::Stale) => Quality::LastUsable,
        (Some(_), Health::OutOfRange) => Quality::OutOfRange,
        (Some(_), Health::DecodeError) => Quality::DeviceFailure,
    }
}

/// A term's group folder: geometric/thermal/load from the model, `Other` when unknown.
fn group_folder(model: Option<&ModelIdentity>, term: &str) -> &'static str {
    match model.and_then(|m| m.term_groups.get(term)).copied() {
        Some("geometric") => "Geometric",
        Some("thermal") => "Thermal",
        Some("load") => "Load",
        _ => "Other",
    }
}

/// What does not change while the gateway runs.
pub(crate) fn identification(box_name: &str, model: Option<&ModelIdentity>) -> Vec<Point> {
    let s = |v: &str| Value::Str(v.to_string());
    let id = |k: &str| format!("Identification/{k}");
    vec![
        p(id("Name"), s(box_name), None),
        p(id("ProductName"), s("retrocomp"), None),
        p(id("SoftwareRevision"), s(env!("CARGO_PKG_VERSION")), None),
        p(id("ModelName"), s(model.map_or("", |m| &m.name)), None),
        p(id("ModelSha256"), s(model.map_or("", |m| &m.sha256)), None),
    ]
}

/// Every variable the snapshot fills, in a stable order.
pub(crate) fn points(snap: &StatusSnapshot, model: Option<&ModelIdentity>) -> Vec<Point> {
    let mut out = Vec::with_capacity(64);
    let comp = |k: &str| format!("Monitoring/Compensation/{k}");
    out.push(p(comp("Enabled"), Value::Bool(snap.enabled), None));
    out.push(p(comp("Cycles"), Value::U64(snap.cycles), None));
    let model_error = snap.model_error.clone().unwrap_or_default();
    out.push(p(comp("ModelError"), Value::Str(model_error), None));
    out.push(p(comp("Time"), Value::F64(Some(snap.t_s)), Some(SECOND)));
    for a in &snap.axes {
        let ax = |k: &str| format!("Monitoring/Axes/{}/{k}", a.axis.to_uppercase());
        let um = Some(MICROMETRE);
        out.push(p(ax("Correction"), Value::F64(Some(a.applied_um)), um));
        out.push(p(ax("TargetCorrection"), Value::F64(a.target_um), um));
        out.push(p(
            ax("Position"),
            Value::F64(a.position_mm),
            Some(MILLIMETRE),
        ));
        out.push(p(
            ax("Mode"),
            Value::Str(crate::northbound::state_name(&a.mode)),
            None,
        ));
        out.push(p(
            ax("Direction"),
            Value::Str(retrocomp_model::approach::latched_name(a.direction).into()),
            None,
        ));
        for (term, v) in &a.terms_um {
            let path = ax(&format!("Terms/{}/{term}", group_folder(model, term)));
            out.push(p(path, Value::F64(Some(*v)), um));
        }
    }
    for (name, c) in &snap.channels {
        let ch = |k: &str| format!("Monitoring/Sensors/{name}/{k}");
        let has = |k: FaultKind| c.faults.contains(&k);
        out.push(Point {
            quality: channel_quality(c),
            source_t_s: c.reading_t_s,
            ..p(ch("Value"), Value::F64(c.value), unit_of_channel(name))
        });
        out.push(p(
            ch("Health"),
            Value::Str(crate::northbound::state_name(&c.health)),
            None,
        ));
        out.push(p(ch("Healthy"), Value::Bool(c.health == Health::Ok), None));
        let stale = c.health == Health::Stale || has(FaultKind::Stale);
        out.push(p(ch("Stale"), Value::Bool(stale), None));
        out.push(p(ch("Stuck"), Value::Bool(has(FaultKind::Stuck)), None));
        out.push(p(ch("Substituted"), Value::Bool(c.substituted), None));
    }
    if let Some(s) = &snap.sink {
        let sk = |k: &str| format!("Monitoring/Sink/{k}");
        out.push(p(sk("Kind"), Value::Str(s.kind.clone()), None));
        out.push(p(sk("Connected"), Value::Bool(s.connected), None));
        out.push(p(sk("WritesOk"), Value::U64(s.writes_ok), None));
        out.push(p(sk("WritesFailed"), Value::U64(s.writes_failed), None));
        let err = s.last_error.clone().unwrap_or_default();
        out.push(p(sk("LastError"), Value::Str(err), None));
    }
    let faults: Vec<String> = snap
        .active_faults
        .iter()
        .map(|(src, kind, since)| {
            format!(
                "{src}: {} since {since:.3} s",
                crate::northbound::state_name(kind)
            )
        })
        .collect();
    let count = faults.len() as u64;
    out.push(p(
        "Notification/ActiveFaults".into(),
        Value::StrArray(faults),
        None,
    ));
    out.push(p(
        "Notification/ActiveFaultCount".into(),
        Value::U64(count),
        None,
    ));
    out
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::engine::health::ChannelStatus;
    use crate::engine::safety::Mode;
    use crate::status::{AxisStatus, SinkStatus};
    use retrocomp_model::approach::Approach;

    fn snapshot() -> StatusSnapshot {
        let terms: BTreeMap<String, f64> = [("EXX".to_string(), 1.5), ("spindle".into(), -4.0)]
            .into_iter()
            .collect();
        let channels = [(
            "T_spindle_C".to_string(),
            ChannelStatus {
                value: Some(24.5),
                health: Health::Stale,
                faults: vec![FaultKind::Stale, FaultKind::Stuck],
                substituted: true,
                reading_t_s: None,
            },
        )]
        .into_iter()
        .collect();
        StatusSnapshot {
            t_s: 12.0,
            cycles: 7,
            enabled: true,
            axes: vec![AxisStatus {
                axis: "x".into(),
                position_mm: Some(100.0),
                direction: Some(Approach::Forward),
                weight_forward: 1.0,
                target_um: None,
                applied_um: -2.5,
                mode: Mode::RampingIn,
                terms_um: terms,
                clamp_hits: 0,
                cap_hits: 0,
            }],
            channels,
            active_faults: vec![("T_spindle_C".into(), FaultKind::Stale, 10.25)],
            model_error: None,
            sink: Some(SinkStatus {
                kind: "origin_shift".into(),
                writes_ok: 3,
                ..SinkStatus::default()
            }),
            sources: vec![],
            model: None,
            telemetry: None,
            timing: Default::default(),
        }
    }

    fn find<'a>(pts: &'a [Point], path: &str) -> &'a Point {
        pts.iter()
            .find(|p| p.path == path)
            .unwrap_or_else(|| panic!("no {path} in {pts:#?}"))
    }

    #[test]
    fn unece_codes_give_the_part_8_unit_ids() {
        // Part 8 §5.6.3's own examples: "4H" (micrometre) and "CEL" (degree Celsius).
        assert_eq!(unece_unit_id("4H"), 13384);
        assert_eq!(unece_unit_id("CEL"), 4408652);
        assert_eq!(unit_of_channel("T_spindle_C"), Some(CELSIUS));
        assert_eq!(unit_of_channel("F_cut_N"), Some(NEWTON));
        assert_eq!(unit_of_channel("strain_g1_ue"), None);
    }

    #[test]
    fn a_snapshot_maps_to_corrections_terms_sensors_and_faults() {
        let model = ModelIdentity {
            name: "mill".into(),
            sha256: "ab".into(),
            term_groups: [
                ("EXX".to_string(), "geometric"),
                ("spindle".into(), "thermal"),
            ]
            .into_iter()
            .collect(),
            ..ModelIdentity::default()
        };
        let pts = points(&snapshot(), Some(&model));
        let c = find(&pts, "Monitoring/Axes/X/Correction");
        assert_eq!(
            (&c.value, c.unit),
            (&Value::F64(Some(-2.5)), Some(MICROMETRE))
        );
        let t = find(&pts, "Monitoring/Axes/X/TargetCorrection");
        assert_eq!(t.value, Value::F64(None));
        let m = find(&pts, "Monitoring/Axes/X/Mode");
        assert_eq!(m.value, Value::Str("ramping_in".into()));
        let g = find(&pts, "Monitoring/Axes/X/Terms/Geometric/EXX");
        assert_eq!(g.value, Value::F64(Some(1.5)));
        let th = find(&pts, "Monitoring/Axes/X/Terms/Thermal/spindle");
        assert_eq!(th.value, Value::F64(Some(-4.0)));
        let v = find(&pts, "Monitoring/Sensors/T_spindle_C/Value");
        assert_eq!((&v.value, v.unit), (&Value::F64(Some(24.5)), Some(CELSIUS)));
        for (flag, want) in [
            ("Stale", true),
            ("Stuck", true),
            ("Substituted", true),
            ("Healthy", false),
        ] {
            let f = find(&pts, &format!("Monitoring/Sensors/T_spindle_C/{flag}"));
            assert_eq!(f.value, Value::Bool(want), "{flag}");
        }
        let w = find(&pts, "Monitoring/Sink/WritesOk");
        assert_eq!(w.value, Value::U64(3));
        let f = find(&pts, "Notification/ActiveFaults");
        assert_eq!(
            f.value,
            Value::StrArray(vec!["T_spindle_C: stale since 10.250 s".into()])
        );
        // Without a model identity the terms still show, under Other.
        let pts = points(&snapshot(), None);
        find(&pts, "Monitoring/Axes/X/Terms/Other/EXX");
    }

    #[test]
    fn a_channel_value_carries_its_health_and_reading_time() {
        let c = |value, health, substituted| ChannelStatus {
            value,
            health,
            faults: vec![],
            substituted,
            reading_t_s: Some(11.5),
        };
        let cases = [
            (c(Some(1.0), Health::Ok, false), Quality::Good),
            (c(Some(1.0), Health::Stale, false), Quality::LastUsable),
            (c(Some(1.0), Health::Stale, true), Quality::Substituted),
            (c(Some(1.0), Health::OutOfRange, false), Quality::OutOfRange),
            (
                c(Some(1.0), Health::DecodeError, false),
                Quality::DeviceFailure,
            ),
            (c(None, Health::Stale, false), Quality::NoData),
        ];
        for (ch, want) in cases {
            assert_eq!(channel_quality(&ch), want, "{ch:?}");
        }
        let mut snap = snapshot();
        snap.channels
            .insert("T_bed_C".into(), c(Some(21.0), Health::Stale, false));
        let pts = points(&snap, None);
        let v = find(&pts, "Monitoring/Sensors/T_bed_C/Value");
        assert_eq!((v.quality, v.source_t_s), (Quality::LastUsable, Some(11.5)));
        let t = find(&pts, "Monitoring/Axes/X/TargetCorrection");
        assert_eq!((t.quality, t.source_t_s), (Quality::NoData, None));
        let a = find(&pts, "Monitoring/Axes/X/Correction");
        assert_eq!(a.quality, Quality::Good);
    }

    #[test]
    fn identification_names_the_model() {
        let model = ModelIdentity {
            name: "mill".into(),
            sha256: "00ff".into(),
            ..ModelIdentity::default()
        };
        let pts = identification("box-1", Some(&model));
        assert_eq!(
            find(&pts, "Identification/ModelSha256").value,
            Value::Str("00ff".into())
        );
        assert_eq!(
            find(&pts, "Identification/Name").value,
            Value::Str("box-1".into())
        );
    }
}
