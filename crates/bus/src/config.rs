//! The field TOML: which buses exist and how their channels map to named, unit-suffixed values.
//!
//! ```toml
//! [can]                                   # optional; see can::backend
//! backend = "socketcand"
//! channel = "can0"
//!
//! [canopen]
//! heartbeat_timeout_s = 0.5
//! [[canopen.encoder]]                     # CiA 406, see canopen::cia406::EncoderChannel
//! channel = "x_mm"
//! node_id = 1
//! counts_per_mm = 1000.0
//! [[canopen.analog]]                      # CiA 404, see canopen::cia404::AnalogChannel
//! channel = "T_spindle_C"
//! node_id = 16
//! type = "int32"
//! decimal_digits = 3
//!
//! [[modbus.source]]                       # see modbus::poller::ModbusSourceConfig
//! name = "pt100"
//! transport = "tcp"
//! host = "192.168.0.20"
//! [[modbus.source.channel]]               # see modbus::regmap::RegisterChannel
//! channel = "T_bed_C"
//! kind = "input"
//! address = 0
//! type = "int16"
//! scale = 0.1
//!
//! [[serial.source]]                       # see serial::source::SerialSourceConfig
//! name = "dro"
//! device = "/dev/ttyUSB0"
//! format = { kind = "heidenhain", decimals = 4 }
//! [[serial.source.channel]]
//! name = "x_mm"
//! ```
//! Errors (syntax, type, unknown key, and the semantic checks in [`validate`]) name the file, the line
//! and the key path (`canopen.encoder[1].counts_per_mm`), and all problems are reported at once.

use super::can::CanBackendConfig;
use super::canopen::{AnalogChannel, AnalogType, CanopenConfig, EncoderChannel};
use super::modbus::{ModbusSourceConfig, TransportKind};
use super::serial::{LineFormat, SerialSourceConfig};
use std::collections::BTreeMap;
use std::path::Path;
use toml::de::{DeTable, DeValue};

#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusSection {
    #[serde(default)]
    pub source: Vec<ModbusSourceConfig>,
}

#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SerialSection {
    #[serde(default)]
    pub source: Vec<SerialSourceConfig>,
}

/// The whole field TOML.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct FieldConfig {
    #[serde(default)]
    pub can: Option<CanBackendConfig>,
    #[serde(default)]
    pub canopen: Option<CanopenConfig>,
    #[serde(default)]
    pub modbus: ModbusSection,
    #[serde(default)]
    pub serial: SerialSection,
}

use retrocomp_model::{ConfigError, ConfigIssue};

/// Read and validate a field TOML file.
pub fn load(path: &Path) -> Result<FieldConfig, ConfigError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| ConfigError::single(&file, "", format!("cannot read: {e}")))?;
    parse(&text, &file)
}

/// Parse and validate field TOML text; `file` names it in errors.
pub fn parse(text: &str, file: &str) -> Result<FieldConfig, ConfigError> {
    let cfg: FieldConfig =
        toml::from_str(text).map_err(|e| ConfigError::from_toml(file, text, &e))?;
    super::modbus::warn_deprecated_spellings(text, file);
    let issues: Vec<ConfigIssue> = validate(&cfg)
        .into_iter()
        .map(|(key, message)| ConfigIssue {
            file: file.to_string(),
            line: locate(text, &key).unwrap_or(0),
            column: 0,
            key,
            message,
        })
        .collect();
    if issues.is_empty() {
        Ok(cfg)
    } else {
        Err(ConfigError { issues })
    }
}

fn line_of(text: &str, byte: usize) -> usize {
    text.as_bytes()[..byte.min(text.len())]
        .iter()
        .filter(|&&c| c == b'\n')
        .count()
        + 1
}

/// Line of a key path like `a.b[2].c` in `text` (the deepest part of the path that exists).
pub fn locate(text: &str, path: &str) -> Option<usize> {
    let root = DeTable::parse(text).ok()?;
    let mut span = root.span();
    let mut table: Option<&DeTable<'_>> = Some(root.get_ref());
    let mut value: Option<&DeValue<'_>> = None;
    for part in path.split('.') {
        let (key, idx) = match part.split_once('[') {
            Some((k, rest)) => (k, rest.trim_end_matches(']').parse::<usize>().ok()),
            None => (part, None),
        };
        let t = match (table, value) {
            (Some(t), _) => t,
            (None, Some(DeValue::Table(t))) => t,
            _ => break,
        };
        let Some((k, v)) = t.iter().find(|(k, _)| k.get_ref().as_ref() == key) else {
            break;
        };
        span = k.span();
        table = None;
        value = Some(v.get_ref());
        if let (Some(i), DeValue::Array(a)) = (idx, v.get_ref()) {
            let Some(item) = a.get(i) else { break };
            span = item.span();
            value = Some(item.get_ref());
        }
    }
    Some(line_of(text, span.start))
}

