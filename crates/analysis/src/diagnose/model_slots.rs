//! Where each finding goes in a machine model (`diagnose --out DIR/model.toml`, see
//! [`super::model_out`] for the mapping table and the check every added term passes).
//!
//! Sign: a finding is error = actual − nominal (µm) added to the simulation; so is every model
//! term. Tables are sampled from the base function (if any) plus the effect's own forward model
//! ([`EffectModel::at_position`]): forward = approach direction +1, reverse = −1.

use super::effects::EffectModel;
use super::features::power_of;
use crate::fit::to_model::put_component;
use retrocomp_model::recording::Recording;
use retrocomp_model::{
    Axis, ComponentId, ErrorFunction, Interpolation, ModelSpec, Motion, Squareness, Table,
};
use retrocomp_model::{
    ComponentSpec, ForceSpec, LoadKind, LoadSpec, SensorSpec, SquarenessSpec, StrainSource,
    ThermalKind, ThermalSpec,
};

/// Table grid: at least this many intervals over the span, and ≥ 32 nodes per cyclic period.
const MIN_INTERVALS: f64 = 400.0;
const NODES_PER_PERIOD: f64 = 32.0;
const MAX_NODES: usize = 20_001;

/// One finding to add: which signal axis and model.
pub(super) struct Item<'a> {
    pub signal: &'a str,
    pub axis: Axis,
    pub model: &'a EffectModel,
}

/// Add one finding to `spec`; returns the slot's description, or why there is no slot.
pub(super) fn add_item(
    spec: &mut ModelSpec,
    item: &Item<'_>,
    rec: &Recording,
) -> Result<String, String> {
    let a = item.axis;
    let own = ComponentId {
        axis: a,
        motion: Motion::Translation(a),
    };
    in_chain(spec, a)?;
    match item.model {
        EffectModel::ScaleError { .. }
        | EffectModel::Backlash { .. }
        | EffectModel::ReversalProfile { .. }
        | EffectModel::CyclicError { .. } => {
            add_to_table(spec, own, a, item.model, rec)?;
            Ok(format!("{} table", own.iso_name()))
        }
        EffectModel::Straightness { along_axis, .. } => {
            let o = other_axis_in_chain(spec, *along_axis)?;
            let id = ComponentId {
                axis: o,
                motion: Motion::Translation(a),
            };
            add_to_table(spec, id, o, item.model, rec)?;
            Ok(format!("{} table", id.iso_name()))
        }
        EffectModel::Squareness { other_axis, urad } => {
            add_squareness(spec, a, other_axis_in_chain(spec, *other_axis)?, *urad)
        }
        EffectModel::Abbe { urad_per_mm } => add_abbe(spec, a, *urad_per_mm, rec),
        EffectModel::ThermalDrift { sensor, um_per_k } => {
            let (name, column) = match sensor_name(sensor) {
                Ok(n) => (n, None),
                Err(_) => (format!("{sensor}_direct"), Some(sensor.clone())),
            };
            let t0 = first_reading(rec, sensor)?;
            let reference = ensure_sensor(spec, &name, None, t0, column, None)?;
            push_linear_dt(spec, item, own, &name, *um_per_k, reference - t0);
            Ok(format!(
                "sensor `{name}` + thermal polynomial_dt on {}",
                own.iso_name()
            ))
        }
        EffectModel::ThermalLag {
            sensor,
            tau_s,
            um_per_k,
        } => add_thermal_lag(spec, item, own, (sensor, *tau_s, *um_per_k), rec),
        EffectModel::ThermalExpansion { sensor, ppm_per_k } => {
            let name = sensor_name(sensor)?;
            let t0 = first_reading(rec, sensor)?;
            ensure_sensor(spec, &name, None, t0, None, None)?;
            push_thermal(
                spec,
                item,
                own,
                ThermalKind::Expansion {
                    sensor: name.clone(),
                    alpha_ppm_per_k: *ppm_per_k,
                    origin_mm: 0.0,
                    reference_c: t0,
                },
            );
            Ok(format!("thermal expansion on {} ({name})", own.iso_name()))
        }
        EffectModel::ForceDeflection { channel, um_per_n } => {
            add_force_deflection(spec, item, own, channel, *um_per_n)
        }
        EffectModel::ServoLag { .. } => {
            Err("no slot: the model is a function of position, not of velocity".into())
        }
        EffectModel::ReversalSpike { .. } => {
            Err("no slot: the model has no state for the distance since the last reversal".into())
        }
        EffectModel::TimeDrift { .. } => {
            Err("no slot: the model has no term in time without a measured cause".into())
        }
    }
}

fn in_chain(spec: &ModelSpec, x: Axis) -> Result<(), String> {
    if spec.axes.iter().any(|s| s.axis == x) {
        Ok(())
    } else {
        Err(format!("axis {} is not in the model's chain", x.upper()))
    }
}

