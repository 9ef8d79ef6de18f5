//! The function shapes `read_function` dispatches to: a table, a polynomial, a piecewise quadratic.
//! Each checks its own keys; `range_mm` is read once by the caller and handed in.

use super::read_scaled_vec;
use crate::function::{ErrorFunction, Interpolation, Table};
use crate::toml_reader::Tbl;

/// `kind = "table"`: positions with forward (and optional reverse) values, linear or C¹.
pub(super) fn read_table(
    t: &Tbl<'_, '_>,
    units: &[(String, f64)],
    range_mm: Option<(f64, f64)>,
    suffix_hint: &str,
) -> Option<ErrorFunction> {
    let Some(positions) = t.vec_opt("positions_mm") else {
        if !t.has("positions_mm") {
            t.err_here("a table needs `positions_mm` (strictly increasing, ≥ 2 points)");
        }
        return None;
    };
    let fwd = read_scaled_vec(t, "forward", units);
    if fwd.is_none() && !t.keys().iter().any(|k| k.starts_with("forward_")) {
        t.err_here(format!(
            "a table needs `forward_<unit>` with unit one of {suffix_hint}"
        ));
    }
    let rev = read_scaled_vec(t, "reverse", units);
    let interpolation = match t.str_opt("interpolation").as_deref() {
        None | Some("linear") => Interpolation::Linear,
        Some("c1") => Interpolation::C1,
        Some(other) => {
            t.err_key(
                "interpolation",
                format!("expected \"linear\" or \"c1\", found {other:?}"),
            );
            Interpolation::Linear
        }
    };
    if positions.len() < 2 {
        t.err_key(
            "positions_mm",
            format!("expected at least 2 points, found {}", positions.len()),
        );
        return None;
    }
    if let Some(i) = positions.windows(2).position(|w| w[1] <= w[0]) {
        t.err_key(
            "positions_mm",
            format!(
                "positions must increase strictly: [{}] = {} is not above [{}] = {}",
                i + 1,
                positions[i + 1],
                i,
                positions[i]
            ),
        );
        return None;
    }
    let (fwd, fwd_unit) = fwd?;
    if !plausible(t, "forward", &fwd_unit, &fwd, suffix_hint) {
        return None;
    }
    if fwd.len() != positions.len() {
        t.err_key(
            &format!("forward_{fwd_unit}"),
            format!(
                "expected {} values (one per position), found {}",
                positions.len(),
                fwd.len()
            ),
        );
        return None;
    }
    let rev = match rev {
        None => fwd.clone(),
        Some((r, ru)) => {
            if !plausible(t, "reverse", &ru, &r, suffix_hint) {
                return None;
            }
            if r.len() != positions.len() {
                t.err_key(
                    &format!("reverse_{ru}"),
                    format!(
                        "expected {} values (one per position), found {}",
                        positions.len(),
                        r.len()
                    ),
                );
                return None;
            }
            r
        }
    };
    if range_mm.is_some() {
        t.err_key(
            "range_mm",
            "a table's range is its positions; range_mm is for polynomials",
        );
    }
    Some(ErrorFunction::Table(Table::new(
        positions,
        fwd,
        rev,
        interpolation,
    )))
}

/// Largest |value| a geometric error table may hold, in internal units (µm, µrad): 10 mm, or
/// 10 mm over a metre. Beyond it the unit is wrong, not the machine (the sink's clamp cannot be set
/// above 10 mm either: `gateway::safety::MAX_CORRECTION_LIMIT_UM`).
const TABLE_LIMIT_INTERNAL: f64 = 10_000.0;

/// Largest |value| written in the coarse length unit `_mm`, mm: a geometric error of more than
/// 1 mm on a machine that is compensated at all is almost surely µm written under `_mm`.
const TABLE_LIMIT_MM: f64 = 1.0;

