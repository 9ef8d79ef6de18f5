//! Readers for the parts of a model file that carry values: error functions (tables, polynomials,
//! piecewise quadratics), squareness, thermal and load terms. Units are converted here, once.

use super::function::ErrorFunction;
use super::names::{Axis, ComponentId, lower_names, parse_squareness};
use super::spec::*;
use super::toml_reader::Tbl;
use crate::units::{AngleUnit, LengthUnit};

mod shapes;
mod thermal_kinds;

/// Read the one `{prefix}_{unit}` key, converted by the unit's factor.
fn read_scaled_vec(
    t: &Tbl<'_, '_>,
    prefix: &str,
    units: &[(String, f64)],
) -> Option<(Vec<f64>, String)> {
    let names: Vec<&str> = units.iter().map(|u| u.0.as_str()).collect();
    let Some((unit, key)) = t.find_suffixed(prefix, &names) else {
        // A key with this prefix in a unit that does not fit (e.g. `_um` for a rotation).
        let start = format!("{prefix}_");
        for k in t.keys().into_iter().filter(|k| k.starts_with(&start)) {
            let rest = &k[start.len()..];
            if !names.contains(&rest) {
                t.get(&k);
                t.err_key(
                    &k,
                    format!("unit `{rest}` does not fit here; expected {prefix}_<unit> with unit one of {}", names.join("|")),
                );
            }
        }
        return None;
    };
    let factor = units
        .iter()
        .find(|u| u.0 == unit)
        .map(|u| u.1)
        .unwrap_or(1.0);
    let v = t.vec_opt(&key)?;
    let v: Vec<f64> = v.into_iter().map(|x| x * factor).collect();
    if let Some(bad) = v.iter().position(|x| !x.is_finite()) {
        // Finite in the file but not after the unit conversion (e.g. 1e306 mm in µm).
        t.err_key(
            &key,
            format!(
                "value [{bad}] is {} after conversion from {unit} to internal units: expected a finite value",
                v[bad]
            ),
        );
        return None;
    }
    Some((v, unit))
}

/// One error function from the keys of `t`: its shape from `kind_key` (or from which keys are
/// present), its values in one of `units` (name, factor to the model unit).
pub(super) fn read_function(
    t: &Tbl<'_, '_>,
    kind_key: &str,
    units: &[(String, f64)],
) -> Option<ErrorFunction> {
    let unit_names: Vec<&str> = units.iter().map(|u| u.0.as_str()).collect();
    let suffix_hint = unit_names.join("|");
    let kind = t.str_opt(kind_key).unwrap_or_else(|| {
        if t.has("positions_mm") {
            "table".into()
        } else if t.has("knots_mm") {
            "piecewise_quadratic".into()
        } else {
            "polynomial".into()
        }
    });
    let range_mm = t.vec_opt("range_mm").and_then(|r| {
        if r.len() == 2 && r[0] < r[1] {
            Some((r[0], r[1]))
        } else {
            t.err_key("range_mm", "expected [min, max] with min < max");
            None
        }
    });
    match kind.as_str() {
        "table" => shapes::read_table(t, units, range_mm, &suffix_hint),
        "polynomial" => shapes::read_polynomial(t, units, range_mm, &suffix_hint),
        "piecewise_quadratic" => shapes::read_piecewise_quadratic(t, units, range_mm, &suffix_hint),
        other => {
            t.err_key(kind_key, format!("unknown function shape {other:?}; expected table, polynomial or piecewise_quadratic"));
            None
        }
    }
}

pub(super) fn read_squareness(t: &Tbl<'_, '_>, in_chain: &[Axis]) -> Option<SquarenessSpec> {
    let name = t.str_req("name", "EC0Y, EB0Z or EA0Z")?;
    let Some(kind) = parse_squareness(&name) else {
        t.err_key(
            "name",
            format!("unknown squareness {name:?}; expected EC0Y (X–Y), EB0Z (X–Z) or EA0Z (Y–Z)"),
        );
        return None;
    };
    let (a, b, _) = kind.axes();
    let on_axis = match t.str_opt("on_axis") {
        None => b,
        Some(s) => match s
            .chars()
            .next()
            .and_then(Axis::from_letter)
            .filter(|_| s.len() == 1)
        {
            Some(x) if x == a || x == b => x,
            _ => {
                t.err_key(
                    "on_axis",
                    format!("expected \"{a}\" or \"{b}\" (an axis of {name}), found {s:?}"),
                );
                return None;
            }
        },
    };
    if !in_chain.contains(&on_axis) {
        t.err_key(
            "name",
            format!(
                "{name} is carried by axis {on_axis}, which is not in the chain {:?}",
                lower_names(in_chain)
            ),
        );
        return None;
    }
    let units = unit_list_rotation();
    let names: Vec<&str> = units.iter().map(|u| u.0.as_str()).collect();
    let value_urad = match t.find_suffixed("value", &names) {
        Some((unit, key)) => {
            let f = units.iter().find(|u| u.0 == unit).unwrap().1;
            let v = t.f64_opt(&key)? * f;
            if !v.is_finite() {
                t.err_key(
                    &key,
                    format!("{v} µrad after conversion from {unit}: expected a finite value"),
                );
                return None;
            }
            v
        }
        None => match (t.f64_opt("deviation_mm"), t.f64_opt("over_mm")) {
            (Some(d), Some(l)) if l > 0.0 && (d / l * 1e6).is_finite() => d / l * 1e6,
            (Some(_), Some(l)) if l > 0.0 => {
                t.err_key(
                    "deviation_mm",
                    "deviation_mm / over_mm is not finite in µrad: expected a finite ratio",
                );
                return None;
            }
            (Some(_), Some(l)) => {
                t.err_key("over_mm", format!("expected a length > 0, found {l}"));
                return None;
            }
            _ => {
                t.err_here(format!(
                    "squareness needs value_<unit> ({}) or deviation_mm + over_mm",
                    names.join("|")
                ));
                return None;
            }
        },
    };
    Some(SquarenessSpec {
        kind,
        on_axis,
        value_urad,
    })
}