/// The second axis a finding names (`along_axis`, `other_axis`), which must be in the chain.
fn other_axis_in_chain(spec: &ModelSpec, letter: char) -> Result<Axis, String> {
    let o = Axis::from_letter(letter).ok_or("bad axis")?;
    in_chain(spec, o)?;
    Ok(o)
}

/// Squareness `urad` between the finding's axis `a` and `o`, added to the pair's entry.
fn add_squareness(spec: &mut ModelSpec, a: Axis, o: Axis, urad: f64) -> Result<String, String> {
    // docs/model.md: EC0Y on x: ey = −S·x, on y: ex = −S·y; EB0Z: ex = +S·z, ez = +S·x;
    // EA0Z: ey = −S·z, ez = −S·y. The finding is e_a += urad·1e-3·q_o.
    let (kind, sign) = match (a.lower().min(o.lower()), a.lower().max(o.lower())) {
        ('x', 'y') => (Squareness::EC0Y, -1.0),
        ('x', 'z') => (Squareness::EB0Z, 1.0),
        ('y', 'z') => (Squareness::EA0Z, -1.0),
        _ => return Err("squareness needs two different axes".into()),
    };
    let value = sign * urad;
    match spec
        .squareness
        .iter_mut()
        .find(|s| s.kind == kind && s.on_axis == o)
    {
        Some(s) => s.value_urad += value,
        None => spec.squareness.push(SquarenessSpec {
            kind,
            on_axis: o,
            value_urad: value,
        }),
    }
    Ok(format!("squareness {} on {}", kind.iso_name(), o.lower()))
}

/// An Abbe error along `a` (µrad per mm of tool length) as the angular table of the rotation
/// that gives it.
fn add_abbe(
    spec: &mut ModelSpec,
    a: Axis,
    urad_per_mm: f64,
    rec: &Recording,
) -> Result<String, String> {
    // e_a = (ε × arm)_a·1e-3 with arm ∋ s·tool_mm·û_t: a rotation about the third axis r
    // gives ε_r·s·h·lc(r, t, a); the finding is urad_per_mm·q_a·h·1e-3.
    let (t, s) = spec.tool_axis;
    if t == a {
        return Err(format!(
            "the tool length lies along {}: no rotation gives an Abbe error along it",
            a.lower()
        ));
    }
    let r = Axis::ALL
        .iter()
        .copied()
        .find(|x| *x != a && *x != t)
        .expect("three axes");
    let lc = levi_civita(r.index(), t.index(), a.index());
    let k = urad_per_mm / (s * lc);
    let id = ComponentId {
        axis: a,
        motion: Motion::Rotation(r),
    };
    let m = EffectModel::ScaleError { ppm: k * 1e3 };
    add_to_table(spec, id, a, &m, rec)?;
    Ok(format!(
        "{} table (µrad, Abbe arm = tool length)",
        id.iso_name()
    ))
}

/// A lag (sensor or driver column, τ s, gain per unit of the lagged reading) as a lag state and
/// a linear `polynomial_dt` on `own`.
fn add_thermal_lag(
    spec: &mut ModelSpec,
    item: &Item<'_>,
    own: ComponentId,
    (sensor, tau_s, um_per_k): (&str, f64, f64),
    rec: &Recording,
) -> Result<String, String> {
    // A power of a column (`krpm^2`, `<name>_A^2`) is written as the lag of the column with
    // its exponent: gain per unit^exponent of the column as recorded, reference likewise (the
    // finding's gain of `krpm^2` is per krpm², 10⁶ rpm²).
    if let Some((column, exponent, per)) = power_of(sensor) {
        let name = format!("{column}_sq_tau_{:.0}s", tau_s.round());
        let t0 = first_reading(rec, column)?.powi(exponent);
        // Times the reciprocal, not divided: 1/10⁶ rounds to the double `1e-6`, so a krpm² gain
        // is um_per_k × 1e-6, the bits the shipped FL models hold (the quotient by 10⁶ is
        // correctly rounded and can differ from it by 1 ulp). Exact for per = 1.
        let um_per_unit = um_per_k * per.powi(exponent).recip();
        let reference = ensure_sensor(
            spec,
            &name,
            Some(tau_s),
            t0,
            Some(column.into()),
            Some(f64::from(exponent)),
        )?;
        push_linear_dt(spec, item, own, &name, um_per_unit, reference - t0);
        return Ok(format!(
            "sensor `{name}` ({column}, exponent {exponent}, tau_s {tau_s:.0}) + thermal polynomial_dt on {}",
            own.iso_name()
        ));
    }
    // A temperature is read as its sensor; any other driver column (rpm, load, power…)
    // gets a lag state of its own reading that column (one per τ).
    let (mut name, mut column) = match sensor_name(sensor) {
        Ok(n) => (n, None),
        Err(_) => (
            format!("{sensor}_tau_{:.0}s", tau_s.round()),
            Some(sensor.to_string()),
        ),
    };
    // A temperature already read with another lag (e.g. as read, by the base model)
    // gets a second lag state of its own on the same column.
    if column.is_none()
        && spec
            .sensors
            .iter()
            .any(|s| s.name == name && s.tau_s != Some(tau_s))
    {
        name = format!("{name}_tau_{:.0}s", tau_s.round());
        column = Some(sensor.to_string());
    }
    let t0 = first_reading(rec, sensor)?;
    let reference = ensure_sensor(spec, &name, Some(tau_s), t0, column, None)?;
    push_linear_dt(spec, item, own, &name, um_per_k, reference - t0);
    Ok(format!(
        "sensor `{name}` (tau_s {tau_s:.0}) + thermal polynomial_dt on {}",
        own.iso_name()
    ))
}

