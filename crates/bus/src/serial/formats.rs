//! Parsers for serial instrument lines (sans-IO: one framed line in, readings out). Each reading has a
//! key that the source maps to a channel: an axis letter, an instrument channel number, a field index.
//!
//! - `heidenhain`: Heidenhain ND 2xx/7xx style, `STX` + sign + 9 digits with no decimal point, one line
//!   per axis in the DRO's axis order; value = digits / 10^decimals (mm). Key: none (order).
//! - `nd522`: Heidenhain ND 522 style `X=+41.29 R` (axis, signed value with point, optional flags).
//!   Key: the axis letter.
//! - `mitutoyo`: Mitutoyo USB-ITN / U-WAVE style `01A+0000.123` (2-digit channel, data letter, signed
//!   value). Key: the channel number, e.g. `1`.
//! - `weighing`: weighing-indicator lines `ST,GS,+0012.345kg` (A&D / CAS style): stability `ST`/`US`/
//!   `OL`, `GS`/`NT` gross or net, signed value, unit. Key: `GS` or `NT`. `OL` (overload) is out of range.
//! - `generic`: configured in TOML: optional `prefix`, fields split at `delimiter` (whitespace if
//!   unset), `key=value` fields reduced to the value, optional `unit` suffix removed. Key: field index.

/// Why a line did not parse (the line is counted as garbage and skipped).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct LineError(pub &'static str);

/// One value from a line.
#[derive(Debug, Clone, PartialEq)]
pub struct Reading {
    pub key: Option<String>,
    pub value: f64,
    /// The instrument itself flags the value as invalid (weighing overload).
    pub overload: bool,
    /// The instrument flags the value as not settled (weighing `US`).
    pub unstable: bool,
}

impl Reading {
    fn plain(key: Option<String>, value: f64) -> Self {
        Reading {
            key,
            value,
            overload: false,
            unstable: false,
        }
    }
}

fn text(line: &[u8]) -> Result<&str, LineError> {
    let s = std::str::from_utf8(line).map_err(|_| LineError("not ASCII"))?;
    if !s.is_ascii() {
        return Err(LineError("not ASCII"));
    }
    Ok(s.trim_matches(|c: char| c.is_ascii_whitespace() || c == '\u{2}' || c == '\u{3}'))
}

/// A signed decimal number: optional sign, digits, at most one point, at least one digit, nothing else
/// (no exponent, no inf/nan, which `f64::from_str` would accept).
pub(crate) fn parse_decimal(s: &str) -> Option<f64> {
    let body = s.strip_prefix(['+', '-']).unwrap_or(s);
    let digits = body.bytes().filter(u8::is_ascii_digit).count();
    let points = body.bytes().filter(|&c| c == b'.').count();
    if digits == 0 || points > 1 || digits + points != body.len() {
        return None;
    }
    s.parse::<f64>().ok()
}

pub fn parse_heidenhain(line: &[u8], decimals: u8) -> Result<Reading, LineError> {
    if line.first() != Some(&0x02) {
        return Err(LineError("heidenhain: line does not start with STX"));
    }
    let s = text(line)?;
    let (sign, digits) = match s.as_bytes().first() {
        Some(b'+') => (1.0, &s[1..]),
        Some(b'-') => (-1.0, &s[1..]),
        _ => return Err(LineError("heidenhain: missing sign")),
    };
    if digits.len() != 9 || !digits.bytes().all(|c| c.is_ascii_digit()) {
        return Err(LineError("heidenhain: expected 9 digits"));
    }
    let n: u64 = digits
        .parse()
        .map_err(|_| LineError("heidenhain: digits"))?;
    Ok(Reading::plain(
        None,
        sign * n as f64 / 10f64.powi(i32::from(decimals.min(9))),
    ))
}

pub fn parse_nd522(line: &[u8]) -> Result<Reading, LineError> {
    let s = text(line)?;
    let (axis, rest) = s
        .split_once('=')
        .ok_or(LineError("nd522: expected `A=value`"))?;
    let axis = axis.trim();
    if axis.len() != 1 || !axis.bytes().all(|c| c.is_ascii_alphabetic()) {
        return Err(LineError("nd522: axis must be one letter"));
    }
    let value = rest
        .split_ascii_whitespace()
        .next()
        .and_then(parse_decimal)
        .ok_or(LineError("nd522: value is not a signed decimal"))?;
    Ok(Reading::plain(Some(axis.to_ascii_uppercase()), value))
}

pub fn parse_mitutoyo(line: &[u8]) -> Result<Reading, LineError> {
    let s = text(line)?;
    let b = s.as_bytes();
    if b.len() < 5
        || !b[0].is_ascii_digit()
        || !b[1].is_ascii_digit()
        || !b[2].is_ascii_alphabetic()
    {
        return Err(LineError("mitutoyo: expected `NNA±value`"));
    }
    let ch: u8 = s[..2].parse().map_err(|_| LineError("mitutoyo: channel"))?;
    let v = &s[3..];
    if !v.starts_with(['+', '-']) {
        return Err(LineError("mitutoyo: value must be signed"));
    }
    let value = parse_decimal(v).ok_or(LineError("mitutoyo: value is not a decimal"))?;
    Ok(Reading::plain(Some(ch.to_string()), value))
}

