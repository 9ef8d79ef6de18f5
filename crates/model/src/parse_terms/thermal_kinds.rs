//! The thermal term kinds `read_thermal` dispatches to, once it has checked the keys' unit
//! (`u` is `um` or `urad`, the target's). Each checks its own keys against the sensors.

use super::{read_sensor_list, read_square};
use crate::names::{Axis, ComponentId, lower_names};
use crate::spec::ThermalKind;
use crate::toml_reader::Tbl;

/// `kind = "polynomial_dt"`: e0 + Σ b ΔT + Σ c ΔT ΔT over the listed sensors.
pub(super) fn read_polynomial_dt(
    t: &Tbl<'_, '_>,
    u: &str,
    sensors: &[String],
) -> Option<ThermalKind> {
    let s = read_sensor_list(t, sensors)?;
    let e0 = t.f64_opt(&format!("e0_{u}")).unwrap_or(0.0);
    let b = t.vec_opt(&format!("b_{u}_per_K")).unwrap_or_default();
    if b.len() != s.len() {
        t.err_key(
            &format!("b_{u}_per_K"),
            format!(
                "expected {} values (one per sensor), found {}",
                s.len(),
                b.len()
            ),
        );
        return None;
    }
    let c = read_square(t, &format!("c_{u}_per_K2"), s.len())?;
    Some(ThermalKind::PolynomialDt {
        sensors: s,
        e0,
        b_per_k: b,
        c_per_k2: c,
    })
}

/// `kind = "slope"`: a slope per metre of the target's travel, linear and quadratic in ΔT.
pub(super) fn read_slope(t: &Tbl<'_, '_>, u: &str, sensors: &[String]) -> Option<ThermalKind> {
    let s = read_sensor_list(t, sensors)?;
    let s0 = t.f64_opt(&format!("s0_{u}_per_m")).unwrap_or(0.0);
    let sv = t.vec_opt(&format!("s_{u}_per_m_K")).unwrap_or_default();
    if sv.len() != s.len() {
        t.err_key(
            &format!("s_{u}_per_m_K"),
            format!(
                "expected {} values (one per sensor), found {}",
                s.len(),
                sv.len()
            ),
        );
        return None;
    }
    let d = read_square(t, &format!("d_{u}_per_m_K2"), s.len())?;
    Some(ThermalKind::Slope {
        sensors: s,
        s0_per_mm: s0,
        s_per_mm_k: sv,
        d_per_mm_k2: d,
    })
}

/// `kind = "expansion"`: a scale's expansion from one sensor; translations only.
pub(super) fn read_expansion(
    t: &Tbl<'_, '_>,
    target: ComponentId,
    sensors: &[String],
) -> Option<ThermalKind> {
    if target.is_rotation() {
        t.err_key("target", "expansion needs a translation target (e.g. EXX)");
        return None;
    }
    let sensor = t.str_req("sensor", "the [[sensors]] name of the scale temperature")?;
    if !sensors.contains(&sensor) {
        t.err_key(
            "sensor",
            format!("unknown sensor {sensor:?}; defined: {sensors:?}"),
        );
        return None;
    }
    let alpha = t.f64_req(
        "alpha_ppm_per_K",
        "expansion coefficient, e.g. 11.5 for steel",
    )?;
    let origin = t.f64_opt("origin_mm").unwrap_or(0.0);
    let reference = t.f64_opt("reference_C").unwrap_or(20.0);
    Some(ThermalKind::Expansion {
        sensor,
        alpha_ppm_per_k: alpha,
        origin_mm: origin,
        reference_c: reference,
    })
}

/// `kind = "stations"`: per station along an axis of the chain e0 + Σ b ΔT, linear in between.
pub(super) fn read_stations(
    t: &Tbl<'_, '_>,
    u: &str,
    sensors: &[String],
    in_chain: &[Axis],
) -> Option<ThermalKind> {
    let s = read_sensor_list(t, sensors)?;
    let along = t.str_req("along", "the axis the stations lie on")?;
    let Some(along) = along
        .chars()
        .next()
        .and_then(Axis::from_letter)
        .filter(|a| along.len() == 1 && in_chain.contains(a))
    else {
        t.err_key(
            "along",
            format!(
                "expected an axis of the chain {:?}, found {along:?}",
                lower_names(in_chain)
            ),
        );
        return None;
    };
    let st = t.vec_opt("stations_mm")?;
    if st.len() < 2 || st.windows(2).any(|w| w[1] <= w[0]) {
        t.err_key("stations_mm", "expected ≥ 2 strictly increasing positions");
        return None;
    }
    let e0 = if t.has(&format!("e0_{u}")) {
        t.vec_opt(&format!("e0_{u}"))?
    } else {
        vec![0.0; st.len()]
    };
    if e0.len() != st.len() {
        t.err_key(
            &format!("e0_{u}"),
            format!("expected {} values (one per station)", st.len()),
        );
        return None;
    }
    let key = format!("b_{u}_per_K");
    let b = t.matrix_opt(&key).unwrap_or_default();
    if b.len() != st.len() || b.iter().any(|r| r.len() != s.len()) {
        t.err_key(
            &key,
            format!(
                "expected {} rows (stations) of {} values (sensors)",
                st.len(),
                s.len()
            ),
        );
        return None;
    }
    Some(ThermalKind::Stations {
        along,
        sensors: s,
        stations_mm: st,
        e0,
        b_per_k: b,
    })
}