/// A deflection proportional to a force read as `F_<name>_N` or derived from `strain_<name>_ue`
/// (µm per N), as a constant compliance on `own`.
fn add_force_deflection(
    spec: &mut ModelSpec,
    item: &Item<'_>,
    own: ComponentId,
    channel: &str,
    um_per_n: f64,
) -> Result<String, String> {
    let force = if let Some(n) = strip(channel, "F_", "_N") {
        match spec.forces.iter().find(|f| f.name == n) {
            Some(f) if f.from_strain.is_some() => {
                return Err(format!(
                    "force `{n}` is derived from a strain in the model, not read from {channel}"
                ));
            }
            Some(_) => {}
            None => spec.forces.push(ForceSpec {
                name: n.clone(),
                from_strain: None,
            }),
        }
        n
    } else if let Some(sname) = strip(channel, "strain_", "_ue") {
        let n = format!("diag_{sname}");
        spec.forces.retain(|f| f.name != n);
        spec.forces.push(ForceSpec {
            name: n.clone(),
            from_strain: Some(StrainSource {
                strain: sname,
                gain_n_per_ue: 1.0,
                offset_ue: 0.0,
            }),
        });
        n
    } else {
        return Err(format!(
            "`{channel}` is neither F_<name>_N nor strain_<name>_ue"
        ));
    };
    let name = unique(
        &format!("diag_{}_{force}", signal_stem(item.signal)),
        spec.load.iter().map(|l| l.name.as_str()),
    );
    spec.load.push(LoadSpec {
        name,
        target: own,
        kind: LoadKind::Compliance {
            force: force.clone(),
            compliance: ErrorFunction::Polynomial {
                coefficients: vec![um_per_n],
                range_mm: None,
            },
        },
    });
    Ok(format!(
        "force {force} + constant compliance on {}",
        own.iso_name()
    ))
}

/// A term linear in one sensor's reading: `um_per_unit` µm per unit of sensor `name` (K, or rpm²
/// for a squared-speed lag), zero at the recording's first reading (`reference_minus_first` = the
/// sensor's reference − that reading, so e0 = um_per_unit × it).
fn push_linear_dt(
    spec: &mut ModelSpec,
    item: &Item<'_>,
    own: ComponentId,
    name: &str,
    um_per_unit: f64,
    reference_minus_first: f64,
) {
    push_thermal(
        spec,
        item,
        own,
        ThermalKind::PolynomialDt {
            sensors: vec![name.to_string()],
            e0: um_per_unit * reference_minus_first,
            b_per_k: vec![um_per_unit],
            c_per_k2: vec![],
        },
    );
}

fn levi_civita(i: usize, j: usize, k: usize) -> f64 {
    match (i, j, k) {
        (0, 1, 2) | (1, 2, 0) | (2, 0, 1) => 1.0,
        (0, 2, 1) | (2, 1, 0) | (1, 0, 2) => -1.0,
        _ => 0.0,
    }
}

fn strip(s: &str, pre: &str, suf: &str) -> Option<String> {
    s.strip_prefix(pre)
        .and_then(|r| r.strip_suffix(suf))
        .filter(|r| !r.is_empty())
        .map(str::to_string)
}

fn sensor_name(column: &str) -> Result<String, String> {
    strip(column, "T_", "_C").ok_or_else(|| format!("`{column}` is not a T_<name>_C column"))
}

fn signal_stem(signal: &str) -> &str {
    signal.trim_end_matches("_um")
}

fn first_reading(rec: &Recording, column: &str) -> Result<f64, String> {
    rec.col(column)
        .and_then(|c| c.first().copied())
        .ok_or_else(|| format!("the recording has no `{column}`"))
}

fn unique<'a>(want: &str, taken: impl Iterator<Item = &'a str> + Clone) -> String {
    let mut name = want.to_string();
    let mut k = 2;
    while taken.clone().any(|t| t == name) {
        name = format!("{want}_{k}");
        k += 1;
    }
    name
}

