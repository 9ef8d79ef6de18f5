//! The simulation as a machine model evaluated on the recording's inputs (`diagnose --model`):
//! positions `<a>_mm`, the latched approach direction of each axis (the same latch diagnose uses),
//! `t_s`, `T_<sensor>_C`, `F_<name>_N`, `strain_<name>_ue` and `tool_mm`. Output: sim error per
//! signal, µm, actual − nominal (the model's sign convention is the recording's).

use retrocomp_model::recording::{AXES, Recording};
use retrocomp_model::{LagState, MachineModel, ModelState};

use super::DiagnoseError;
use super::features::Context;

/// Evaluate `model` (exact HTM form) at every row; returns `(signal, sim_um)` for each error signal
/// of the recording. A channel the model needs but the recording lacks is an error naming it.
pub fn simulate(
    model: &MachineModel,
    rec: &Recording,
) -> Result<Vec<(String, Vec<f64>)>, DiagnoseError> {
    let sim = simulate_axes(model, rec)?;
    Ok(rec
        .error_signals()
        .into_iter()
        .map(|s| {
            let k = AXES
                .iter()
                .position(|&a| Some(a) == s.chars().nth(1))
                .expect("e<axis>_um");
            (s, sim[k].clone())
        })
        .collect())
}

/// The model's error along machine x, y, z (µm) at every row.
pub fn simulate_axes(
    model: &MachineModel,
    rec: &Recording,
) -> Result<[Vec<f64>; 3], DiagnoseError> {
    Ok(run(model, rec)?.0)
}

/// Where the model's lags stand after the recording's last row (`[lag_state]`, for `retrocomp
/// eval` to continue this recording): `None` when the recording has no `t_s` column or the model
/// no lag.
pub fn final_lag_state(
    model: &MachineModel,
    rec: &Recording,
) -> Result<Option<LagState>, DiagnoseError> {
    let (Some(t), true) = (
        rec.col("t_s"),
        model.spec().sensors.iter().any(|s| s.tau_s.is_some()),
    ) else {
        return Ok(None);
    };
    let Some(&last) = t.last() else {
        return Ok(None);
    };
    let (_, state) = run(model, rec)?;
    Ok(Some(model.lag_state_of(&state, last)))
}

/// Every row through the model: the error along x, y, z (µm) and the state after the last row.
fn run(
    model: &MachineModel,
    rec: &Recording,
) -> Result<([Vec<f64>; 3], ModelState), DiagnoseError> {
    let ctx = Context::from_recording(rec);
    let need = |name: String| -> Result<&[f64], DiagnoseError> {
        rec.col(&name).ok_or(DiagnoseError::MissingColumn(name))
    };
    // A model with no position-dependent term needs no axis column (a thermal-only recording):
    // missing axes stay at the input's 0 mm, which no term reads.
    if model.is_position_dependent() {
        for a in model.axes() {
            need(format!("{a}_mm"))?;
        }
    }
    let temps: Vec<&[f64]> = model
        .sensor_columns()
        .iter()
        .map(|n| need(n.clone()))
        .collect::<Result<_, _>>()?;
    let forces: Vec<&[f64]> = model
        .force_channels()
        .iter()
        .map(|n| need(format!("F_{n}_N")))
        .collect::<Result<_, _>>()?;
    let strains: Vec<&[f64]> = model
        .strain_channels()
        .iter()
        .map(|n| need(format!("strain_{n}_ue")))
        .collect::<Result<_, _>>()?;
    let tool = rec.col("tool_mm");
    let mut state = model.new_state();
    let mut out = model.new_breakdown();
    let mut input = model.new_input();
    let n = rec.n_rows();
    let mut sim = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    for i in 0..n {
        for (k, f) in ctx.axes.iter().enumerate() {
            if let Some(f) = f {
                input.pos_mm[k] = f.pos_mm[i];
                input.dir[k] = f.dir[i];
            }
        }
        input.t_s = ctx.t_s[i];
        for (j, c) in temps.iter().enumerate() {
            input.temps_c[j] = c[i];
        }
        for (j, c) in forces.iter().enumerate() {
            input.forces_n[j] = c[i];
        }
        for (j, c) in strains.iter().enumerate() {
            input.strains_ue[j] = c[i];
        }
        input.tool_mm = tool.map(|t| t[i]);
        model.evaluate(&input, &mut state, &mut out);
        if out.flags.invalid_input || out.flags.time_backwards {
            return Err(DiagnoseError::ModelEvaluation {
                line: rec.line_of_row(i),
                flags: out.flags,
            });
        }
        for (s, v) in sim.iter_mut().zip(out.total_um) {
            s[i] = v;
        }
    }
    Ok((sim, state))
}

/// The simulation's thermal inputs, one column per sensor the model reads: the reading (or
/// |reading|^exponent) through the sensor's first-order lag when it has one (started at steady
/// state on the first row, as the model starts it), minus its reference. A polynomial_dt term is
/// linear in these, so a forward fold can refit the simulation's thermal gains on them
/// (`super::heldout`). Sensors whose column the recording lacks are left out (the simulation
/// would have failed on them).
pub fn regressors(model: &MachineModel, rec: &Recording) -> Vec<Vec<f64>> {
    let Some(t) = rec.col("t_s") else {
        return vec![];
    };
    model
        .spec()
        .sensors
        .iter()
        .filter_map(|s| {
            let u: Vec<f64> = rec
                .col(&s.column_name())?
                .iter()
                .map(|&v| s.input(v))
                .collect();
            let y = match s.tau_s {
                Some(tau) => retrocomp_model::lag::series(t, &u, tau, u[0]),
                None => u,
            };
            Some(y.into_iter().map(|v| v - s.reference_c).collect())
        })
        .collect()
}
