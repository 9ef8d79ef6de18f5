//! Artefact readings → observations of the joint fit, with thermal expansion removed.
//!
//! Hole plate (plane axes a, b): the hole's actual position is H = c + R(θ)·p, p the certified
//! centre expanded to the plate temperature; the machine reads r where r + e(r) = H, so
//! r − c₀ − R(θ₀)p = −e(r) + δc + δθ·J·R(θ₀)p (J = 90° in-plane rotation). (c₀, θ₀) is a first
//! rigid fit of the plate (2-D Procrustes), so the linearised rotation stays tiny. Only the two
//! in-plane directions are observed; the plate's out-of-plane pose is not seen to first order.
//!
//! Ball bar: the bar reads L = |r + e(r) − C| with C = C₀ + δC, so
//! dr − (|r − C₀| − R_nom) = n·e(r) − n·δC, n the unit vector from C₀ to r. The bar's length is
//! its certificate at 20 °C expanded to `T_bar_C`.
//!
//! y in µm; positions mm; set-up parameters µm (translations, centres) and µrad (rotations).

use super::contracts::{BallBar, HolePlate, REFERENCE_C, scale_corrected};
use super::design::Obs;

/// How many γ parameters each artefact has, and its kind.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Setup {
    pub name: String,
    pub kind: &'static str,
    /// Index of the first γ column.
    pub first: usize,
    pub names: Vec<String>,
    /// Rigid first guess: plate (c_a, c_b mm, θ rad); sphere centre (mm).
    pub nominal: Vec<f64>,
}

/// Plate coordinates p (mm) of each probing at its plate temperature.
pub(super) fn expanded_uv(plate: &HolePlate) -> Vec<[f64; 2]> {
    plate
        .probes
        .iter()
        .map(|p| {
            let k = p.t_plate_c.map_or(1.0, |t| {
                1.0 + plate.alpha_ppm_per_k * 1e-6 * (t - REFERENCE_C)
            });
            [p.uv_mm[0] * k, p.uv_mm[1] * k]
        })
        .collect()
}

/// Corrected in-plane machine coordinates of each probing.
pub(super) fn plane_readings(plate: &HolePlate) -> Vec<[f64; 2]> {
    let [a, b] = plate.plane.axes();
    plate
        .probes
        .iter()
        .map(|p| {
            let r = scale_corrected(p.pos_mm, p.t_scale_c, plate.scale_alpha_ppm_per_k);
            [r[a], r[b]]
        })
        .collect()
}

/// Least-squares rigid 2-D fit r ≈ c + R(θ)p: (c, θ).
pub(super) fn rigid_2d(p: &[[f64; 2]], r: &[[f64; 2]]) -> ([f64; 2], f64) {
    let n = p.len() as f64;
    let mp = p
        .iter()
        .fold([0.0; 2], |a, x| [a[0] + x[0] / n, a[1] + x[1] / n]);
    let mr = r
        .iter()
        .fold([0.0; 2], |a, x| [a[0] + x[0] / n, a[1] + x[1] / n]);
    let (mut sc, mut ss) = (0.0, 0.0);
    for (p, r) in p.iter().zip(r) {
        let (pu, pv) = (p[0] - mp[0], p[1] - mp[1]);
        let (ru, rv) = (r[0] - mr[0], r[1] - mr[1]);
        sc += pu * ru + pv * rv;
        ss += pu * rv - pv * ru;
    }
    let th = ss.atan2(sc);
    let (s, c) = th.sin_cos();
    (
        [
            mr[0] - (c * mp[0] - s * mp[1]),
            mr[1] - (s * mp[0] + c * mp[1]),
        ],
        th,
    )
}

/// Rotates p by θ.
pub(super) fn rot(th: f64, p: [f64; 2]) -> [f64; 2] {
    let (s, c) = th.sin_cos();
    [c * p[0] - s * p[1], s * p[0] + c * p[1]]
}

/// Observations of one plate (two per probing); γ columns start at `first`.
pub(super) fn plate_obs(plate: &HolePlate, artefact: usize, first: usize) -> (Vec<Obs>, Setup) {
    let [a, b] = plate.plane.axes();
    let p = expanded_uv(plate);
    let r = plane_readings(plate);
    let (c0, th0) = rigid_2d(&p, &r);
    let mut obs = Vec::with_capacity(2 * p.len());
    for (i, probe) in plate.probes.iter().enumerate() {
        let rp = rot(th0, p[i]);
        let jrp = [-rp[1], rp[0]];
        let pos = scale_corrected(probe.pos_mm, probe.t_scale_c, plate.scale_alpha_ppm_per_k);
        for (k, axis) in [a, b].into_iter().enumerate() {
            let mut n = [0.0; 3];
            n[axis] = -1.0;
            obs.push(Obs {
                pos_mm: pos,
                tool_mm: probe.tool_mm,
                n,
                y_um: (r[i][k] - c0[k] - rp[k]) * 1e3,
                setup: vec![(first + k, 1.0), (first + 2, jrp[k] * 1e-3)],
                artefact,
                key: probe.hole.clone(),
                repeat: probe.repeat,
                dir: Some(axis),
            });
        }
    }
    let ax = |i: usize| ["x", "y", "z"][i];
    let setup = Setup {
        name: plate.name.clone(),
        kind: "hole_plate",
        first,
        names: vec![
            format!("translation_{}_um", ax(a)),
            format!("translation_{}_um", ax(b)),
            "rotation_urad".into(),
        ],
        nominal: vec![c0[0], c0[1], th0],
    };
    (obs, setup)
}

/// Observations of one ball-bar sphere (one per point); γ = centre shift (3).
pub(super) fn ballbar_obs(bar: &BallBar, artefact: usize, first: usize) -> (Vec<Obs>, Setup) {
    let c0 = bar.centre_mm;
    let mut obs = Vec::with_capacity(bar.points.len());
    for pt in &bar.points {
        let r = scale_corrected(pt.pos_mm, pt.t_scale_c, bar.scale_alpha_ppm_per_k);
        let d = [r[0] - c0[0], r[1] - c0[1], r[2] - c0[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let n = d.map(|v| v / len);
        // The bar at its temperature is longer than certified: the reading dr is relative to it.
        let r_bar = bar.r_nom_mm
            * pt.t_bar_c.map_or(1.0, |t| {
                1.0 + bar.alpha_ppm_per_k * 1e-6 * (t - REFERENCE_C)
            });
        obs.push(Obs {
            pos_mm: r,
            tool_mm: pt.tool_mm,
            n,
            y_um: pt.dr_um + (r_bar - len) * 1e3,
            setup: (0..3).map(|k| (first + k, -n[k])).collect(),
            artefact,
            key: pt.point.clone(),
            repeat: 0,
            dir: None,
        });
    }
    let setup = Setup {
        name: bar.name.clone(),
        kind: "ballbar",
        first,
        names: vec![
            "centre_x_um".into(),
            "centre_y_um".into(),
            "centre_z_um".into(),
        ],
        nominal: c0.to_vec(),
    };
    (obs, setup)
}
