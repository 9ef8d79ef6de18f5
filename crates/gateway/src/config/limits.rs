//! Start-time checks that a field config's numbers can be kept: the direction latch's settings are
//! real durations and distances, every correction register can hold the clamp it is asked to
//! carry, and a served register image knows what the controller holds after a restart. Each
//! problem is `(key path, what was expected)`; the caller places it at the key's line (file:line:key).
//! Units as in the schema: mm, s, ms, µm.

use crate::config::FieldConfig;
use crate::sinks::origin_shift::map::AxisRegister;
use crate::sinks::origin_shift::server::ServerConfig;
use retrocomp_bus::modbus::DataType;

type Checked = Result<(), (String, String)>;

/// Largest direction deadband accepted, mm: beyond it the latch would miss every reversal of a
/// finishing pass (typical 0.001–0.05 mm).
const MAX_DEADBAND_MM: f64 = 1.0;
/// Longest forward/reverse blend accepted, s.
const MAX_SWITCH_TIME_S: f64 = 10.0;

/// Every check of this file, in file order of the keys they look at.
pub(super) fn check(cfg: &FieldConfig) -> Checked {
    check_direction(cfg)?;
    if let Some(os) = &cfg.sink.origin_shift {
        for (i, r) in os.map.axes.iter().enumerate() {
            register_holds_clamp(cfg, &format!("sink.origin_shift.map.axis[{i}]"), r)?;
        }
    }
    if let Some(srv) = &cfg.sink.origin_shift_server {
        check_server(cfg, srv)?;
    }
    Ok(())
}

/// `[direction]`: a deadband of 0 … 1 mm and a blend of 0 … 10 s, both finite (NaN compares false
/// everywhere and would disable the latch's hysteresis or blend without a word).
fn check_direction(cfg: &FieldConfig) -> Checked {
    let d = &cfg.direction;
    for (key, v, max, unit) in [
        (
            "direction.deadband_mm",
            d.deadband_mm,
            MAX_DEADBAND_MM,
            "mm",
        ),
        (
            "direction.switch_time_s",
            d.switch_time_s,
            MAX_SWITCH_TIME_S,
            "s",
        ),
    ] {
        if !(v.is_finite() && (0.0..=max).contains(&v)) {
            return Err((key.into(), format!("expected 0 ≤ {unit} ≤ {max}, got {v}")));
        }
    }
    Ok(())
}

/// Largest count a correction register holds (signed types only: `map.rs` refuses the others).
fn max_counts(t: DataType) -> Option<f64> {
    match t {
        DataType::Int16 => Some(f64::from(i16::MAX)),
        DataType::Int32 => Some(f64::from(i32::MAX)),
        _ => None,
    }
}

/// The axis' clamp (`max_correction_um`, its override or `[safety]`) fits the register: otherwise
/// the encoder would saturate or wrap a value the guard let through.
fn register_holds_clamp(cfg: &FieldConfig, key: &str, r: &AxisRegister) -> Checked {
    let Some(max) = max_counts(r.data_type) else {
        return Ok(());
    };
    if !(r.lsb_um.is_finite() && r.lsb_um > 0.0) {
        return Ok(()); // the map's own check names lsb_um
    }
    let clamp_um = cfg.safety_for(&r.axis).max_correction_um;
    let holds_um = max * r.lsb_um;
    if clamp_um > holds_um {
        return Err((
            format!("{key}.kind"),
            format!(
                "{:?} at lsb_um = {} holds at most ±{holds_um:.1} µm, but axis {}'s clamp max_correction_um is {clamp_um} µm: expected a clamp ≤ {holds_um:.1} µm, a larger lsb_um or kind = \"int32\"",
                r.data_type, r.lsb_um, r.axis
            )
            .replace("Int16", "int16")
            .replace("Int32", "int32"),
        ));
    }
    Ok(())
}

/// `[sink.origin_shift_server]`: a controller timeout that can be noticed, held registers (what
/// the controller applies is the only safe start after a restart of the box), and correction
/// registers that hold the clamp.
fn check_server(cfg: &FieldConfig, srv: &ServerConfig) -> Checked {
    const KEY: &str = "sink.origin_shift_server";
    let t = srv.controller_timeout_ms;
    if !(srv.update_period_ms.max(1)..=60_000).contains(&t) {
        return Err((
            format!("{KEY}.controller_timeout_ms"),
            format!(
                "expected {}..=60000 ms (at least update_period_ms: 0 would fault at every update or never notice a silent controller), got {t}",
                srv.update_period_ms.max(1)
            ),
        ));
    }
    if srv.map.held.is_empty() {
        return Err((
            format!("{KEY}.map.held"),
            "expected a held register for every corrected axis (held = [ { axis = \"x\", address = … } ]): without it a restarted box serves from 0 whatever the controller holds, a step of up to the clamp".into(),
        ));
    }
    for (i, r) in srv.map.axes.iter().enumerate() {
        register_holds_clamp(cfg, &format!("{KEY}.map.axis[{i}]"), r)?;
    }
    Ok(())
}
