//! TOML → [`ModelSpec`]: every key read, checked and converted to internal units exactly once.
//! The schema is documented in `docs/model.md`; each problem becomes a [`ConfigIssue`] naming file,
//! line, key and what was expected, and reading continues so one run reports them all.

use std::collections::HashSet;

use super::function::{ErrorFunction, Interpolation, Table};
use super::names::{Axis, ComponentId, parse_component, parse_squareness};
use super::spec::*;
use super::toml_reader::{ConfigError, Ctx, Tbl};
use crate::units::{AngleUnit, LengthUnit};

const TOP_KEYS: &str =
    "schema, machine, axes, tools, components, squareness, sensors, thermal, forces, load";

/// Parse and validate a model file's text. `origin` names the file in messages.
pub fn parse_model(text: &str, origin: &str) -> Result<ModelSpec, ConfigError> {
    let ctx = Ctx::new(origin, text);
    let Some(doc) = ctx.parse() else {
        return Err(ctx.into_error());
    };
    let spec = read_doc(
        &ctx,
        &Tbl::new(&ctx, doc.get_ref(), String::new(), doc.span()),
    );
    match spec {
        Some(s) if !ctx.has_errors() => Ok(s),
        _ => Err(ctx.into_error()),
    }
}

fn unit_list_translation() -> Vec<(String, f64)> {
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

fn unit_list_rotation() -> Vec<(String, f64)> {
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

fn value_units(target: ComponentId) -> Vec<(String, f64)> {
    if target.is_rotation() {
        unit_list_rotation()
    } else {
        unit_list_translation()
    }
}

fn is_identifier(s: &str) -> bool {
    !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

fn read_doc(ctx: &Ctx<'_>, top: &Tbl<'_, '_>) -> Option<ModelSpec> {
    if let Some(v) = top.int_opt("schema")
        && v != 1
    {
        top.err_key(
            "schema",
            format!("unsupported schema {v}; this retrocomp reads schema = 1"),
        );
    }
    let Some(machine) = top.table_opt("machine") else {
        top.err_here("missing table [machine] (name, chain)");
        return None;
    };
    let name = machine.str_req("name", "the machine's name");
    let description = machine.str_opt("description").unwrap_or_default();
    let synthetic = machine.bool_opt("synthetic").unwrap_or(false);
    let chain = machine.str_req(
        "chain",
        "axes from workpiece to tool with F for the frame, e.g. \"X F Y Z\"",
    );
    let tool_axis_s = machine.str_opt("tool_axis");
    machine.finish("name, description, synthetic, chain, tool_axis");

    let mut axes = chain.and_then(|c| parse_chain(&machine, &c))?;
    let tool_axis = match tool_axis_s {
        None => (Axis::Z, -1.0),
        Some(s) => parse_signed_axis(&s).unwrap_or_else(|| {
            machine.err_key(
                "tool_axis",
                format!("expected an axis with optional sign like \"-z\" or \"+x\", found {s:?}"),
            );
            (Axis::Z, -1.0)
        }),
    };
    let in_chain: Vec<Axis> = axes.iter().map(|a| a.axis).collect();

    if let Some(at) = top.table_opt("axes") {
        for key in at.keys() {
            let axis = key
                .chars()
                .next()
                .and_then(Axis::from_letter)
                .filter(|_| key.len() == 1);
            match axis.and_then(|a| axes.iter_mut().find(|s| s.axis == a)) {
                None => at.err_key(
                    &key,
                    format!(
                        "not an axis of the chain; expected one of {:?}",
                        lower_names(&in_chain)
                    ),
                ),
                Some(spec) => {
                    if let Some(t) = at.table_opt(&key) {
                        if let Some(o) = t.vec3_opt("offset_mm") {
                            spec.offset_mm = o;
                        }
                        if let Some(tr) = t.vec_opt("travel_mm") {
                            if tr.len() == 2 && tr[0] < tr[1] {
                                spec.travel_mm = Some((tr[0], tr[1]));
                            } else {
                                t.err_key("travel_mm", "expected [min, max] with min < max");
                            }
                        }
                        t.finish("offset_mm, travel_mm");
                    }
                }
            }
        }
    }

    let mut tools = Vec::new();
    for t in top.tables("tools") {
        let name = t.str_req("name", "tool name").unwrap_or_default();
        let offset_mm = t.vec3_opt("offset_mm").unwrap_or([0.0; 3]);
        if !t.has("offset_mm") {
            t.get("offset_mm");
            t.err_here("missing key `offset_mm` (tool tip relative to the last tool-side carriage, [x, y, z] mm)");
        }
        t.finish("name, offset_mm");
        tools.push(ToolSpec { name, offset_mm });
    }
    if tools.is_empty() {
        top.err_here("at least one [[tools]] entry is needed (name, offset_mm); use offset_mm = [0, 0, 0] when there is no Abbe arm");
    }

    let mut term_names: HashSet<String> = HashSet::new();
    term_names.insert("higher_order".into());
    let mut unique_term = |t: &Tbl<'_, '_>, key: &str, name: &str| {
        if !is_identifier(name) {
            t.err_key(key, format!("term name {name:?} must use only letters, digits and _ (it becomes a CSV column)"));
        } else if !term_names.insert(name.to_string()) {
            t.err_key(key, format!("term name {name:?} is used twice (names must be unique; `higher_order` is reserved)"));
        }
    };

    let mut components = Vec::new();
    for t in top.tables("components") {
        let Some(id) = read_target(&t, "name", &in_chain) else {
            t.finish(COMPONENT_KEYS);
            continue;
        };
        unique_term(&t, "name", &id.iso_name());
        let units = value_units(id);
        if let Some(function) = read_function(&t, "kind", &units) {
            components.push(ComponentSpec { id, function });
        }
        t.finish(COMPONENT_KEYS);
    }

    let mut squareness: Vec<SquarenessSpec> = Vec::new();
    for t in top.tables("squareness") {
        let sq = read_squareness(&t, &in_chain);
        t.finish("name, on_axis, value_urad, value_rad, value_arcsec, value_mm_per_m, value_um_per_m, deviation_mm, over_mm");
        if let Some(s) = sq {
            unique_term(&t, "name", &ModelSpec::squareness_term_name(&s));
            squareness.push(s);
        }
    }

    let mut sensors: Vec<SensorSpec> = Vec::new();
    for t in top.tables("sensors") {
        let name = t
            .str_req("name", "sensor name; the column is T_<name>_C")
            .unwrap_or_default();
        if !is_identifier(&name) {
            t.err_key("name", "sensor name must use only letters, digits and _");
        } else if sensors.iter().any(|s| s.name == name) {
            t.err_key("name", format!("sensor {name:?} is defined twice"));
        }
        let reference_c = t.f64_opt("reference_C").unwrap_or(20.0);
        let tau_s = t.f64_opt("tau_s");
        if let Some(tau) = tau_s
            && tau <= 0.0
        {
            t.err_key(
                "tau_s",
                format!("expected a time constant > 0 s, found {tau}"),
            );
        }
        t.finish("name, reference_C, tau_s");
        sensors.push(SensorSpec {
            name,
            reference_c,
            tau_s,
        });
    }
    let sensor_names: Vec<String> = sensors.iter().map(|s| s.name.clone()).collect();

    let mut thermal = Vec::new();
    for t in top.tables("thermal") {
        let name = t.str_req("name", "term name").unwrap_or_default();
        unique_term(&t, "name", &name);
        let target = read_target(&t, "target", &in_chain);
        let kind = t.str_req("kind", "polynomial_dt, slope, expansion or stations");
        if let (Some(target), Some(kind)) = (target, kind)
            && let Some(k) = read_thermal(&t, &kind, target, &sensor_names, &in_chain)
        {
            thermal.push(ThermalSpec {
                name,
                target,
                kind: k,
            });
        }
        t.finish(THERMAL_KEYS);
    }

    let mut forces: Vec<ForceSpec> = Vec::new();
    for t in top.tables("forces") {
        let name = t
            .str_req("name", "force channel name; the column is F_<name>_N")
            .unwrap_or_default();
        if !is_identifier(&name) {
            t.err_key("name", "force name must use only letters, digits and _");
        } else if forces.iter().any(|f| f.name == name) {
            t.err_key("name", format!("force {name:?} is defined twice"));
        }
        let from_strain = t.str_opt("strain").map(|strain| StrainSource {
            strain,
            gain_n_per_ue: t
                .f64_req("gain_N_per_ue", "N per µm/m of strain")
                .unwrap_or(0.0),
            offset_ue: t.f64_opt("offset_ue").unwrap_or(0.0),
        });
        if from_strain.is_none() && (t.has("gain_N_per_ue") || t.has("offset_ue")) {
            t.err_here(
                "gain_N_per_ue/offset_ue need `strain = \"<name>\"` (the strain_<name>_ue column)",
            );
            t.get("gain_N_per_ue");
            t.get("offset_ue");
        }
        t.finish("name, strain, gain_N_per_ue, offset_ue");
        forces.push(ForceSpec { name, from_strain });
    }
    let force_names: Vec<String> = forces.iter().map(|f| f.name.clone()).collect();

    let mut load = Vec::new();
    for t in top.tables("load") {
        let name = t.str_req("name", "term name").unwrap_or_default();
        unique_term(&t, "name", &name);
        let target = read_target(&t, "target", &in_chain);
        let kind = t.str_req("kind", "compliance or weight_angular");
        let force = t.str_req("force", "a [[forces]] name");
        if let Some(f) = &force
            && !force_names.contains(f)
        {
            t.err_key(
                "force",
                format!("unknown force {f:?}; defined: {force_names:?}"),
            );
        }
        if let (Some(target), Some(kind), Some(force)) = (target, kind, force)
            && let Some(k) = read_load(&t, &kind, target, force)
        {
            load.push(LoadSpec {
                name,
                target,
                kind: k,
            });
        }
        t.finish(LOAD_KEYS);
    }
    top.finish(TOP_KEYS);

    if ctx.has_errors() {
        return None;
    }
    Some(ModelSpec {
        name: name?,
        description,
        synthetic,
        axes,
        tool_axis,
        tools,
        components,
        squareness,
        sensors,
        thermal,
        forces,
        load,
    })
}

const COMPONENT_KEYS: &str = "name, kind, positions_mm, forward_<unit>, reverse_<unit>, interpolation, \
coefficients_<unit>, knots_mm, knot_coefficients_<unit>, range_mm";
const THERMAL_KEYS: &str = "name, target, kind, sensors, sensor, e0_<u>, b_<u>_per_K, c_<u>_per_K2, s0_<u>_per_m, \
s_<u>_per_m_K, d_<u>_per_m_K2, alpha_ppm_per_K, origin_mm, reference_C, along, stations_mm (<u> = um or urad)";
const LOAD_KEYS: &str = "name, target, kind, shape, force, reference_force_N, lever_mm, load_height_mm, positions_mm, \
forward_<unit>, reverse_<unit>, interpolation, coefficients_<unit>, knots_mm, knot_coefficients_<unit>, range_mm";

fn lower_names(axes: &[Axis]) -> Vec<String> {
    axes.iter().map(|a| a.lower().to_string()).collect()
}

fn parse_signed_axis(s: &str) -> Option<(Axis, f64)> {
    let s = s.trim();
    let (sign, rest) = match s.strip_prefix('-') {
        Some(r) => (-1.0, r),
        None => (1.0, s.strip_prefix('+').unwrap_or(s)),
    };
    let mut chars = rest.chars();
    let a = Axis::from_letter(chars.next()?)?;
    chars.next().is_none().then_some((a, sign))
}

fn parse_chain(machine: &Tbl<'_, '_>, chain: &str) -> Option<Vec<AxisSpec>> {
    let mut axes: Vec<AxisSpec> = Vec::new();
    let tokens: Vec<&str> = chain.split_whitespace().collect();
    let has_frame = tokens.iter().any(|t| t.eq_ignore_ascii_case("F"));
    let mut branch = if has_frame {
        Branch::Workpiece
    } else {
        Branch::Tool
    };
    let mut frames = 0;
    let bad = |msg: String| {
        machine.err_key("chain", format!("{msg}; expected 2 or 3 of X, Y, Z from workpiece to tool with F for the frame, e.g. \"X F Y Z\" or \"Z X\""));
        None
    };
    for tok in &tokens {
        if tok.eq_ignore_ascii_case("F") {
            frames += 1;
            branch = Branch::Tool;
            continue;
        }
        let axis = match (tok.len(), tok.chars().next().and_then(Axis::from_letter)) {
            (1, Some(a)) => a,
            _ => return bad(format!("unknown element {tok:?}")),
        };
        if axes.iter().any(|s| s.axis == axis) {
            return bad(format!("axis {} appears twice", axis.upper()));
        }
        axes.push(AxisSpec {
            axis,
            branch,
            offset_mm: [0.0; 3],
            travel_mm: None,
        });
    }
    if frames > 1 {
        return bad("F appears more than once".into());
    }
    if !(2..=3).contains(&axes.len()) {
        return bad(format!("found {} axes", axes.len()));
    }
    Some(axes)
}

/// Read a component name (`name` or `target` key) whose axis must be in the chain.
fn read_target(t: &Tbl<'_, '_>, key: &str, in_chain: &[Axis]) -> Option<ComponentId> {
    let n = t.str_req(key, "an ISO 230-1 component such as EXX, EYZ, EBX")?;
    match parse_component(&n) {
        None => {
            t.err_key(key, format!("unknown component {n:?}; expected an ISO 230-1 name E[XYZABC][XYZ] or a seed alias (see src/models/names.rs)"));
            None
        }
        Some(id) if !in_chain.contains(&id.axis) => {
            t.err_key(
                key,
                format!(
                    "{n} depends on axis {} which is not in the chain {:?}",
                    id.axis,
                    lower_names(in_chain)
                ),
            );
            None
        }
        Some(id) => Some(id),
    }
}

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
    Some((v.into_iter().map(|x| x * factor).collect(), unit))
}

/// One error function from the keys of `t`; `prefix` is prepended to value keys (unused: "").
fn read_function(
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
        "table" => {
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
        "polynomial" => {
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
        "piecewise_quadratic" => {
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
        other => {
            t.err_key(kind_key, format!("unknown function shape {other:?}; expected table, polynomial or piecewise_quadratic"));
            None
        }
    }
}

fn read_squareness(t: &Tbl<'_, '_>, in_chain: &[Axis]) -> Option<SquarenessSpec> {
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
            t.f64_opt(&key)? * f
        }
        None => match (t.f64_opt("deviation_mm"), t.f64_opt("over_mm")) {
            (Some(d), Some(l)) if l > 0.0 => d / l * 1e6,
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

fn read_thermal(
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
        "polynomial_dt" => {
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
        "slope" => {
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
        "expansion" => {
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
        "stations" => {
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
        other => {
            t.err_key("kind", format!("unknown thermal kind {other:?}; expected polynomial_dt, slope, expansion or stations"));
            None
        }
    }
}

fn read_load(t: &Tbl<'_, '_>, kind: &str, target: ComponentId, force: String) -> Option<LoadKind> {
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
