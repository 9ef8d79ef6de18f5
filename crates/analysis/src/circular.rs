//! Circular test analysis: ISO 230-4 circular deviation G and radial deviation F, and a ballbar
//! diagnosis that fits named error sources to the radial deviation of CW and CCW traces, each with
//! its share of the deviation (the Renishaw-style list in anchors-compensation.md §b).
//!
//! Input: traces of radial deviation Δr (µm, measured radius − nominal radius, about the nominal
//! centre, i.e. the ballbar pivot) at angle θ (rad, from +X towards +Y in the test plane), in the
//! order sampled. Nominal path x = R cosθ, y = R sinθ; X reverses at 0°/180°, Y at 90°/270°.
//! First order: Δr = ex·cosθ + ey·sinθ, with error e = actual − nominal.
//!
//! Terms and their parameter conventions (v = direction of axis motion, sgn ±1):
//! - `backlash_x` `b_um`: ex = −(b/2)·sgn(vx) (b > 0: lost motion, the axis falls short); `_y` alike.
//! - `lateral_play_x` `p_um`: ey = (p/2)·sgn(vx) (X carriage shifts sideways when X reverses); `_y`: ex = (p/2)·sgn(vy).
//! - `reversal_spike_x` `amplitude_um`, `decay_mm`: ex = −a·sgn(vx)·exp(−s/λ), s = path length since the X reversal.
//! - `cyclic_x` `amplitude_um`, `period_mm`: ex = a·sin(2πx/λ + φ) (only when the period is given).
//! - `servo_mismatch` `ms`: ex = −vx·τx, ey = −vy·τy, reported Δτ = τx − τy (tilt flips with rotation;
//!   needs both a CW and a CCW trace, otherwise it is indistinguishable from squareness and omitted).
//! - `squareness` `urad`: ex = α·y (α = −EC0Y in ISO 230-1 terms; same tilt in CW and CCW).
//! - `straightness_x` `bow_um`: ey = bow·(x/R)²; `straightness_y`: ex = bow·(y/R)².
//! - `scale_mismatch` `ppm`: ex = εx·x, ey = εy·y, reported εx − εy (the mean scale is
//!   indistinguishable from a radius error and is reported as `radius_error_um`).
//!
//! The centre offset (setup) and the radius error are fitted but not given a share.

use std::collections::BTreeMap;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::fit::{LsqError, lstsq};
use super::import_error::{ErrorSink, ImportErrors};

mod terms;

use terms::{Fitted, path_terms, reversal_terms};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Rotation {
    Ccw,
    Cw,
}

