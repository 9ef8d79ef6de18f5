//! Turns fit results into machine-model terms (`retrocomp_model::ModelSpec`), so `retrocomp fit`
//! writes a model TOML that `check-config`, `run` and `diagnose` read. The written text is always
//! read back through the model's own validating parser before it is returned.
//!
//! - An axis fit becomes one component: a bidirectional table sampled from the forward/reverse
//!   piecewise quadratics at the measured targets (`AxisForm::Table`, keeps the reversal), or one
//!   piecewise quadratic, the mean of both directions (`AxisForm::Piecewise`, reversal dropped).
//!   With a lead wave the table is linear at steps of lead/16 (`fit::lead`) instead of at the
//!   targets; a piecewise quadratic cannot carry the wave.
//! - A thermal fit becomes a `polynomial_dt` term on the target component with its sensors; each
//!   sensor's reference is its training mean and its lag the selected τ.
//! - A load fit becomes, per strain, a pseudo-force F = 1 N/µε · (strain − offset) and a constant
//!   compliance, so v = β·(strain − offset); the first term's offset carries the intercept.

use crate::fit::piecewise::PiecewiseQuadratic;
use crate::fit::workflow::{AxisFit, ContextFit, Driver};
use retrocomp_model::{
    Axis, ComponentId, ErrorFunction, Interpolation, MachineModel, ModelSpec, Table,
};
use retrocomp_model::{
    AxisSpec, Branch, ComponentSpec, ForceSpec, LoadKind, LoadSpec, SensorSpec, StrainSource,
    ThermalKind, ThermalSpec, ToolSpec,
};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisForm {
    Table,
    Piecewise,
}

#[derive(Debug, thiserror::Error)]
pub enum ToModelError {
    #[error("component {0} is on axis {1}, which the base model does not have")]
    NoAxis(String, char),
    #[error("the fitted model does not validate: {0}")]
    Invalid(String),
    #[error("a table needs at least 2 targets")]
    TooFewTargets,
    #[error(
        "a lead wave goes into the model as a table (--form table): a piecewise quadratic cannot carry it"
    )]
    LeadNeedsTable,
}

/// Absolute-coordinate coefficients of a centred piecewise quadratic.
fn absolute_base(p: &PiecewiseQuadratic) -> [f64; 3] {
    let c = p.centre_mm;
    let [b0, b1, b2] = p.poly;
    [b0 - b1 * c + b2 * c * c, b1 - 2.0 * b2 * c, b2]
}

/// The component for an axis fit.
#[allow(
    clippy::float_cmp,
    reason = "knots are copied from the two fits' shared knot vector: the same knot is bit-equal"
)]
pub fn axis_component(
    fit: &AxisFit,
    id: ComponentId,
    form: AxisForm,
    targets_mm: &[f64],
) -> Result<ComponentSpec, ToModelError> {
    let lo = targets_mm.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = targets_mm.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let lead = fit.forward.lead.as_ref().map(|w| w.lead_mm);
    let function = match (form, lead) {
        (AxisForm::Table, Some(l)) => {
            let t = crate::fit::lead::table_positions(lo, hi, l);
            let f = t.iter().map(|x| fit.forward.eval(*x)).collect();
            let r = t.iter().map(|x| fit.reverse.eval(*x)).collect();
            ErrorFunction::Table(Table::new(t, f, r, Interpolation::Linear))
        }
        (AxisForm::Piecewise, Some(_)) => return Err(ToModelError::LeadNeedsTable),
        (AxisForm::Table, None) => {
            let mut t: Vec<f64> = targets_mm.to_vec();
            t.sort_by(f64::total_cmp);
            t.dedup();
            if t.len() < 2 {
                return Err(ToModelError::TooFewTargets);
            }
            let f = t.iter().map(|x| fit.forward.eval(*x)).collect();
            let r = t.iter().map(|x| fit.reverse.eval(*x)).collect();
            ErrorFunction::Table(Table::new(t, f, r, Interpolation::C1))
        }
        (AxisForm::Piecewise, None) => {
            let (bf, br) = (absolute_base(&fit.forward), absolute_base(&fit.reverse));
            let mut knots: Vec<(f64, f64)> = Vec::new();
            for p in [&fit.forward, &fit.reverse] {
                for (k, g) in p.knots_mm.iter().zip(&p.gammas) {
                    match knots.iter_mut().find(|(t, _)| t == k) {
                        Some(e) => e.1 += 0.5 * g,
                        None => knots.push((*k, 0.5 * g)),
                    }
                }
            }
            knots.sort_by(|a, b| a.0.total_cmp(&b.0));
            ErrorFunction::PiecewiseQuadratic {
                base: [
                    0.5 * (bf[0] + br[0]),
                    0.5 * (bf[1] + br[1]),
                    0.5 * (bf[2] + br[2]),
                ],
                knots_mm: knots.iter().map(|k| k.0).collect(),
                knot_coefficients: knots.iter().map(|k| k.1).collect(),
                range_mm: Some((lo, hi)),
            }
        }
    };
    Ok(ComponentSpec { id, function })
}

