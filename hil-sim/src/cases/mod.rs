//! `hil-sim gen-cases`: the concealed-effect benchmark. Each case is a recording (docs/recording-csv.md) whose
//! `sim_e*_um` columns come from a model that omits zero, one or two hidden effects, plus a JSON
//! manifest of the truth ([`retrocomp_analysis::diagnose::scoring::CaseManifest`], params in docs/diagnose-json.md units).
//!
//! Deterministic: case `i` of seed `s` depends only on (s, i) through a ChaCha8 stream. The schedule
//! cycles so every effect id appears in every variant: case i with i mod 10 < 3 is a null (30 %);
//! the others take effect id `EFFECT_IDS[j mod 14]` and variant `(j / 14) mod 5` (j counts effect
//! cases): 0 single (effect/noise 2–6), 1 masked under large modelled terms (1–3), 2 low SNR
//! (0.2–0.8), 3 two effects (1.5–5), 4 confounded (thermal/scale/time effects: one forward sweep
//! during a linear warm-up, unidentifiable; others: extra decoy channels, 1–4).
//! Errors are actual − nominal (µm); the truth of thermal effects is on the NODE temperature while
//! the recording carries lagged, noisy, quantised sensors (so the candidate forms are approximations).
//!
//! This is the `standard` family (files `case_NNNN`, output unchanged since before families
//! existed); `hard` adds six families with one difficulty each (`<family>_NNNN`).

pub(crate) mod hard;
pub(crate) mod physics;
pub(crate) mod trajectory;

pub use hard::{Family, generate_family_case};

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use retrocomp_analysis::diagnose::effects::{EFFECT_IDS, EffectModel};
use retrocomp_analysis::diagnose::features::Context;
use retrocomp_analysis::diagnose::scoring::{CaseManifest, TruthEffect};
use retrocomp_model::recording::Recording;

use physics::*;
use trajectory::{Path as MotionPath, uniform};

pub(crate) const DT_S: f64 = 1.0;
const X_TRAVEL: (f64, f64) = (0.0, 300.0);
const Y_TRAVEL: (f64, f64) = (0.0, 200.0);

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Program {
    /// Four runs: laser runs on X and Y, slow scans, a diagonal, a cutting pass; warm-up then cool-down.
    Standard,
    /// One slow forward sweep of X during a steady warm-up: position, time and temperature collinear.
    SingleSweep,
}

pub(crate) fn build_path(rng: &mut ChaCha8Rng, program: Program) -> MotionPath {
    let mut p = MotionPath::new(DT_S);
    match program {
        Program::Standard => {
            let tools = [80.0, 140.0, 200.0, 110.0];
            p.move_to(0.0, 0.0, 20.0, false, 0, tools[0]);
            for (run, &tool) in (0..4i64).zip(&tools) {
                p.laser_run(rng, X_TRAVEL.0, X_TRAVEL.1, 11, false, 20.0, 4.0, run, tool);
                p.move_to(X_TRAVEL.1, 0.0, 1.0, false, run, tool);
                p.move_to(X_TRAVEL.0, 0.0, 1.0, false, run, tool);
                p.move_to(X_TRAVEL.1, Y_TRAVEL.1, 20.0, false, run, tool);
                p.move_to(X_TRAVEL.0, Y_TRAVEL.0, 20.0, false, run, tool);
                p.laser_run(rng, Y_TRAVEL.0, Y_TRAVEL.1, 9, true, 20.0, 4.0, run, tool);
                p.move_to(20.0, 100.0, 20.0, false, run, tool);
                p.move_to(280.0, 100.0, 5.0, true, run, tool);
                p.move_to(0.0, 0.0, 20.0, false, run, tool);
                p.dwell(uniform(rng, 60.0, 240.0), run, tool);
            }
        }
        Program::SingleSweep => {
            p.move_to(0.0, 100.0, 20.0, false, 0, 100.0);
            p.move_to(X_TRAVEL.1, 100.0, 0.1, false, 0, 100.0);
        }
    }
    p
}