fn read_sensor_list(t: &Tbl<'_, '_>, sensors: &[String]) -> Option<Vec<String>> {
    let list = match t.strings_opt("sensors") {
        Some(l) => l,
        None => {
            if !t.has("sensors") {
                t.err_here("missing key `sensors` (names of [[sensors]] entries)");
            }
            return None;
        }
    };
    let mut ok = true;
    for s in &list {
        if !sensors.contains(s) {
            t.err_key(
                "sensors",
                format!("unknown sensor {s:?}; defined: {sensors:?}"),
            );
            ok = false;
        }
    }
    ok.then_some(list)
}

fn read_square(t: &Tbl<'_, '_>, key: &str, n: usize) -> Option<Vec<Vec<f64>>> {
    if !t.has(key) {
        return Some(Vec::new());
    }
    let m = t.matrix_opt(key)?;
    if m.len() != n || m.iter().any(|r| r.len() != n) {
        t.err_key(
            key,
            format!("expected a {n}×{n} matrix (one row and column per sensor)"),
        );
        return None;
    }
    Some(m)
}

pub(super) fn read_thermal(
    t: &Tbl<'_, '_>,
    kind: &str,
    target: ComponentId,
    sensors: &[String],
    in_chain: &[Axis],
) -> Option<ThermalKind> {
    let (u, other) = if target.is_rotation() {
        ("urad", "um")
    } else {
        ("um", "urad")
    };
    // A key in the wrong unit for the target is a clear mistake; say so and stop here.
    let mut wrong_unit = false;
    for k in t.keys() {
        if k.contains(&format!("_{other}")) && !k.starts_with("alpha") {
            wrong_unit = true;
            t.err_key(
                &k,
                format!(
                    "target {} is a {}: use the `_{u}` form of this key",
                    target.iso_name(),
                    if target.is_rotation() {
                        "rotation (µrad)"
                    } else {
                        "translation (µm)"
                    }
                ),
            );
            t.get(&k);
        }
    }
    if wrong_unit {
        return None;
    }
    match kind {
        "polynomial_dt" => thermal_kinds::read_polynomial_dt(t, u, sensors),
        "slope" => thermal_kinds::read_slope(t, u, sensors),
        "expansion" => thermal_kinds::read_expansion(t, target, sensors),
        "stations" => thermal_kinds::read_stations(t, u, sensors, in_chain),
        other => {
            t.err_key("kind", format!("unknown thermal kind {other:?}; expected polynomial_dt, slope, expansion or stations"));
            None
        }
    }
}

pub(super) fn read_load(
    t: &Tbl<'_, '_>,
    kind: &str,
    target: ComponentId,
    force: String,
) -> Option<LoadKind> {
    match kind {
        "compliance" => {
            let units: Vec<(String, f64)> = if target.is_rotation() {
                vec![("urad_per_N".into(), 1.0)]
            } else {
                vec![("um_per_N".into(), 1.0), ("mm_per_N".into(), 1e3)]
            };
            let compliance = read_function(t, "shape", &units)?;
            Some(LoadKind::Compliance { force, compliance })
        }
        "weight_angular" => {
            let reference = read_function(t, "shape", &value_units(target))?;
            let reference_force_n = t.f64_req(
                "reference_force_N",
                "the load the reference profile was measured with",
            )?;
            let lever_mm = t.f64_req(
                "lever_mm",
                "distance from the load to the guideway centroid (Spaan: 375 mm)",
            )?;
            let load_height_mm = t.f64_opt("load_height_mm").unwrap_or(0.0);
            if reference_force_n == 0.0 || lever_mm == 0.0 {
                t.err_here("reference_force_N and lever_mm must be non-zero");
                return None;
            }
            Some(LoadKind::WeightAngular {
                force,
                reference,
                reference_force_n,
                lever_mm,
                load_height_mm,
            })
        }
        other => {
            t.err_key(
                "kind",
                format!("unknown load kind {other:?}; expected compliance or weight_angular"),
            );
            None
        }
    }
}

// Unit suffixes of term values (`_um`, `_mm`, `_urad`, …) and their factors to internal units.
pub(super) fn unit_list_translation() -> Vec<(String, f64)> {
    LengthUnit::SUFFIXES
        .iter()
        .map(|s| {
            (
                s.to_string(),
                LengthUnit::from_suffix(s).unwrap().to_um_factor(),
            )
        })
        .collect()
}

pub(super) fn unit_list_rotation() -> Vec<(String, f64)> {
    AngleUnit::SUFFIXES
        .iter()
        .map(|s| {
            (
                s.to_string(),
                AngleUnit::from_suffix(s).unwrap().to_urad_factor(),
            )
        })
        .collect()
}

pub(super) fn value_units(target: ComponentId) -> Vec<(String, f64)> {
    if target.is_rotation() {
        unit_list_rotation()
    } else {
        unit_list_translation()
    }
}