/// A placeholder three-axis mill (`X F Y Z`, no tool offset) carrying the fitted axis' travel,
/// for an axis fit without a base model (the model format needs 2–3 axes). Translation
/// components do not depend on the chain; give `--base-model` for anything else.
pub fn single_axis_spec(name: &str, axis: Axis, travel_mm: (f64, f64)) -> ModelSpec {
    ModelSpec {
        name: name.to_string(),
        description: format!(
            "fitted by retrocomp fit from laser runs of axis {}",
            axis.upper()
        ),
        synthetic: false,
        axes: Axis::ALL
            .iter()
            .map(|&a| AxisSpec {
                axis: a,
                branch: if a == Axis::X {
                    Branch::Workpiece
                } else {
                    Branch::Tool
                },
                offset_mm: [0.0; 3],
                travel_mm: (a == axis).then_some(travel_mm),
            })
            .collect(),
        tool_axis: (Axis::Z, -1.0),
        tools: vec![ToolSpec {
            name: "tool".into(),
            offset_mm: [0.0; 3],
        }],
        components: vec![],
        squareness: vec![],
        sensors: vec![],
        thermal: vec![],
        forces: vec![],
        load: vec![],
        lag_state: None,
    }
}

/// Replaces (or adds) the component with the same id.
pub fn put_component(spec: &mut ModelSpec, c: ComponentSpec) -> Result<(), ToModelError> {
    if !spec.axes.iter().any(|a| a.axis == c.id.axis) {
        return Err(ToModelError::NoAxis(c.id.iso_name(), c.id.axis.upper()));
    }
    spec.components.retain(|x| x.id != c.id);
    spec.components.push(c);
    Ok(())
}

/// Adds the thermal term of a context fit. `means` gives each selected signal's mean over the
/// rows the model was fitted on (the sensor's reference).
///
/// Sensors are named as `diagnose` names its lag states: `T_<name>_C` is sensor `<name>`; a column
/// the model already reads at another lag gets a lag state of its own, `<name>_tau_<τ>s` reading
/// `T_<name>_C`; a driver `rpm^2` is `rpm_sq_tau_<τ>s` (rpm, exponent 2, gain per rpm²).
pub fn add_thermal(
    spec: &mut ModelSpec,
    fit: &ContextFit,
    target: ComponentId,
    means: &dyn Fn(&str) -> f64,
) -> Result<(), ToModelError> {
    if !spec.axes.iter().any(|a| a.axis == target.axis) {
        return Err(ToModelError::NoAxis(target.iso_name(), target.axis.upper()));
    }
    let mut sensors = Vec::new();
    let mut b = Vec::new();
    let mut e0 = fit.model.intercept_um;
    for term in &fit.model.terms {
        let tau = (term.tau_s > 0.0).then_some(term.tau_s);
        let mut want = sensor_for(&term.signal, tau);
        if spec
            .sensors
            .iter()
            .any(|s| s.name == want.name && (s.tau_s != tau || s.column != want.column))
        {
            want.name = format!("{}_tau_{:.0}s", want.name, term.tau_s.round());
            want.column.get_or_insert_with(|| term.signal.clone());
        }
        match spec.sensors.iter().find(|s| s.name == want.name) {
            Some(s) => e0 += term.coef * s.reference_c,
            None => {
                want.reference_c = means(&term.signal);
                e0 += term.coef * want.reference_c;
                spec.sensors.push(want.clone());
            }
        }
        sensors.push(want.name);
        b.push(term.coef);
    }
    let name = format!("fit_{}", fit.signal.trim_end_matches("_um"));
    spec.thermal.retain(|t| t.name != name);
    spec.thermal.push(ThermalSpec {
        name,
        target,
        kind: ThermalKind::PolynomialDt {
            sensors,
            e0,
            b_per_k: b,
            c_per_k2: vec![],
        },
    });
    Ok(())
}