pub(crate) fn rms_centered(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

pub(crate) fn signed(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    uniform(rng, lo, hi) * if rng.random_bool(0.5) { 1.0 } else { -1.0 }
}

/// Draw a hidden effect of id `id` with physically plausible parameters (anchors-discrepancy §3).
pub(crate) fn draw_effect(rng: &mut ChaCha8Rng, id: &str, x_range: (f64, f64)) -> TruthEffect {
    let ex = |model| TruthEffect {
        signal: "ex_um".into(),
        axis: "x".into(),
        model,
    };
    let ey = |model| TruthEffect {
        signal: "ey_um".into(),
        axis: "y".into(),
        model,
    };
    let sensor = if rng.random_bool(0.5) {
        "T_spindle_C"
    } else {
        "T_column_C"
    };
    match id {
        "scale_error" => ex(EffectModel::ScaleError {
            ppm: signed(rng, 10.0, 60.0),
        }),
        "backlash" => ex(EffectModel::Backlash {
            b_um: signed(rng, 3.0, 15.0),
        }),
        "reversal_profile" => {
            let (lo, hi) = x_range;
            let edges_mm = (0..=4)
                .map(|k| lo + (hi - lo) * f64::from(k) / 4.0)
                .collect();
            let start = uniform(rng, 8.0, 14.0);
            let b_um = (0..4)
                .map(|k| start * (1.0 - 0.25 * f64::from(k)) + uniform(rng, -0.5, 0.5))
                .collect();
            ex(EffectModel::ReversalProfile { edges_mm, b_um })
        }
        "cyclic_error" => ex(EffectModel::CyclicError {
            period_mm: uniform(rng, 5.0, 25.0),
            amplitude_um: uniform(rng, 1.0, 5.0),
            phase_rad: uniform(rng, -3.1, 3.1),
            harmonic2_um: 0.0,
            harmonic2_phase_rad: 0.0,
        }),
        "squareness" => ex(EffectModel::Squareness {
            other_axis: 'y',
            urad: signed(rng, 10.0, 50.0),
        }),
        "straightness" => {
            let half = 0.5 * (x_range.1 - x_range.0);
            let bow = signed(rng, 2.0, 8.0);
            ey(EffectModel::Straightness {
                along_axis: 'x',
                mid_mm: 0.5 * (x_range.0 + x_range.1),
                c2_um_per_mm2: bow / (half * half),
            })
        }
        "abbe" => ex(EffectModel::Abbe {
            urad_per_mm: signed(rng, 0.03, 0.12),
        }),
        "thermal_drift" => ex(EffectModel::ThermalDrift {
            sensor: sensor.into(),
            um_per_k: signed(rng, 1.0, 4.0),
        }),
        "thermal_lag" => ex(EffectModel::ThermalLag {
            sensor: "T_spindle_C".into(),
            tau_s: uniform(rng, 200.0, 900.0),
            um_per_k: signed(rng, 1.5, 4.0),
        }),
        "thermal_expansion" => ex(EffectModel::ThermalExpansion {
            sensor: sensor.into(),
            ppm_per_k: uniform(rng, 6.0, 16.0),
        }),
        "force_deflection" => ex(EffectModel::ForceDeflection {
            channel: "F_cut_N".into(),
            um_per_n: uniform(rng, 0.01, 0.05),
        }),
        "servo_lag" => ex(EffectModel::ServoLag {
            ms: signed(rng, 0.1, 0.5),
        }),
        "reversal_spike" => ex(EffectModel::ReversalSpike {
            amplitude_um: signed(rng, 3.0, 10.0),
            decay_mm: uniform(rng, 2.0, 10.0),
        }),
        "time_drift" => ex(EffectModel::TimeDrift {
            um_per_h: signed(rng, 2.0, 8.0),
        }),
        other => unreachable!("unknown effect id {other}"),
    }
}

/// Generate case `index` of `seed`.
pub fn generate_case(seed: u64, index: usize) -> (Recording, CaseManifest) {
    let mut rng =
        ChaCha8Rng::seed_from_u64(seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let (is_null, j) = schedule_slot(index);
    let id = EFFECT_IDS[j % EFFECT_IDS.len()];
    let (class, program, snr_range) = standard_class(is_null, j, id);
    let d = standard_drive(&mut rng, program);
    let n = d.t_s.len();
    // Truth context: commanded path and the TRUE node temperatures and force.
    let truth_rec =
        Recording::from_columns(truth_columns(&d)).expect("generator columns are valid");
    let tctx = Context::from_recording(&truth_rec);
    let x_range = x_range(&d.path);
    let hidden = if is_null {
        vec![]
    } else {
        draw_hidden(&mut rng, id, class == "two", x_range)
    };
    // Large modelled terms (in the errors AND in the simulation) for masked cases and half the nulls.
    let modelled = if class == "masked" || (is_null && rng.random_bool(0.5)) {
        large_modelled_terms(&mut rng)
    } else {
        vec![]
    };
    let hx = contribution(&hidden, "ex_um", n, &tctx);
    let hy = contribution(&hidden, "ey_um", n, &tctx);
    let mx = contribution(&modelled, "ex_um", n, &tctx);
    let my = contribution(&modelled, "ey_um", n, &tctx);
    let effect_rms = hidden_rms(&hidden, &tctx);
    let snr = (!is_null).then(|| uniform(&mut rng, snr_range.0, snr_range.1));
    let noise_um = match snr {
        None => uniform(&mut rng, 0.3, 2.0),
        Some(s) => effect_rms.iter().copied().fold(f64::INFINITY, f64::min) / s,
    };
    let nx = error_noise(&mut rng, n, noise_um);
    let ny = error_noise(&mut rng, n, noise_um);
    let errors = Errors {
        ex_um: quantized_errors(&hx, &mx, &nx),
        ey_um: quantized_errors(&hy, &my, &ny),
        sim_ex_um: mx,
        sim_ey_um: my,
    };
    let (cols, decoys) = standard_columns(&mut rng, d, errors, class, program);
    let rec = Recording::from_columns(cols).expect("generated recording is valid");
    let identifiable = class != "confounded";
    let expected_verdict = if is_null {
        "none"
    } else if identifiable {
        "found"
    } else {
        "ambiguous"
    };
    let notes = format!(
        "program {program:?}; thermal truth on node temperatures (sensors lag 15/30 s, 0.1 °C steps); \
         noise: white+AR(1) rho 0.9, 0.5 % outliers at 6 sigma, 0.05 um steps; hidden effect RMS {effect_rms:?} um"
    );
    let manifest = CaseManifest {
        case: format!("case_{index:04}"),
        seed,
        family: Family::Standard.name().into(),
        class: class.into(),
        hidden,
        modelled,
        noise_um,
        snr,
        identifiable,
        expected_verdict: expected_verdict.into(),
        decoys,
        family_params: Default::default(),
        notes,
    };
    (rec, manifest)
}

/// Where case `index` sits in the schedule: whether it is a null (index mod 10 < 3) and `j`, its
/// position among the effect cases (which picks the effect id, and the variant in `standard`).
fn schedule_slot(index: usize) -> (bool, usize) {
    let is_null = index % 10 < 3;
    let j = index - (index / 10) * 3 - (index % 10).min(3);
    (is_null, j)
}

/// The standard family's class, program and effect/noise range for effect case `j` (module docs:
/// the variant cycles every 14 effect cases; only thermal/scale/time effects can be confounded).
fn standard_class(is_null: bool, j: usize, id: &str) -> (&'static str, Program, (f64, f64)) {
    let variant = if is_null {
        0
    } else {
        (j / EFFECT_IDS.len()) % 5
    };
    let confound_group = matches!(
        id,
        "thermal_drift" | "thermal_expansion" | "scale_error" | "time_drift"
    );
    match (is_null, variant) {
        (true, _) => ("null", Program::Standard, (0.0, 0.0)),
        (false, 0) => ("single", Program::Standard, (2.0, 6.0)),
        (false, 1) => ("masked", Program::Standard, (1.0, 3.0)),
        (false, 2) => ("low_snr", Program::Standard, (0.2, 0.8)),
        (false, 3) => ("two", Program::Standard, (1.5, 5.0)),
        (false, _) if confound_group => ("confounded", Program::SingleSweep, (1.5, 4.0)),
        (false, _) => ("decoy", Program::Standard, (1.0, 4.0)),
    }
}

/// What the simulated machine did: the inputs of both the truth context and the recorded sensors.
struct Drive {
    path: MotionPath,
    t_s: Vec<f64>,
    rpm: Vec<f64>,
    /// TRUE node temperatures (the sensors lag and quantise them).
    th: Thermal,
    /// TRUE cutting force (the load cell and strain gauge read it with noise).
    force: Vec<f64>,
    /// The path's run index as a column.
    run: Vec<f64>,
}

impl Drive {
    /// The last draws of every drive, in the generator's order: the cutting-force level and the
    /// force along the path's cuts; and the path's run column.
    fn with_force(
        rng: &mut ChaCha8Rng,
        path: MotionPath,
        t_s: Vec<f64>,
        rpm: Vec<f64>,
        th: Thermal,
    ) -> Drive {
        let force_level_n = uniform(rng, 150.0, 500.0);
        let force = cutting_force(rng, &path.cut, force_level_n);
        let run = path.run.iter().map(|&r| r as f64).collect();
        Drive {
            path,
            t_s,
            rpm,
            th,
            force,
            run,
        }
    }
}

/// The standard family's motion, spindle, thermal and force draws, in the generator's fixed order.
fn standard_drive(rng: &mut ChaCha8Rng, program: Program) -> Drive {
    let path = build_path(rng, program);
    let n = path.len();
    let t_s = time_axis(n);
    let duration = t_s[n - 1];
    // Spindle: warm-up then cool-down (Standard), or steady heating through the sweep.
    let (t_off, tau_node) = match program {
        Program::Standard => (
            duration * uniform(rng, 0.55, 0.7),
            uniform(rng, 300.0, 700.0),
        ),
        Program::SingleSweep => (f64::INFINITY, 4.0 * duration),
    };
    let rpm_level = uniform(rng, 4000.0, 8000.0);
    let rpm: Vec<f64> = t_s
        .iter()
        .map(|&t| if t < t_off { rpm_level } else { 0.0 })
        .collect();
    let speed = path_speed(&path);
    let k_heat = uniform(rng, 0.8, 1.2);
    let th = thermal(
        &t_s,
        &rpm,
        &speed,
        k_heat,
        tau_node,
        1500.0,
        0.3,
        4.0 * duration,
    );
    Drive::with_force(rng, path, t_s, rpm, th)
}

/// Sample times of an `n`-sample recording.
fn time_axis(n: usize) -> Vec<f64> {
    (0..n).map(|i| i as f64 * DT_S).collect()
}

/// Path speed (mm/s), the friction input of the structure node.
fn path_speed(path: &MotionPath) -> Vec<f64> {
    (0..path.len())
        .map(|i| {
            if i == 0 {
                0.0
            } else {
                (path.x_mm[i] - path.x_mm[i - 1]).hypot(path.y_mm[i] - path.y_mm[i - 1]) / DT_S
            }
        })
        .collect()
}

/// Columns of the truth recording: the commanded path with the TRUE node temperatures and force,
/// so hidden effects are evaluated on the truth rather than on the recorded sensors.
fn truth_columns(d: &Drive) -> Vec<(String, Vec<f64>)> {
    vec![
        ("t_s".into(), d.t_s.clone()),
        ("x_mm".into(), d.path.x_mm.clone()),
        ("y_mm".into(), d.path.y_mm.clone()),
        ("ex_um".into(), vec![0.0; d.t_s.len()]),
        ("T_spindle_C".into(), d.th.spindle_c.clone()),
        ("T_column_C".into(), d.th.structure_c.clone()),
        ("F_cut_N".into(), d.force.clone()),
        ("tool_mm".into(), d.path.tool_mm.clone()),
        ("run".into(), d.run.clone()),
    ]
}

/// The X travel actually covered, which scales position-dependent effects.
fn x_range(path: &MotionPath) -> (f64, f64) {
    (
        path.x_mm.iter().copied().fold(f64::INFINITY, f64::min),
        path.x_mm.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    )
}

/// The standard family's hidden effects: effect `id`, and for `two` a second id drawn among the
/// other twelve that follow it in [`EFFECT_IDS`].
fn draw_hidden(rng: &mut ChaCha8Rng, id: &str, two: bool, x_range: (f64, f64)) -> Vec<TruthEffect> {
    let mut hidden = vec![draw_effect(rng, id, x_range)];
    if two {
        let k =
            (EFFECT_IDS.iter().position(|e| *e == id).expect("id") + 1 + rng.random_range(0..12))
                % 14;
        hidden.push(draw_effect(rng, EFFECT_IDS[k], x_range));
    }
    hidden
}

/// Large modelled terms (X scale, XY squareness): present in the errors AND in the simulation,
/// so they mask hidden effects unless the simulation is subtracted.
fn large_modelled_terms(rng: &mut ChaCha8Rng) -> Vec<TruthEffect> {
    vec![
        TruthEffect {
            signal: "ex_um".into(),
            axis: "x".into(),
            model: EffectModel::ScaleError {
                ppm: uniform(rng, 40.0, 80.0),
            },
        },
        TruthEffect {
            signal: "ey_um".into(),
            axis: "y".into(),
            model: EffectModel::Squareness {
                other_axis: 'x',
                urad: uniform(rng, 20.0, 60.0),
            },
        },
    ]
}

/// Sum of the effects of `effs` on error signal `sig` (µm), evaluated on the truth context.
fn contribution(effs: &[TruthEffect], sig: &str, n: usize, tctx: &Context) -> Vec<f64> {
    let mut v = vec![0.0; n];
    for e in effs.iter().filter(|e| e.signal == sig) {
        let c = e
            .model
            .evaluate(e.axis.chars().next().expect("axis"), tctx)
            .expect("truth inputs exist");
        v.iter_mut().zip(c).for_each(|(a, b)| *a += b);
    }
    v
}

/// Centred RMS of each hidden effect on the truth: the noise level is set from the smallest.
fn hidden_rms(hidden: &[TruthEffect], tctx: &Context) -> Vec<f64> {
    hidden
        .iter()
        .map(|e| {
            rms_centered(
                &e.model
                    .evaluate(e.axis.chars().next().expect("axis"), tctx)
                    .expect("inputs"),
            )
        })
        .collect()
}

/// Measured errors: hidden + modelled + noise, quantised to the 0.05 µm step of the instrument.
fn quantized_errors(hidden: &[f64], modelled: &[f64], noise: &[f64]) -> Vec<f64> {
    (0..hidden.len())
        .map(|i| quantize(hidden[i] + modelled[i] + noise[i], 0.05))
        .collect()
}

/// The error columns of a recording: measured (`e*_um`) and simulated from the modelled terms
/// (`sim_e*_um`).
struct Errors {
    ex_um: Vec<f64>,
    ey_um: Vec<f64>,
    sim_ex_um: Vec<f64>,
    sim_ey_um: Vec<f64>,
}

/// The leading columns every family records: time, commanded position, the errors.
fn error_columns(t_s: Vec<f64>, path: &MotionPath, e: Errors) -> Vec<(String, Vec<f64>)> {
    vec![
        ("t_s".to_string(), t_s),
        ("x_mm".into(), path.x_mm.clone()),
        ("y_mm".into(), path.y_mm.clone()),
        ("ex_um".into(), e.ex_um),
        ("ey_um".into(), e.ey_um),
        ("sim_ex_um".into(), e.sim_ex_um),
        ("sim_ey_um".into(), e.sim_ey_um),
    ]
}

/// The standard family's recorded columns (sensors drawn in the generator's fixed order; extra
/// decoy channels for `decoy` cases) and the names of the decoys.
fn standard_columns(
    rng: &mut ChaCha8Rng,
    d: Drive,
    errors: Errors,
    class: &str,
    program: Program,
) -> (Vec<(String, Vec<f64>)>, Vec<String>) {
    let n = d.t_s.len();
    // Sensors as recorded.
    let t_spindle = temp_sensor(rng, &d.t_s, &d.th.spindle_c, 15.0, 0.02);
    let t_column = temp_sensor(rng, &d.t_s, &d.th.structure_c, 30.0, 0.02);
    let t_amb = temp_sensor(rng, &d.t_s, &d.th.ambient_c, 60.0, 0.02);
    let t_decoy = random_walk(rng, n, 21.0, 0.01);
    let f_cut = load_cell(rng, &d.force, 2.0);
    let strain = strain_gauge(rng, &d.force, &t_column, 0.05, 2.0);
    let aux = random_walk(rng, n, 0.0, 0.05);
    let mut cols = error_columns(d.t_s, &d.path, errors);
    cols.extend([
        ("T_spindle_C".into(), t_spindle),
        ("T_column_C".into(), t_column),
        ("T_amb_C".into(), t_amb),
        ("T_decoy_C".into(), t_decoy),
        ("rpm".into(), d.rpm),
        ("F_cut_N".into(), f_cut),
        ("strain_col_ue".into(), strain),
        ("tool_mm".into(), d.path.tool_mm),
        ("aux_V".into(), aux),
    ]);
    let mut decoys = vec![
        "T_decoy_C".to_string(),
        "aux_V".to_string(),
        "T_amb_C".to_string(),
    ];
    if class == "decoy" {
        let f_clamp: Vec<f64> = (0..n)
            .map(|_| quantize(uniform(rng, 800.0, 820.0), 0.1))
            .collect();
        cols.push(("F_clamp_N".into(), f_clamp));
        cols.push(("T_decoy2_C".into(), random_walk(rng, n, 22.0, 0.02)));
        decoys.extend(["F_clamp_N".to_string(), "T_decoy2_C".to_string()]);
    }
    if program == Program::Standard {
        cols.push(("run".into(), d.run));
    }
    (cols, decoys)
}

/// Write cases `0..count` of `seed` into `dir` as `case_NNNN.csv` + `case_NNNN.json`.
pub fn write_cases(seed: u64, count: usize, dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    write_family_cases(seed, count, &[Family::Standard], dir)
}

/// Write cases `0..count` of `seed` for each family into `dir` (`case_NNNN.*` for the standard
/// family, `<family>_NNNN.*` for the others).
pub fn write_family_cases(
    seed: u64,
    count: usize,
    families: &[Family],
    dir: &Path,
) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut out = vec![];
    for (&fam, i) in families
        .iter()
        .flat_map(|f| std::iter::repeat(f).zip(0..count))
    {
        let (rec, m) = generate_family_case(fam, seed, i);
        let csv = dir.join(format!("{}.csv", m.case));
        rec.write_csv(std::fs::File::create(&csv)?)?;
        std::fs::write(
            dir.join(format!("{}.json", m.case)),
            serde_json::to_string_pretty(&m)?,
        )?;
        out.push(csv);
    }
    Ok(out)
}