impl Rotation {
    fn sign(self) -> f64 {
        match self {
            Rotation::Ccw => 1.0,
            Rotation::Cw => -1.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct CircleTrace {
    pub rotation: Rotation,
    pub angle_rad: Vec<f64>,
    pub dr_um: Vec<f64>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct CircleSetup {
    pub radius_mm: f64,
    pub feed_mm_per_min: f64,
    pub cyclic_period_x_mm: Option<f64>,
    pub cyclic_period_y_mm: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Iso230_4 {
    /// Circular deviation per trace (radial band about its least-squares centre).
    pub g_um: BTreeMap<String, f64>,
    /// Bi-directional circular deviation G(b) (both traces, common LSQ centre), when CW and CCW exist.
    pub g_bidirectional_um: Option<f64>,
    /// Radial deviation F about the nominal centre and radius: max and min of Δr.
    pub f_max_um: f64,
    pub f_min_um: f64,
    pub centre_method: &'static str,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TermFit {
    pub effect: String,
    pub params: BTreeMap<String, f64>,
    /// Peak-to-valley of this term's radial contribution over the traces.
    pub contribution_um: f64,
    /// contribution / Σ contributions × 100.
    pub share_pct: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CircleReport {
    pub standard: &'static str,
    pub radius_mm: f64,
    pub feed_mm_per_min: f64,
    pub iso230_4: Iso230_4,
    pub radius_error_um: f64,
    pub centre_x_um: f64,
    pub centre_y_um: f64,
    pub terms: Vec<TermFit>,
    pub residual_rms_um: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CircleError {
    #[error("no trace")]
    Empty,
    #[error("trace {index}: {angles} angles but {values} deviations")]
    Lengths {
        index: usize,
        angles: usize,
        values: usize,
    },
    #[error("non-finite value in trace {index}")]
    NonFinite { index: usize },
    #[error("radius and feed must be positive")]
    Setup,
    #[error(transparent)]
    Lsq(#[from] LsqError),
}

/// Path length travelled since the last reversal of an axis that reverses at θ = `at` and `at + π`.
fn since_reversal_mm(theta: f64, at: f64, rot: Rotation, r_mm: f64) -> f64 {
    let phi = (theta - at).rem_euclid(PI);
    let ang = match rot {
        Rotation::Ccw => phi,
        Rotation::Cw => (PI - phi).rem_euclid(PI),
    };
    r_mm * ang
}

fn sgn(v: f64) -> f64 {
    if v >= 0.0 { 1.0 } else { -1.0 }
}

struct Column {
    effect: &'static str,
    values: Vec<f64>,
}

/// Builds the regressors for all samples of all traces, for a given spike decay length.
fn columns(traces: &[CircleTrace], setup: &CircleSetup, decay_mm: f64) -> Vec<Column> {
    let r = setup.radius_mm;
    let mut cols: Vec<Column> = Vec::new();
    let mut add = |effect: &'static str, f: &dyn Fn(f64, Rotation) -> f64| {
        let values = traces
            .iter()
            .flat_map(|t| t.angle_rad.iter().map(move |&th| (th, t.rotation)))
            .map(|(th, rot)| f(th, rot))
            .collect();
        cols.push(Column { effect, values });
    };
    // Velocity direction of the nominal motion: CCW v ∝ (−sinθ, cosθ).
    let vx = |th: f64, rot: Rotation| sgn(-rot.sign() * th.sin());
    let vy = |th: f64, rot: Rotation| sgn(rot.sign() * th.cos());
    add("radius", &|_, _| 1.0);
    add("centre_x", &|th, _| th.cos());
    add("centre_y", &|th, _| th.sin());
    add("backlash_x", &|th, rot| vx(th, rot) * th.cos());
    add("backlash_y", &|th, rot| vy(th, rot) * th.sin());
    add("lateral_play_x", &|th, rot| vx(th, rot) * th.sin());
    add("lateral_play_y", &|th, rot| vy(th, rot) * th.cos());
    add("reversal_spike_x", &|th, rot| {
        vx(th, rot) * (-since_reversal_mm(th, 0.0, rot, r) / decay_mm).exp() * th.cos()
    });
    add("reversal_spike_y", &|th, rot| {
        vy(th, rot) * (-since_reversal_mm(th, FRAC_PI_2, rot, r) / decay_mm).exp() * th.sin()
    });
    if let Some(p) = setup.cyclic_period_x_mm {
        add("cyclic_x_sin", &|th, _| {
            (TAU * r * th.cos() / p).sin() * th.cos()
        });
        add("cyclic_x_cos", &|th, _| {
            (TAU * r * th.cos() / p).cos() * th.cos()
        });
    }
    if let Some(p) = setup.cyclic_period_y_mm {
        add("cyclic_y_sin", &|th, _| {
            (TAU * r * th.sin() / p).sin() * th.sin()
        });
        add("cyclic_y_cos", &|th, _| {
            (TAU * r * th.sin() / p).cos() * th.sin()
        });
    }
    // Servo mismatch is told from squareness only by its sign flip between CW and CCW: with one
    // rotation the two columns are identical, so it is not fitted (and not reported).
    let both = traces.iter().any(|t| t.rotation == Rotation::Cw)
        && traces.iter().any(|t| t.rotation == Rotation::Ccw);
    if both {
        add("servo_mismatch", &|th, rot| rot.sign() * (2.0 * th).sin());
    }
    add("squareness", &|th, _| (2.0 * th).sin());
    add("straightness_x", &|th, _| th.cos().powi(2) * th.sin());
    add("straightness_y", &|th, _| th.sin().powi(2) * th.cos());
    add("scale_mismatch", &|th, _| (2.0 * th).cos());
    cols
}

fn p2v(v: &[f64]) -> f64 {
    v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
        - v.iter().cloned().fold(f64::INFINITY, f64::min)
}

/// Least-squares circle (Δr = r0 + cx cosθ + cy sinθ) residual band.
fn band_about_lsq_centre(angles: &[f64], dr: &[f64]) -> Result<f64, LsqError> {
    let x = DMatrix::from_fn(angles.len(), 3, |i, j| {
        [1.0, angles[i].cos(), angles[i].sin()][j]
    });
    let y = DVector::from_column_slice(dr);
    let f = lstsq(&x, &y)?;
    let res = y - x * f.beta;
    Ok(p2v(res.as_slice()))
}

/// Analyses the traces. Spike decay length is chosen by least squares over a log grid 0.2–20 mm.
pub fn analyse(traces: &[CircleTrace], setup: &CircleSetup) -> Result<CircleReport, CircleError> {
    check_input(traces, setup)?;
    // ISO 230-4.
    let (iso, all_dr) = iso230_4(traces)?;

    // Diagnosis: pick the spike decay by SSE over a grid, then fit all terms.
    let best = best_decay(traces, setup, &all_dr)?;
    let fit = Fitted {
        cols: &best.cols,
        beta: &best.beta,
        n: all_dr.len(),
    };
    let mut terms = reversal_terms(&fit, best.decay);
    terms.extend(path_terms(&fit, setup));
    let total: f64 = terms.iter().map(|t| t.contribution_um).sum();
    for t in &mut terms {
        t.share_pct = if total > 0.0 {
            100.0 * t.contribution_um / total
        } else {
            0.0
        };
    }
    terms.sort_by(|a, b| b.contribution_um.total_cmp(&a.contribution_um));
    Ok(CircleReport {
        standard: "ISO 230-4:2005",
        radius_mm: setup.radius_mm,
        feed_mm_per_min: setup.feed_mm_per_min,
        iso230_4: iso,
        radius_error_um: fit.c("radius"),
        centre_x_um: fit.c("centre_x"),
        centre_y_um: fit.c("centre_y"),
        terms,
        residual_rms_um: (best.sse / all_dr.len() as f64).sqrt(),
    })
}

/// Rejects what the fit cannot take (no trace, a bad setup, ragged or non-finite traces) before
/// any work, in the order the errors are reported.
fn check_input(traces: &[CircleTrace], setup: &CircleSetup) -> Result<(), CircleError> {
    if traces.is_empty() {
        return Err(CircleError::Empty);
    }
    if !(setup.radius_mm > 0.0 && setup.feed_mm_per_min > 0.0) {
        return Err(CircleError::Setup);
    }
    for (i, t) in traces.iter().enumerate() {
        if t.angle_rad.len() != t.dr_um.len() {
            return Err(CircleError::Lengths {
                index: i,
                angles: t.angle_rad.len(),
                values: t.dr_um.len(),
            });
        }
        if t.angle_rad.iter().chain(&t.dr_um).any(|v| !v.is_finite()) {
            return Err(CircleError::NonFinite { index: i });
        }
    }
    Ok(())
}

/// The ISO 230-4 figures, and every trace's deviations in one series (the diagnosis fits it).
fn iso230_4(traces: &[CircleTrace]) -> Result<(Iso230_4, Vec<f64>), CircleError> {
    let mut g_um = BTreeMap::new();
    for t in traces {
        let key = format!("{:?}", t.rotation).to_lowercase();
        g_um.insert(key, band_about_lsq_centre(&t.angle_rad, &t.dr_um)?);
    }
    let has_both = traces.iter().any(|t| t.rotation == Rotation::Cw)
        && traces.iter().any(|t| t.rotation == Rotation::Ccw);
    let all_th: Vec<f64> = traces
        .iter()
        .flat_map(|t| t.angle_rad.iter().cloned())
        .collect();
    let all_dr: Vec<f64> = traces
        .iter()
        .flat_map(|t| t.dr_um.iter().cloned())
        .collect();
    let g_b = if has_both {
        Some(band_about_lsq_centre(&all_th, &all_dr)?)
    } else {
        None
    };
    let iso = Iso230_4 {
        g_um,
        g_bidirectional_um: g_b,
        f_max_um: all_dr.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        f_min_um: all_dr.iter().cloned().fold(f64::INFINITY, f64::min),
        centre_method: "least squares",
    };
    Ok((iso, all_dr))
}

/// The least-squares fit at the spike decay with the lowest SSE.
struct DecayFit {
    decay: f64,
    cols: Vec<Column>,
    beta: DVector<f64>,
    sse: f64,
}

/// Fits every term at each decay of the grid and keeps the best (the first of equals).
fn best_decay(
    traces: &[CircleTrace],
    setup: &CircleSetup,
    all_dr: &[f64],
) -> Result<DecayFit, CircleError> {
    let y = DVector::from_column_slice(all_dr);
    let mut best: Option<DecayFit> = None;
    for k in 0..=40 {
        let decay = 0.2 * 100f64.powf(f64::from(k) / 40.0);
        let cols = columns(traces, setup, decay);
        let x = DMatrix::from_fn(all_dr.len(), cols.len(), |i, j| cols[j].values[i]);
        let f = lstsq(&x, &y)?;
        if best.as_ref().is_none_or(|b| f.sse < b.sse) {
            best = Some(DecayFit {
                decay,
                cols,
                beta: f.beta,
                sse: f.sse,
            });
        }
    }
    Ok(best.expect("grid is not empty"))
}

/// Text form.
pub fn to_text(rep: &CircleReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{} circular test, R = {} mm, F = {} mm/min",
        rep.standard, rep.radius_mm, rep.feed_mm_per_min
    );
    for (k, g) in &rep.iso230_4.g_um {
        let _ = writeln!(s, "G ({k}) = {g:.2} µm");
    }
    if let Some(g) = rep.iso230_4.g_bidirectional_um {
        let _ = writeln!(s, "G(b) = {g:.2} µm");
    }
    let _ = writeln!(
        s,
        "F: max {:.2} µm, min {:.2} µm (nominal centre); centre {}",
        rep.iso230_4.f_max_um, rep.iso230_4.f_min_um, rep.iso230_4.centre_method
    );
    let _ = writeln!(
        s,
        "radius error {:.2} µm, centre offset ({:.2}, {:.2}) µm",
        rep.radius_error_um, rep.centre_x_um, rep.centre_y_um
    );
    let _ = writeln!(
        s,
        "{:<18} {:>10} {:>7}  params",
        "effect", "p-v_um", "share%"
    );
    for t in &rep.terms {
        let p: Vec<String> = t
            .params
            .iter()
            .map(|(k, v)| format!("{k}={v:.3}"))
            .collect();
        let _ = writeln!(
            s,
            "{:<18} {:>10.2} {:>7.1}  {}",
            t.effect,
            t.contribution_um,
            t.share_pct,
            p.join(" ")
        );
    }
    let _ = writeln!(s, "residual rms {:.3} µm", rep.residual_rms_um);
    s
}

/// The traces of a ballbar CSV `angle_deg,dr_um,direction` (direction `ccw` or `cw`, rows in
/// sampling order; dr_um = measured radius − nominal radius), one per direction present. `file`
/// names the text in the located errors; every bad row is reported.
pub fn parse_traces(file: &str, text: &str) -> Result<Vec<CircleTrace>, ImportErrors> {
    let mut sink = ErrorSink::new(file);
    let mut ccw = CircleTrace {
        rotation: Rotation::Ccw,
        angle_rad: vec![],
        dr_um: vec![],
    };
    let mut cw = CircleTrace {
        rotation: Rotation::Cw,
        angle_rad: vec![],
        dr_um: vec![],
    };
    let mut header_seen = false;
    for (i, raw) in text.lines().enumerate() {
        let line = i as u64 + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            continue;
        }
        let f: Vec<&str> = body.split(',').map(str::trim).collect();
        if !header_seen {
            if f != ["angle_deg", "dr_um", "direction"] {
                sink.push(
                    line,
                    None,
                    format!("expected header `angle_deg,dr_um,direction`, found `{body}`"),
                );
                return sink.finish(vec![]);
            }
            header_seen = true;
            continue;
        }
        if f.len() != 3 {
            sink.push(line, None, format!("expected 3 fields, found {}", f.len()));
            continue;
        }
        let a = sink.parse_f64(line, "angle_deg", f[0]);
        let d = sink.parse_f64(line, "dr_um", f[1]);
        let t = match f[2] {
            "ccw" | "CCW" => Some(&mut ccw),
            "cw" | "CW" => Some(&mut cw),
            other => {
                sink.push(
                    line,
                    Some("direction"),
                    format!("expected `ccw` or `cw`, found `{other}`"),
                );
                None
            }
        };
        if let (Some(a), Some(d), Some(t)) = (a, d, t) {
            t.angle_rad.push(a.to_radians());
            t.dr_um.push(d);
        }
    }
    if !header_seen {
        sink.push(0, None, "empty file");
    }
    let traces: Vec<CircleTrace> = [ccw, cw]
        .into_iter()
        .filter(|t| !t.angle_rad.is_empty())
        .collect();
    if traces.is_empty() && sink.is_empty() {
        sink.push(0, None, "no data rows");
    }
    sink.finish(traces)
}