/// The sensor a regressor reads: `T_<name>_C` → `<name>`; a driver `col^p` → `<col>_sq_tau_<τ>s`
/// (p = 2) or `<col>_p<p>_tau_<τ>s`, reading `col` raised to p. Reference 0 until the caller sets
/// it.
#[allow(
    clippy::float_cmp,
    reason = "an exponent is 1.0 or 2.0 as written by the driver table, never computed"
)]
fn sensor_for(signal: &str, tau_s: Option<f64>) -> SensorSpec {
    let t = tau_s.unwrap_or(0.0).round();
    let (name, column, exponent) = match Driver::of_signal(signal) {
        Some(Driver { column, exponent }) => {
            let power = if exponent == 2.0 {
                "sq".to_string()
            } else {
                format!("p{exponent}")
            };
            (
                format!("{column}_{power}_tau_{t:.0}s"),
                Some(column),
                Some(exponent),
            )
        }
        None => (
            signal
                .trim_start_matches("T_")
                .trim_end_matches("_C")
                .to_string(),
            None,
            None,
        ),
    };
    SensorSpec {
        name,
        reference_c: 0.0,
        tau_s,
        column,
        exponent,
    }
}

/// Adds the load terms of a context fit on strains.
pub fn add_load(
    spec: &mut ModelSpec,
    fit: &ContextFit,
    target: ComponentId,
) -> Result<(), ToModelError> {
    if !spec.axes.iter().any(|a| a.axis == target.axis) {
        return Err(ToModelError::NoAxis(target.iso_name(), target.axis.upper()));
    }
    for (i, term) in fit.model.terms.iter().enumerate() {
        let strain = term
            .signal
            .trim_start_matches("strain_")
            .trim_end_matches("_ue")
            .to_string();
        let force = format!("fit_{strain}");
        // v = β·(s − offset) = β·s + β0 for the first term.
        let offset_ue = if i == 0 && term.coef != 0.0 {
            -fit.model.intercept_um / term.coef
        } else {
            0.0
        };
        spec.forces.retain(|f| f.name != force);
        spec.forces.push(ForceSpec {
            name: force.clone(),
            from_strain: Some(StrainSource {
                strain: strain.clone(),
                gain_n_per_ue: 1.0,
                offset_ue,
            }),
        });
        let name = format!("fit_{}_{strain}", fit.signal.trim_end_matches("_um"));
        spec.load.retain(|l| l.name != name);
        spec.load.push(LoadSpec {
            name,
            target,
            kind: LoadKind::Compliance {
                force,
                compliance: ErrorFunction::Polynomial {
                    coefficients: vec![term.coef],
                    range_mm: None,
                },
            },
        });
    }
    Ok(())
}

/// Canonical TOML of `spec`, read back through the validating parser.
pub fn to_checked_toml(spec: ModelSpec) -> Result<(String, MachineModel), ToModelError> {
    let text = MachineModel::from_spec(spec).to_toml_string();
    let model = MachineModel::from_toml_str(&text, "fitted model")
        .map_err(|e| ToModelError::Invalid(e.to_string()))?;
    Ok((text, model))
}