pub fn parse_weighing(line: &[u8], unit: Option<&str>) -> Result<Reading, LineError> {
    let s = text(line)?;
    let mut f = s.split(',').map(str::trim);
    let (Some(stab), Some(kind), Some(val), None) = (f.next(), f.next(), f.next(), f.next()) else {
        return Err(LineError("weighing: expected `ST,GS,±value unit`"));
    };
    let (overload, unstable) = match stab {
        "ST" => (false, false),
        "US" => (false, true),
        "OL" => (true, false),
        _ => return Err(LineError("weighing: stability must be ST, US or OL")),
    };
    if kind != "GS" && kind != "NT" {
        return Err(LineError("weighing: kind must be GS or NT"));
    }
    let split = val
        .find(|c: char| c.is_ascii_alphabetic())
        .unwrap_or(val.len());
    let (num, got_unit) = (val[..split].trim(), val[split..].trim());
    if let Some(u) = unit
        && got_unit != u
    {
        return Err(LineError("weighing: unexpected unit"));
    }
    // An overloaded indicator often sends no number at all; the reading is invalid either way.
    let value = match parse_decimal(num) {
        Some(v) => v,
        None if overload => f64::NAN,
        None => return Err(LineError("weighing: value is not a signed decimal")),
    };
    Ok(Reading {
        key: Some(kind.to_string()),
        value,
        overload,
        unstable,
    })
}

/// Options of the generic format.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct GenericFormat {
    #[serde(default)]
    pub prefix: Option<String>,
    #[serde(default)]
    pub delimiter: Option<String>,
    #[serde(default)]
    pub unit: Option<String>,
}

/// Every field that parses as a decimal gives a reading keyed by its 0-based index; a line with no
/// numeric field at all is an error.
pub fn parse_generic(line: &[u8], g: &GenericFormat) -> Result<Vec<Reading>, LineError> {
    let mut s = text(line)?;
    if let Some(p) = &g.prefix {
        s = s
            .strip_prefix(p.as_str())
            .ok_or(LineError("generic: prefix missing"))?;
    }
    let fields: Vec<&str> = match g.delimiter.as_deref() {
        Some(d) if !d.is_empty() => s.split(d).collect(),
        _ => s.split_ascii_whitespace().collect(),
    };
    let mut out = Vec::new();
    for (i, f) in fields.iter().enumerate() {
        let mut v = f.trim();
        if let Some((_, r)) = v.split_once('=') {
            v = r.trim();
        }
        if let Some(u) = &g.unit {
            v = v.strip_suffix(u.as_str()).unwrap_or(v).trim_end();
        }
        if let Some(x) = parse_decimal(v) {
            out.push(Reading::plain(Some(i.to_string()), x));
        }
    }
    if out.is_empty() {
        return Err(LineError("generic: no numeric field"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heidenhain_stx_sign_nine_digits() {
        // rust-stack.md §6: ND 2xx/7xx reply STX + sign + 9 digits, no decimal point.
        let r = parse_heidenhain(b"\x02-000412900", 4).unwrap();
        assert_eq!(r.value, -41.29);
        assert!(parse_heidenhain(b"-000412900", 4).is_err(), "no STX");
        assert!(parse_heidenhain(b"\x02+00041290", 4).is_err(), "8 digits");
        assert!(parse_heidenhain(b"\x02+0004129.0", 4).is_err(), "point");
    }

    #[test]
    fn nd522_and_mitutoyo_examples() {
        // rust-stack.md §6: ND 522 `X=+41.29 R`; Mitutoyo `01A+0000.123`.
        let r = parse_nd522(b"X=+41.29 R").unwrap();
        assert_eq!((r.key.as_deref(), r.value), (Some("X"), 41.29));
        assert_eq!(parse_nd522(b"Z=-0.005").unwrap().value, -0.005);
        assert!(parse_nd522(b"XY=1.0").is_err());
        let r = parse_mitutoyo(b"01A+0000.123").unwrap();
        assert_eq!((r.key.as_deref(), r.value), (Some("1"), 0.123));
        assert_eq!(parse_mitutoyo(b"12A-0012.500").unwrap().value, -12.5);
        assert!(parse_mitutoyo(b"01A0000.123").is_err(), "unsigned");
        assert!(
            parse_mitutoyo(b"01A+1e3").is_err(),
            "exponent is not a DRO value"
        );
    }

    #[test]
    fn weighing_stability_and_overload() {
        let r = parse_weighing(b"ST,GS,+0012.345kg", Some("kg")).unwrap();
        assert_eq!(
            (r.key.as_deref(), r.value, r.unstable, r.overload),
            (Some("GS"), 12.345, false, false)
        );
        assert!(parse_weighing(b"US,NT,-0000.020kg", None).unwrap().unstable);
        assert!(parse_weighing(b"OL,GS,         kg", None).unwrap().overload);
        assert!(parse_weighing(b"ST,GS,+0012.345lb", Some("kg")).is_err());
        assert!(parse_weighing(b"ST,XX,+1kg", None).is_err());
    }

    #[test]
    fn generic_fields() {
        let g = GenericFormat {
            prefix: Some("T:".into()),
            delimiter: Some(";".into()),
            unit: Some("C".into()),
        };
        let r = parse_generic(b"T:spindle=23.5C;bed=21.0C;ok", &g).unwrap();
        let kv: Vec<_> = r
            .iter()
            .map(|r| (r.key.clone().unwrap(), r.value))
            .collect();
        assert_eq!(kv, vec![("0".into(), 23.5), ("1".into(), 21.0)]);
        assert!(parse_generic(b"P:1;2", &g).is_err());
        assert!(parse_generic(b"T:nan;inf", &g).is_err());
    }
}