fn is_channel_name(n: &str) -> bool {
    // A name carries its unit as a suffix after the last '_' (x_mm, T_spindle_C, strain_col_ue).
    !n.is_empty()
        && n.bytes().all(|c| c.is_ascii_alphanumeric() || c == b'_')
        && n.rsplit_once('_')
            .is_some_and(|(a, u)| !a.is_empty() && !u.is_empty())
}

fn pos(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

type Problems = Vec<(String, String)>;

/// A channel name must carry a unit suffix and be defined once across all buses; `names` maps each
/// name to the key that defined it first.
fn check_channel_name(
    p: &mut Problems,
    names: &mut BTreeMap<String, String>,
    key: String,
    n: &str,
) {
    if !is_channel_name(n) {
        p.push((
            key.clone(),
            format!("`{n}` is not a channel name with a unit suffix (e.g. x_mm, T_bed_C)"),
        ));
    }
    if let Some(first) = names.insert(n.to_string(), key.clone()) {
        p.push((key, format!("channel `{n}` is already defined at {first}")));
    }
}

/// A CANopen node id (1..=127) and the TPDO number it sends on (1..=4), under `key`.
fn check_node_and_tpdo(p: &mut Problems, key: &str, node_id: u8, tpdo: u8) {
    if !(1..=127).contains(&node_id) {
        p.push((
            format!("{key}.node_id"),
            format!("{node_id} is outside 1..=127"),
        ));
    }
    if !(1..=4).contains(&tpdo) {
        p.push((format!("{key}.tpdo"), format!("{tpdo} is outside 1..=4")));
    }
}

/// Optional physical limits must leave a range (min below max).
fn check_limits(p: &mut Problems, key: &str, min: Option<f64>, max: Option<f64>) {
    if let (Some(a), Some(b)) = (min, max)
        && a >= b
    {
        p.push((
            format!("{key}.min"),
            format!("min {a} must be below max {b}"),
        ));
    }
}

/// Semantic checks; returns (key path, message) for each problem.
pub fn validate(cfg: &FieldConfig) -> Vec<(String, String)> {
    let mut p: Vec<(String, String)> = Vec::new();
    let mut names: BTreeMap<String, String> = BTreeMap::new();
    if let Some(co) = &cfg.canopen {
        validate_canopen(co, &mut p, &mut names);
    }
    for (i, s) in cfg.modbus.source.iter().enumerate() {
        validate_modbus_source(i, s, &mut p, &mut names);
    }
    for (i, s) in cfg.serial.source.iter().enumerate() {
        validate_serial_source(i, s, &mut p, &mut names);
    }
    p
}

/// `[canopen]`: positive timeouts, then each CiA 406 encoder and CiA 404 analog channel.
fn validate_canopen(co: &CanopenConfig, p: &mut Problems, names: &mut BTreeMap<String, String>) {
    if co.heartbeat_timeout_s.is_some_and(|t| !pos(t)) {
        p.push(("canopen.heartbeat_timeout_s".into(), "must be > 0 s".into()));
    }
    if !pos(co.pdo_timeout_s) {
        p.push(("canopen.pdo_timeout_s".into(), "must be > 0 s".into()));
    }
    for (i, e) in co.encoder.iter().enumerate() {
        validate_encoder(i, e, p, names);
    }
    for (i, a) in co.analog.iter().enumerate() {
        validate_analog(i, a, p, names);
    }
}

/// `[[canopen.encoder]]`: node and TPDO numbers, the position's place in the PDO, the scale, range
/// and offset that turn counts into mm, the TPDO timer, and the limits.
fn validate_encoder(
    i: usize,
    e: &EncoderChannel,
    p: &mut Problems,
    names: &mut BTreeMap<String, String>,
) {
    let k = format!("canopen.encoder[{i}]");
    check_channel_name(p, names, format!("{k}.channel"), &e.channel);
    check_node_and_tpdo(p, &k, e.node_id, e.tpdo);
    if e.byte_offset > 4 {
        p.push((
            format!("{k}.byte_offset"),
            "6004h (4 bytes) must fit in 8 bytes: at most 4".into(),
        ));
    }
    if !pos(e.counts_per_mm) {
        p.push((
            format!("{k}.counts_per_mm"),
            format!(
                "must be > 0 (got {}); use direction for the sign",
                e.counts_per_mm
            ),
        ));
    }
    if e.total_range_counts
        .is_some_and(|r| !(2..=1 << 32).contains(&r))
    {
        p.push((
            format!("{k}.total_range_counts"),
            "must be in 2..=2^32".into(),
        ));
    }
    if !e.offset_mm.is_finite() {
        p.push((format!("{k}.offset_mm"), "must be finite".into()));
    }
    if e.cyclic_ms == Some(0) {
        p.push((
            format!("{k}.cyclic_ms"),
            "0 disables the TPDO timer; omit the key instead".into(),
        ));
    }
    check_limits(p, &k, e.min_mm, e.max_mm);
}

/// `[[canopen.analog]]`: node and TPDO numbers, the value's place in the PDO, its decimal
/// scaling, and the limits.
fn validate_analog(
    i: usize,
    a: &AnalogChannel,
    p: &mut Problems,
    names: &mut BTreeMap<String, String>,
) {
    let k = format!("canopen.analog[{i}]");
    check_channel_name(p, names, format!("{k}.channel"), &a.channel);
    check_node_and_tpdo(p, &k, a.node_id, a.tpdo);
    if usize::from(a.byte_offset) + a.data_type.size() > 8 {
        p.push((
            format!("{k}.byte_offset"),
            "value must fit in the 8-byte PDO".into(),
        ));
    }
    if a.decimal_digits > 9 {
        p.push((format!("{k}.decimal_digits"), "at most 9".into()));
    }
    if a.data_type == AnalogType::Real32 && a.decimal_digits != 0 {
        p.push((
            format!("{k}.decimal_digits"),
            "REAL32 values are not scaled by decimal digits".into(),
        ));
    }
    check_limits(p, &k, a.min, a.max);
}

/// `[[modbus.source]]`: a transport with its endpoint, the unit id and timing, and each register
/// channel.
fn validate_modbus_source(
    i: usize,
    s: &ModbusSourceConfig,
    p: &mut Problems,
    names: &mut BTreeMap<String, String>,
) {
    let k = format!("modbus.source[{i}]");
    match s.transport {
        TransportKind::Tcp if s.host.is_none() => {
            p.push((format!("{k}.transport"), "tcp needs `host`".into()));
        }
        TransportKind::Rtu if s.device.is_none() => {
            p.push((format!("{k}.transport"), "rtu needs `device`".into()));
        }
        _ => {}
    }
    if s.baud == 0 {
        p.push((format!("{k}.baud"), "must be > 0".into()));
    }
    if !(1..=247).contains(&s.unit_id) {
        p.push((
            format!("{k}.unit_id"),
            format!("{} is outside 1..=247", s.unit_id),
        ));
    }
    for (key, v) in [
        ("period_s", s.period_s),
        ("timeout_s", s.timeout_s),
        ("backoff_min_s", s.backoff_min_s),
        ("backoff_max_s", s.backoff_max_s),
    ] {
        if !pos(v) {
            p.push((format!("{k}.{key}"), format!("must be > 0 s (got {v})")));
        }
    }
    if s.backoff_min_s > s.backoff_max_s {
        p.push((
            format!("{k}.backoff_min_s"),
            "must not exceed backoff_max_s".into(),
        ));
    }
    if s.channel.is_empty() {
        p.push((k.clone(), "has no [[modbus.source.channel]]".into()));
    }
    for (j, c) in s.channel.iter().enumerate() {
        let kc = format!("{k}.channel[{j}]");
        check_channel_name(p, names, format!("{kc}.channel"), &c.channel);
        if c.last_address() > 0xFFFF {
            p.push((
                format!("{kc}.address"),
                "the value runs past register 65535".into(),
            ));
        }
        if !c.scale.is_finite() || c.scale == 0.0 {
            p.push((format!("{kc}.scale"), "must be finite and non-zero".into()));
        }
        if !c.offset.is_finite() {
            p.push((format!("{kc}.offset"), "must be finite".into()));
        }
        check_limits(p, &kc, c.min, c.max);
    }
}

/// `[[serial.source]]`: a device, line timing and length, the line format, and each channel.
fn validate_serial_source(
    i: usize,
    s: &SerialSourceConfig,
    p: &mut Problems,
    names: &mut BTreeMap<String, String>,
) {
    let k = format!("serial.source[{i}]");
    if s.device.is_none() {
        p.push((format!("{k}.device"), "missing (e.g. /dev/ttyUSB0)".into()));
    }
    if s.baud == 0 {
        p.push((format!("{k}.baud"), "must be > 0".into()));
    }
    if !pos(s.period_s) || !pos(s.timeout_s) {
        p.push((
            format!("{k}.timeout_s"),
            "period_s and timeout_s must be > 0 s".into(),
        ));
    }
    if s.max_line < 16 {
        p.push((format!("{k}.max_line"), "at least 16 bytes".into()));
    }
    if let LineFormat::Heidenhain { decimals } = s.format
        && decimals > 9
    {
        p.push((
            format!("{k}.format"),
            "heidenhain decimals: at most 9".into(),
        ));
    }
    if s.channel.is_empty() {
        p.push((k.clone(), "has no [[serial.source.channel]]".into()));
    }
    for (j, c) in s.channel.iter().enumerate() {
        let kc = format!("{k}.channel[{j}]");
        check_channel_name(p, names, format!("{kc}.name"), &c.name);
        if !c.scale.is_finite() || c.scale == 0.0 {
            p.push((format!("{kc}.scale"), "must be finite and non-zero".into()));
        }
        check_limits(p, &kc, c.min, c.max);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[can]
backend = "socketcand"
channel = "can0"

[canopen]
heartbeat_timeout_s = 0.5
[[canopen.encoder]]
channel = "x_mm"
node_id = 1
counts_per_mm = 1000.0
cyclic_ms = 10
[[canopen.encoder]]
channel = "y_mm"
node_id = 2
counts_per_mm = 409.6
direction = "negative"
[[canopen.analog]]
channel = "T_spindle_C"
node_id = 16
type = "int32"
decimal_digits = 3

[[modbus.source]]
name = "pt100"
transport = "tcp"
host = "127.0.0.1"
[[modbus.source.channel]]
channel = "T_bed_C"
kind = "input"
address = 0
type = "int16"
scale = 0.1

[[serial.source]]
name = "dro"
device = "/dev/ttyUSB0"
format = { kind = "heidenhain", decimals = 4 }
[[serial.source.channel]]
name = "z_mm"
"#;

    #[test]
    fn good_file_parses() {
        let c = parse(GOOD, "field.toml").unwrap();
        let co = c.canopen.unwrap();
        assert_eq!(co.encoder.len(), 2);
        assert_eq!(co.encoder[1].counts_per_mm, 409.6);
        assert_eq!(c.modbus.source[0].channel[0].scale, 0.1);
        assert_eq!(
            c.serial.source[0].format,
            LineFormat::Heidenhain { decimals: 4 }
        );
    }

    #[test]
    fn semantic_errors_name_file_line_and_key() {
        let bad = GOOD
            .replace("counts_per_mm = 409.6", "counts_per_mm = 0.0")
            .replace("scale = 0.1", "scale = 0.0")
            .replace("name = \"z_mm\"", "name = \"x_mm\"");
        let e = parse(&bad, "field.toml").unwrap_err();
        let text = e.to_string();
        assert_eq!(e.issues.len(), 3, "{text}");
        let line = |s: &str| bad.lines().position(|l| l.contains(s)).unwrap() + 1;
        assert!(
            text.contains(&format!(
                "field.toml:{}: key `canopen.encoder[1].counts_per_mm`: must be > 0",
                line("counts_per_mm = 0.0")
            )),
            "{text}"
        );
        assert!(
            text.contains(&format!(
                "field.toml:{}: key `modbus.source[0].channel[0].scale`",
                line("scale = 0.0")
            )),
            "{text}"
        );
        assert!(text.contains("serial.source[0].channel[0].name`: channel `x_mm` is already defined at canopen.encoder[0].channel"), "{text}");
    }

    #[test]
    fn syntax_and_unknown_keys_report_the_line() {
        let bad = GOOD.replace(
            "decimal_digits = 3",
            "decimal_digits = 3\ncounts_per_rev = 4096",
        );
        let e = parse(&bad, "f.toml").unwrap_err();
        let want = bad
            .lines()
            .position(|l| l.contains("counts_per_rev"))
            .unwrap()
            + 1;
        assert_eq!(e.issues[0].line, want, "{e}");
        assert!(e.to_string().contains("counts_per_rev"), "{e}");
        let e = parse("[canopen]\npdo_timeout_s = \"fast\"\n", "f.toml").unwrap_err();
        assert_eq!(e.issues[0].line, 2, "{e}");
    }
}