/// The unit suffix of a table's values checked against their magnitude: a translation (µm) or
/// rotation (µrad) table beyond [`TABLE_LIMIT_INTERNAL`], or an `_mm` table beyond
/// [`TABLE_LIMIT_MM`], is refused at its key. Other quantities (compliance per N) pass. `values`
/// are already in internal units.
fn plausible(t: &Tbl<'_, '_>, prefix: &str, unit: &str, values: &[f64], suffix_hint: &str) -> bool {
    let internal = if crate::units::LengthUnit::from_suffix(unit).is_some() {
        "µm"
    } else if crate::units::AngleUnit::from_suffix(unit).is_some() {
        "µrad"
    } else {
        return true;
    };
    let Some((i, &v)) = values
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
    else {
        return true;
    };
    let key = format!("{prefix}_{unit}");
    if unit == "mm" && v.abs() > TABLE_LIMIT_MM * 1e3 {
        t.err_key(
            &key,
            format!(
                "value [{i}] is {} mm ({v} µm): expected |value| ≤ {TABLE_LIMIT_MM} mm for a geometric error; if these numbers are µm, write {prefix}_um",
                v / 1e3
            ),
        );
        return false;
    }
    if v.abs() > TABLE_LIMIT_INTERNAL {
        t.err_key(
            &key,
            format!(
                "value [{i}] is {v:e} {internal} after conversion from {unit}: expected |value| ≤ {TABLE_LIMIT_INTERNAL} {internal} (check the unit suffix, one of {suffix_hint})"
            ),
        );
        return false;
    }
    true
}

/// `kind = "polynomial"`: Σ a_i·q^i, optionally limited to `range_mm`.
pub(super) fn read_polynomial(
    t: &Tbl<'_, '_>,
    units: &[(String, f64)],
    range_mm: Option<(f64, f64)>,
    suffix_hint: &str,
) -> Option<ErrorFunction> {
    let Some((coefficients, _)) = read_scaled_vec(t, "coefficients", units) else {
        if t.keys().iter().any(|k| k.starts_with("coefficients_")) {
            return None;
        }
        t.err_here(format!("a polynomial needs `coefficients_<unit>` = [a0, a1, …] (value = Σ a_i·q^i, q in mm), unit one of {suffix_hint}"));
        return None;
    };
    if coefficients.is_empty() {
        t.err_here("polynomial coefficients are empty");
        return None;
    }
    Some(ErrorFunction::Polynomial {
        coefficients,
        range_mm,
    })
}

/// `kind = "piecewise_quadratic"`: a quadratic base plus one coefficient per knot.
pub(super) fn read_piecewise_quadratic(
    t: &Tbl<'_, '_>,
    units: &[(String, f64)],
    range_mm: Option<(f64, f64)>,
    suffix_hint: &str,
) -> Option<ErrorFunction> {
    let base = read_scaled_vec(t, "coefficients", units);
    let knots = t.vec_opt("knots_mm").unwrap_or_default();
    let kc = read_scaled_vec(t, "knot_coefficients", units)
        .map(|v| v.0)
        .unwrap_or_default();
    let Some((base, _)) = base else {
        t.err_here(format!("a piecewise_quadratic needs `coefficients_<unit>` = [b0, b1, b2], unit one of {suffix_hint}"));
        return None;
    };
    if base.len() != 3 {
        t.err_here(format!(
            "piecewise_quadratic coefficients: expected 3 values [b0, b1, b2], found {}",
            base.len()
        ));
        return None;
    }
    if knots.len() != kc.len() {
        t.err_key(
            "knots_mm",
            format!(
                "expected one knot coefficient per knot: {} knots, {} coefficients",
                knots.len(),
                kc.len()
            ),
        );
        return None;
    }
    if knots.windows(2).any(|w| w[1] <= w[0]) {
        t.err_key("knots_mm", "knots must increase strictly");
        return None;
    }
    Some(ErrorFunction::PiecewiseQuadratic {
        base: [base[0], base[1], base[2]],
        knots_mm: knots,
        knot_coefficients: kc,
        range_mm,
    })
}
