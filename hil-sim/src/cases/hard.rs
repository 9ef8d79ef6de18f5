//! The hard families of `hil-sim gen-cases` (issue 12 item 6): the standard program of
//! [`super::generate_case`] with ONE difficulty changed per family, so a failure names its cause.
//!
//! | family | what changes | hidden effects (effect cases) |
//! |---|---|---|
//! | `ar099` | error noise = AR(1) with ρ 0.99 (stationary σ = `noise_um`) | every effect id in turn |
//! | `random_walk` | error noise = a Gaussian random walk, scaled to centred RMS `noise_um` | every effect id |
//! | `rw_decoy` | random-walk noise AND decoys `T_decoy_C` / `aux_V` that are random walks with their own, independent increments, each picked among 20 draws for the largest sample correlation with the ex / ey noise (spurious regression: they track the noise in the recording but share nothing with it) | every effect id |
//! | `rpm_heat` | spindle speed in steps (starting cold); a heat source seen ONLY through `rpm`: `ex += um_per_K·(LPF_τ(rpm) − rpm(0))`, gain in µm per rpm (`sensor: "rpm"`); no spindle sensor, and the column node is not heated by the spindle (no temperature near the source) | that lag, every effect case |
//! | `ambient_drift` | ambient drifts 1–4 K over the recording (ramp + a slow wave): every temperature and the thermal truth trend with time | every effect id |
//! | `regime` | rpm steps at 1000–3000 rpm for the first 60 % of the recording, 4500–8000 rpm after: the fit part never shows the hot regime | thermal lag / drift / expansion in turn |
//!
//! 30 % nulls (index mod 10 < 3), effect/noise 1–4 (the targets' range), one hidden effect per
//! case, half the nulls with large modelled terms (as the standard family). Deterministic per
//! (family, seed, index): the ChaCha8 stream is seeded from all three. `family_params` of the
//! manifest records what the family drew (ρ, decoy correlations, rpm split, ambient ramp…).

use std::collections::BTreeMap;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use retrocomp_analysis::diagnose::effects::{EFFECT_IDS, EffectModel};
use retrocomp_analysis::diagnose::features::Context;
use retrocomp_analysis::diagnose::scoring::{CaseManifest, TruthEffect};
use retrocomp_model::recording::Recording;

use super::physics::*;
use super::trajectory::uniform;
use super::{
    Drive, Errors, Program, build_path, contribution, draw_effect, error_columns,
    large_modelled_terms, path_speed, quantized_errors, rms_centered, schedule_slot, signed,
    time_axis, truth_columns, x_range,
};

/// A family of cases; `Standard` is [`super::generate_case`] (unchanged output for old seeds).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    Standard,
    Ar099,
    RandomWalk,
    RwDecoy,
    RpmHeat,
    AmbientDrift,
    Regime,
}

impl Family {
    pub const ALL: [Family; 7] = [
        Family::Standard,
        Family::Ar099,
        Family::RandomWalk,
        Family::RwDecoy,
        Family::RpmHeat,
        Family::AmbientDrift,
        Family::Regime,
    ];
    pub const HARD: [Family; 6] = [
        Family::Ar099,
        Family::RandomWalk,
        Family::RwDecoy,
        Family::RpmHeat,
        Family::AmbientDrift,
        Family::Regime,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Family::Standard => "standard",
            Family::Ar099 => "ar099",
            Family::RandomWalk => "random_walk",
            Family::RwDecoy => "rw_decoy",
            Family::RpmHeat => "rpm_heat",
            Family::AmbientDrift => "ambient_drift",
            Family::Regime => "regime",
        }
    }

    pub fn parse(s: &str) -> Option<Family> {
        Family::ALL.into_iter().find(|f| f.name() == s)
    }

    /// Case file stem: `case_NNNN` for the standard family (as before), `<family>_NNNN` otherwise.
    pub fn case_name(self, index: usize) -> String {
        match self {
            Family::Standard => format!("case_{index:04}"),
            f => format!("{}_{index:04}", f.name()),
        }
    }

    /// Seed-stream salt: distinct per family so families are independent draws.
    fn salt(self) -> u64 {
        let h = self.name().bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
        });
        h.rotate_left(17)
    }
}

