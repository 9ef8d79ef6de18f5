//! TOML → [`ModelSpec`]: every key read, checked and converted to internal units exactly once.
//! The schema is documented in `docs/model.md`; each problem becomes a [`ConfigIssue`](crate::ConfigIssue) naming file,
//! line, key and what was expected, and reading continues so one run reports them all.

use std::collections::HashSet;

use super::names::{Axis, ComponentId, lower_names, parse_component};
use super::parse_terms::{read_function, read_load, read_squareness, read_thermal, value_units};
use super::spec::*;
use super::toml_reader::{ConfigError, Ctx, Tbl};

const TOP_KEYS: &str = "schema, machine, axes, tools, components, squareness, sensors, thermal, forces, load, \
lag_state";

/// Parse and validate a model file's text. `origin` names the file in messages.
pub(crate) fn parse_model(text: &str, origin: &str) -> Result<ModelSpec, ConfigError> {
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

fn is_identifier(s: &str) -> bool {
    !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// What `[machine]` gives: the chain (with the tool axis) every later table is checked against.
struct Machine {
    name: Option<String>,
    description: String,
    synthetic: bool,
    axes: Vec<AxisSpec>,
    tool_axis: (Axis, f64),
}

/// Term names seen so far: each becomes a CSV column, so two terms may not share one.
struct TermNames(HashSet<String>);

impl TermNames {
    fn new() -> TermNames {
        let mut term_names: HashSet<String> = HashSet::new();
        term_names.insert("higher_order".into());
        TermNames(term_names)
    }

    /// Report `name` (at `key` of `t`) when it is not column-safe or is already taken.
    fn claim(&mut self, t: &Tbl<'_, '_>, key: &str, name: &str) {
        if !is_identifier(name) {
            t.err_key(key, format!("term name {name:?} must use only letters, digits and _ (it becomes a CSV column)"));
        } else if !self.0.insert(name.to_string()) {
            t.err_key(key, format!("term name {name:?} is used twice (names must be unique; `higher_order` is reserved)"));
        }
    }
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
    let Machine {
        name,
        description,
        synthetic,
        mut axes,
        tool_axis,
    } = read_machine(top)?;
    let in_chain: Vec<Axis> = axes.iter().map(|a| a.axis).collect();
    read_axes(top, &mut axes, &in_chain);
    let tools = read_tools(top);

    let mut term_names = TermNames::new();
    let components = read_components(top, &in_chain, &mut term_names);
    let squareness = read_squareness_tables(top, &in_chain, &mut term_names);
    let sensors = read_sensors(top);
    let sensor_names: Vec<String> = sensors.iter().map(|s| s.name.clone()).collect();
    let thermal = read_thermal_terms(top, &in_chain, &sensor_names, &mut term_names);
    let forces = read_forces(top);
    let force_names: Vec<String> = forces.iter().map(|f| f.name.clone()).collect();
    let load = read_load_terms(top, &in_chain, &force_names, &mut term_names);
    let lag_state = top
        .table_opt("lag_state")
        .and_then(|t| read_lag_state(&t, &sensors));
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
        lag_state,
    })
}

/// `[machine]`; `None` when there is no usable chain, since every later table is checked against it.
fn read_machine(top: &Tbl<'_, '_>) -> Option<Machine> {
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

    let axes = chain.and_then(|c| parse_chain(&machine, &c))?;
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
    Some(Machine {
        name,
        description,
        synthetic,
        axes,
        tool_axis,
    })
}

/// `[axes.<a>]`: per chain axis its offset and travel.
fn read_axes(top: &Tbl<'_, '_>, axes: &mut [AxisSpec], in_chain: &[Axis]) {
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
                        lower_names(in_chain)
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
}

/// `[[tools]]`: at least one, each with its tip offset (the Abbe arm).
fn read_tools(top: &Tbl<'_, '_>) -> Vec<ToolSpec> {
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
    tools
}

/// `[[components]]`: the ISO 230-1 geometric errors, one function each.
fn read_components(
    top: &Tbl<'_, '_>,
    in_chain: &[Axis],
    term_names: &mut TermNames,
) -> Vec<ComponentSpec> {
    let mut components = Vec::new();
    for t in top.tables("components") {
        let Some(id) = read_target(&t, "name", in_chain) else {
            t.finish(COMPONENT_KEYS);
            continue;
        };
        term_names.claim(&t, "name", &id.iso_name());
        let units = value_units(id);
        if let Some(function) = read_function(&t, "kind", &units) {
            components.push(ComponentSpec { id, function });
        }
        t.finish(COMPONENT_KEYS);
    }
    components
}

/// `[[squareness]]`: one angle per pair of axes.
fn read_squareness_tables(
    top: &Tbl<'_, '_>,
    in_chain: &[Axis],
    term_names: &mut TermNames,
) -> Vec<SquarenessSpec> {
    let mut squareness: Vec<SquarenessSpec> = Vec::new();
    for t in top.tables("squareness") {
        let sq = read_squareness(&t, in_chain);
        t.finish("name, on_axis, value_urad, value_rad, value_arcsec, value_mm_per_m, value_um_per_m, deviation_mm, over_mm");
        if let Some(s) = sq {
            term_names.claim(&t, "name", &ModelSpec::squareness_term_name(&s));
            squareness.push(s);
        }
    }
    squareness
}