/// Make sure sensor `name` exists with lag `tau_s`; returns its reference temperature. A sensor
/// already in the model with another lag cannot also be read without it (one sensor per column).
fn ensure_sensor(
    spec: &mut ModelSpec,
    name: &str,
    tau_s: Option<f64>,
    t0: f64,
    column: Option<String>,
    exponent: Option<f64>,
) -> Result<f64, String> {
    if let Some(s) = spec.sensors.iter().find(|s| s.name == name) {
        let same = match (s.tau_s, tau_s) {
            (None, None) => true,
            (Some(a), Some(b)) => (a - b).abs() <= 1e-9 * a.abs().max(b.abs()),
            _ => false,
        };
        return if same {
            Ok(s.reference_c)
        } else {
            Err(format!(
                "sensor `{name}` is already in the model with lag {:?} s, the finding needs {:?} s",
                s.tau_s, tau_s
            ))
        };
    }
    spec.sensors.push(SensorSpec {
        name: name.to_string(),
        reference_c: t0,
        tau_s,
        column,
        exponent,
    });
    Ok(t0)
}

fn push_thermal(spec: &mut ModelSpec, item: &Item<'_>, target: ComponentId, kind: ThermalKind) {
    let name = unique(
        &format!("diag_{}_{}", signal_stem(item.signal), item.model.id()),
        spec.thermal.iter().map(|t| t.name.as_str()),
    );
    spec.thermal.push(ThermalSpec { name, target, kind });
}

/// Add a one-position (and direction) effect to component `id` whose argument is axis `arg`:
/// the base function (if any) plus the effect, sampled as a bidirectional table.
fn add_to_table(
    spec: &mut ModelSpec,
    id: ComponentId,
    arg: Axis,
    m: &EffectModel,
    rec: &Recording,
) -> Result<(), String> {
    let base = spec
        .components
        .iter()
        .find(|c| c.id == id)
        .map(|c| c.function.clone());
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut widen = |a: f64, b: f64| {
        lo = lo.min(a);
        hi = hi.max(b);
    };
    if let Some(p) = rec.col(&format!("{}_mm", arg.lower())) {
        widen(
            p.iter().copied().fold(f64::INFINITY, f64::min),
            p.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
    }
    if let Some((a, b)) = spec
        .axes
        .iter()
        .find(|s| s.axis == arg)
        .and_then(|s| s.travel_mm)
    {
        widen(a, b);
    }
    let mut extra_nodes = vec![];
    match &base {
        Some(ErrorFunction::Table(t)) => {
            widen(t.positions_mm[0], *t.positions_mm.last().expect("≥ 2"));
            extra_nodes.extend(t.positions_mm.iter().copied());
        }
        Some(
            ErrorFunction::Polynomial {
                range_mm: Some((a, b)),
                ..
            }
            | ErrorFunction::PiecewiseQuadratic {
                range_mm: Some((a, b)),
                ..
            },
        ) => widen(*a, *b),
        _ => {}
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(format!("no positions of axis {} to tabulate", arg.lower()));
    }
    if hi - lo < 1e-6 {
        hi = lo + 1.0;
    }
    let span = hi - lo;
    let mut h = span / MIN_INTERVALS;
    if let EffectModel::CyclicError { period_mm, .. } = m {
        h = h.min(period_mm / NODES_PER_PERIOD);
    }
    h = h.max(span / (MAX_NODES - 1) as f64);
    let n = crate::numeric::ceil_usize(span / h);
    let mut nodes: Vec<f64> = (0..=n).map(|i| lo + span * i as f64 / n as f64).collect();
    nodes.extend(extra_nodes);
    if let EffectModel::ReversalProfile { edges_mm, .. } = m {
        // A zone edge is a step: one node just below it and one on it.
        for &e in edges_mm {
            if e > lo && e < hi {
                nodes.push(e - 1e-6 * span);
                nodes.push(e);
            }
        }
    }
    nodes.sort_by(f64::total_cmp);
    nodes.dedup_by(|b, a| (*b - *a).abs() < 1e-9 * span);
    let val = |x: f64, dir: i8| {
        base.as_ref().map_or(0.0, |f| f.eval(x, dir).0)
            + m.at_position(x, f64::from(dir)).expect("positional effect")
    };
    let forward = nodes.iter().map(|&x| val(x, 1)).collect();
    let reverse = nodes.iter().map(|&x| val(x, -1)).collect();
    let interpolation = match &base {
        Some(ErrorFunction::Table(t)) => t.interpolation,
        _ => Interpolation::Linear,
    };
    put_component(
        spec,
        ComponentSpec {
            id,
            function: ErrorFunction::Table(Table::new(nodes, forward, reverse, interpolation)),
        },
    )
    .map_err(|e| e.to_string())
}