/// Generate case `index` of `seed` in `family`.
pub fn generate_family_case(family: Family, seed: u64, index: usize) -> (Recording, CaseManifest) {
    if family == Family::Standard {
        return super::generate_case(seed, index);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(
        seed ^ family.salt() ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    );
    let (is_null, j) = schedule_slot(index);
    let id = match family {
        Family::RpmHeat => "rpm_lag",
        Family::Regime => ["thermal_lag", "thermal_drift", "thermal_expansion"][j % 3],
        _ => EFFECT_IDS[j % EFFECT_IDS.len()],
    };
    let mut fp: BTreeMap<String, f64> = BTreeMap::new();
    let d = family_drive(&mut rng, family, &mut fp);
    let n = d.t_s.len();
    let mut truth_cols = truth_columns(&d);
    truth_cols.push(("rpm".into(), d.rpm.clone()));
    let truth_rec = Recording::from_columns(truth_cols).expect("generator columns are valid");
    let mut tctx = Context::from_recording(&truth_rec);
    // The rpm-driven lag is evaluated by the shared forward model with `rpm` as its driver.
    tctx.temps.push(("rpm".into(), d.rpm.clone().into()));
    let x_range = x_range(&d.path);
    let mut hidden = vec![];
    if !is_null {
        hidden.push(family_effect(&mut rng, id, x_range, &mut fp));
    }
    let modelled = if is_null && rng.random_bool(0.5) {
        large_modelled_terms(&mut rng)
    } else {
        vec![]
    };
    let contrib = |effs: &[TruthEffect], sig: &str| contribution(effs, sig, n, &tctx);
    let (hx, hy) = (contrib(&hidden, "ex_um"), contrib(&hidden, "ey_um"));
    let (mx, my) = (contrib(&modelled, "ex_um"), contrib(&modelled, "ey_um"));
    let effect_rms = hidden
        .iter()
        .map(|e| rms_centered(&contrib(std::slice::from_ref(e), &e.signal)))
        .fold(f64::INFINITY, f64::min);
    let snr = (!is_null).then(|| uniform(&mut rng, 1.0, 4.0));
    let noise_um = match snr {
        None => uniform(&mut rng, 0.3, 2.0),
        Some(s) => effect_rms / s,
    };
    let (nx, ny, noise_desc) = noise(&mut rng, family, n, noise_um, &mut fp);
    let errors = Errors {
        ex_um: quantized_errors(&hx, &mx, &nx),
        ey_um: quantized_errors(&hy, &my, &ny),
        sim_ex_um: mx,
        sim_ey_um: my,
    };
    let cols = family_columns(&mut rng, family, d, errors, (&nx, &ny), &mut fp);
    let rec = Recording::from_columns(cols).expect("generated recording is valid");
    let notes = format!(
        "family {}; program Standard; thermal truth on node temperatures (sensors lag 15/30/60 s, \
         0.1 °C steps); noise: {noise_desc}; 0.05 um steps; hidden effect RMS {effect_rms:.3} um",
        family.name()
    );
    let manifest = CaseManifest {
        case: family.case_name(index),
        seed,
        family: family.name().into(),
        class: if is_null { "null" } else { "single" }.into(),
        hidden,
        modelled,
        noise_um,
        snr,
        identifiable: true,
        expected_verdict: if is_null { "none" } else { "found" }.into(),
        decoys: vec!["T_decoy_C".into(), "aux_V".into(), "T_amb_C".into()],
        family_params: fp,
        notes,
    };
    (rec, manifest)
}

/// The family's motion, spindle, ambient, thermal and force draws, in the generator's fixed order:
/// the standard program, with the family's rpm profile, ambient and spindle-to-column heat share.
fn family_drive(rng: &mut ChaCha8Rng, family: Family, fp: &mut BTreeMap<String, f64>) -> Drive {
    let path = build_path(rng, Program::Standard);
    let n = path.len();
    let t_s = time_axis(n);
    let duration = t_s[n - 1];
    let rpm = match family {
        Family::RpmHeat => rpm_steps(rng, &t_s, (1500.0, 8000.0), None, fp),
        Family::Regime => rpm_steps(
            rng,
            &t_s,
            (1000.0, 3000.0),
            Some((0.6, (4500.0, 8000.0))),
            fp,
        ),
        _ => {
            // The standard profile: warm-up at one speed, then cool-down.
            let t_off = duration * uniform(rng, 0.55, 0.7);
            let level = uniform(rng, 4000.0, 8000.0);
            t_s.iter()
                .map(|&t| if t < t_off { level } else { 0.0 })
                .collect()
        }
    };
    let ambient_c = ambient(rng, family, &t_s, fp);
    let speed = path_speed(&path);
    let tau_node = uniform(rng, 300.0, 700.0);
    let k_heat = uniform(rng, 0.8, 1.2);
    // rpm_heat: the column node gets no spindle heat (no temperature sensor near the source).
    let spindle_share = if family == Family::RpmHeat { 0.0 } else { 0.4 };
    let th = thermal_with_ambient(
        &t_s,
        ambient_c,
        &rpm,
        &speed,
        k_heat,
        tau_node,
        1500.0,
        spindle_share,
    );
    Drive::with_force(rng, path, t_s, rpm, th)
}

/// The hidden effect of an effect case: `rpm_lag` (the rpm_heat family's heat source seen only
/// through `rpm`, its lag recorded in `fp`), otherwise a standard effect of id `id`.
fn family_effect(
    rng: &mut ChaCha8Rng,
    id: &str,
    x_range: (f64, f64),
    fp: &mut BTreeMap<String, f64>,
) -> TruthEffect {
    match id {
        "rpm_lag" => {
            let tau_s = uniform(rng, 300.0, 1200.0);
            fp.insert("rpm_tau_s".into(), tau_s);
            TruthEffect {
                signal: "ex_um".into(),
                axis: "x".into(),
                model: EffectModel::ThermalLag {
                    sensor: "rpm".into(),
                    tau_s,
                    // µm per rpm (0.5–3 µm per 1000 rpm).
                    um_per_k: signed(rng, 0.5, 3.0) * 1e-3,
                },
            }
        }
        id => draw_effect(rng, id, x_range),
    }
}

/// The family's recorded columns, sensors drawn in the generator's fixed order: `rw_decoy` picks
/// its decoys for correlation with the error noise `(nx, ny)`; `rpm_heat` records no spindle
/// temperature.
fn family_columns(
    rng: &mut ChaCha8Rng,
    family: Family,
    d: Drive,
    errors: Errors,
    (nx, ny): (&[f64], &[f64]),
    fp: &mut BTreeMap<String, f64>,
) -> Vec<(String, Vec<f64>)> {
    let n = d.t_s.len();
    let t_column = temp_sensor(rng, &d.t_s, &d.th.structure_c, 30.0, 0.02);
    let t_amb = temp_sensor(rng, &d.t_s, &d.th.ambient_c, 60.0, 0.02);
    let (t_decoy, aux) = if family == Family::RwDecoy {
        let (decoy, cx) = correlated_walk_decoy(rng, nx, 21.0, 0.01, 20);
        let (a, cy) = correlated_walk_decoy(rng, ny, 0.0, 0.05, 20);
        fp.insert("decoy_corr_ex".into(), cx);
        fp.insert("aux_corr_ey".into(), cy);
        (decoy, a)
    } else {
        (
            random_walk(rng, n, 21.0, 0.01),
            random_walk(rng, n, 0.0, 0.05),
        )
    };
    let f_cut = load_cell(rng, &d.force, 2.0);
    let strain = strain_gauge(rng, &d.force, &t_column, 0.05, 2.0);
    let mut cols = error_columns(d.t_s.clone(), &d.path, errors);
    if family != Family::RpmHeat {
        cols.push((
            "T_spindle_C".into(),
            temp_sensor(rng, &d.t_s, &d.th.spindle_c, 15.0, 0.02),
        ));
    }
    cols.extend([
        ("T_column_C".into(), t_column),
        ("T_amb_C".into(), t_amb),
        ("T_decoy_C".into(), t_decoy),
        ("rpm".into(), d.rpm),
        ("F_cut_N".into(), f_cut),
        ("strain_col_ue".into(), strain),
        ("tool_mm".into(), d.path.tool_mm),
        ("aux_V".into(), aux),
        ("run".into(), d.run),
    ]);
    cols
}

/// Spindle speed in steps: idle for the first 5–10 min (the machine starts cold), then segments of
/// 5–15 min at levels drawn from `lo_hi` (a fifth of them idle), 10 rpm resolution. With `late =
/// Some((frac, range))` the segments starting after `frac` of the recording draw from `range`.
fn rpm_steps(
    rng: &mut ChaCha8Rng,
    t_s: &[f64],
    lo_hi: (f64, f64),
    late: Option<(f64, (f64, f64))>,
    fp: &mut BTreeMap<String, f64>,
) -> Vec<f64> {
    let duration = t_s[t_s.len() - 1];
    let split_s = late.map_or(f64::INFINITY, |(f, _)| f * duration);
    if split_s.is_finite() {
        fp.insert("regime_split_s".into(), split_s);
    }
    let mut edges = vec![(0.0, 0.0)];
    let mut t = uniform(rng, 300.0, 600.0);
    while t < duration {
        let range = if t >= split_s {
            late.expect("split").1
        } else {
            lo_hi
        };
        let level = if rng.random_bool(0.2) {
            0.0
        } else {
            quantize(uniform(rng, range.0, range.1), 10.0)
        };
        edges.push((t, level));
        // A segment never straddles the regime split: the fit part sees only its own range.
        let next = t + uniform(rng, 300.0, 900.0);
        t = if t < split_s && next > split_s {
            split_s
        } else {
            next
        };
    }
    t_s.iter()
        .map(|&ti| {
            edges
                .iter()
                .rev()
                .find(|(s, _)| *s <= ti)
                .map_or(0.0, |e| e.1)
        })
        .collect()
}

/// Ambient: the standard slow wave (±0.3 K over 4× the duration), or for `ambient_drift` a ramp of
/// ±1–4 K over the recording plus a wave of 0.3–1 K with a period of a third to two thirds of it.
fn ambient(
    rng: &mut ChaCha8Rng,
    family: Family,
    t_s: &[f64],
    fp: &mut BTreeMap<String, f64>,
) -> Vec<f64> {
    let duration = t_s[t_s.len() - 1];
    if family != Family::AmbientDrift {
        return standard_ambient(t_s, 0.3, 4.0 * duration);
    }
    let ramp = signed(rng, 1.0, 4.0);
    let amp = uniform(rng, 0.3, 1.0);
    let period = duration * uniform(rng, 0.33, 0.67);
    let phase = uniform(rng, -3.1, 3.1);
    fp.insert("ambient_ramp_K".into(), ramp);
    fp.insert("ambient_wave_K".into(), amp);
    fp.insert("ambient_wave_period_s".into(), period);
    fp.insert("ambient_wave_phase_rad".into(), phase);
    t_s.iter()
        .map(|&t| {
            20.0 + ramp * t / duration + amp * ((std::f64::consts::TAU * t / period + phase).sin())
                - amp * phase.sin()
        })
        .collect()
}

/// The family's error noise on ex and ey (µm) and a description for the manifest's notes.
fn noise(
    rng: &mut ChaCha8Rng,
    family: Family,
    n: usize,
    sigma_um: f64,
    fp: &mut BTreeMap<String, f64>,
) -> (Vec<f64>, Vec<f64>, String) {
    match family {
        Family::Ar099 => {
            fp.insert("noise_ar_rho".into(), 0.99);
            (
                ar1_noise(rng, n, sigma_um, 0.99),
                ar1_noise(rng, n, sigma_um, 0.99),
                "AR(1) rho 0.99, stationary sigma = noise_um".into(),
            )
        }
        Family::RandomWalk | Family::RwDecoy => (
            walk_noise(rng, n, sigma_um),
            walk_noise(rng, n, sigma_um),
            "Gaussian random walk scaled to centred RMS = noise_um".into(),
        ),
        _ => (
            error_noise(rng, n, sigma_um),
            error_noise(rng, n, sigma_um),
            "white+AR(1) rho 0.9, 0.5 % outliers at 6 sigma".into(),
        ),
    }
}