/// `[[sensors]]`: the temperature inputs thermal terms and `[lag_state]` refer to by name.
fn read_sensors(top: &Tbl<'_, '_>) -> Vec<SensorSpec> {
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
        let column = t.str_opt("column");
        if let Some(c) = &column
            && (c.is_empty() || !c.chars().all(|ch| ch.is_ascii_alphanumeric() || ch == '_'))
        {
            t.err_key(
                "column",
                format!("expected a column name of letters, digits and _, found {c:?}"),
            );
        }
        let exponent = t.f64_opt("exponent");
        if let Some(p) = exponent
            && !(p > 0.0 && p <= 4.0)
        {
            t.err_key(
                "exponent",
                format!("expected a power 0 < exponent ≤ 4 of the column's reading, found {p}"),
            );
        }
        t.finish("name, reference_C, tau_s, column, exponent");
        sensors.push(SensorSpec {
            name,
            reference_c,
            tau_s,
            column,
            exponent,
        });
    }
    sensors
}

/// `[[thermal]]`: terms driven by the sensors, read by kind in `parse_terms.rs`.
fn read_thermal_terms(
    top: &Tbl<'_, '_>,
    in_chain: &[Axis],
    sensor_names: &[String],
    term_names: &mut TermNames,
) -> Vec<ThermalSpec> {
    let mut thermal = Vec::new();
    for t in top.tables("thermal") {
        let name = t.str_req("name", "term name").unwrap_or_default();
        term_names.claim(&t, "name", &name);
        let target = read_target(&t, "target", in_chain);
        let kind = t.str_req("kind", "polynomial_dt, slope, expansion or stations");
        if let (Some(target), Some(kind)) = (target, kind)
            && let Some(k) = read_thermal(&t, &kind, target, sensor_names, in_chain)
        {
            thermal.push(ThermalSpec {
                name,
                target,
                kind: k,
            });
        }
        t.finish(THERMAL_KEYS);
    }
    thermal
}

/// `[[forces]]`: the force inputs load terms refer to, read directly or from a strain column.
fn read_forces(top: &Tbl<'_, '_>) -> Vec<ForceSpec> {
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
    forces
}

/// `[[load]]`: terms driven by a force channel, read by kind in `parse_terms.rs`.
fn read_load_terms(
    top: &Tbl<'_, '_>,
    in_chain: &[Axis],
    force_names: &[String],
    term_names: &mut TermNames,
) -> Vec<LoadSpec> {
    let mut load = Vec::new();
    for t in top.tables("load") {
        let name = t.str_req("name", "term name").unwrap_or_default();
        term_names.claim(&t, "name", &name);
        let target = read_target(&t, "target", in_chain);
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
    load
}

/// `[lag_state]`: `t_s` and `lagged = { <sensor> = <lagged input> }`, each a sensor with `tau_s`.
fn read_lag_state(t: &Tbl<'_, '_>, sensors: &[SensorSpec]) -> Option<LagState> {
    let t_s = t.f64_req("t_s", "the recording time of the stored lag states, s");
    let mut lagged = Vec::new();
    if let Some(l) = t.table_opt("lagged") {
        let keys = l.keys();
        for k in &keys {
            let Some(v) = l.f64_opt(k) else { continue };
            match sensors.iter().find(|s| &s.name == k) {
                Some(s) if s.tau_s.is_some() && v.is_finite() => lagged.push((k.clone(), v)),
                Some(s) if s.tau_s.is_some() => {
                    l.err_key(k, format!("expected a finite lagged value, found {v}"));
                }
                Some(_) => l.err_key(k, "sensor has no tau_s: there is no lag state to store"),
                None => l.err_key(
                    k,
                    format!(
                        "unknown sensor; defined: {:?}",
                        sensors.iter().map(|s| &s.name).collect::<Vec<_>>()
                    ),
                ),
            }
        }
        l.finish(&keys.join(", "));
    } else {
        t.err_here("missing table lagged = { <sensor> = <lagged value> }");
    }
    t.finish("t_s, lagged");
    Some(LagState { t_s: t_s?, lagged })
}

const COMPONENT_KEYS: &str = "name, kind, positions_mm, forward_<unit>, reverse_<unit>, interpolation, \
coefficients_<unit>, knots_mm, knot_coefficients_<unit>, range_mm";
const THERMAL_KEYS: &str = "name, target, kind, sensors, sensor, e0_<u>, b_<u>_per_K, c_<u>_per_K2, s0_<u>_per_m, \
s_<u>_per_m_K, d_<u>_per_m_K2, alpha_ppm_per_K, origin_mm, reference_C, along, stations_mm (<u> = um or urad)";
const LOAD_KEYS: &str = "name, target, kind, shape, force, reference_force_N, lever_mm, load_height_mm, positions_mm, \
forward_<unit>, reverse_<unit>, interpolation, coefficients_<unit>, knots_mm, knot_coefficients_<unit>, range_mm";

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
            t.err_key(key, format!("unknown component {n:?}; expected an ISO 230-1 name E[XYZABC][XYZ] or a seed alias (see crates/model/src/names.rs)"));
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
