//! The kinematic chain: nominal translations, Abbe arms and the exact product of 4×4 homogeneous
//! transforms (nalgebra).
//!
//! The chain is read from workpiece to tool. With `n_K` the nominal translation of element K and
//! `E_K = Trans(δ_K) · Rot(ε_K)` its error motion (Rot = Rx(εa)·Ry(εb)·Rz(εc)), the tool tip
//! relative to the workpiece is
//!
//! ```text
//! r = Π_K  M_K · t,   M_K = E_K · Trans(q_K ũ_K − o_K)   (workpiece-branch axis)
//!                     M_K = Trans(o_K + q_K ũ_K) · E_K   (tool-branch axis)
//! ```
//!
//! where `ũ_K` is the axis direction tilted by its squareness errors and `o_K` the carriage's offset.
//! A workpiece-branch carriage therefore rotates about its own reference point, which the tool sees
//! at the arm `Σ_{k ≥ K} n_k + t` (own travel included, as in Graves' Z slide and Spaan's moving
//! table); a tool-branch carriage rotates about its reference point, arm `Σ_{k > K} n_k + t`.
//! Error = r − r_nominal; first order it is Σ δ_K + ε_K × arm_K + q_K (ũ_K − u_K).

#[cfg(test)]
use nalgebra::Vector3;
use nalgebra::{Matrix3, Matrix4};

use super::names::Axis;
use super::spec::{AxisSpec, Branch};

/// sin and cos; exact to double precision. Small angles (all error motions) use a Taylor series
/// whose truncation error is below 1e-17 for |θ| ≤ 1e-2 rad; larger angles use libm. Up to 1e-4 rad
/// (100 µrad, far above typical error motions) two terms each suffice: the first dropped terms,
/// θ⁵/120 and θ⁶/720, are below 1e-18 of θ and 1e-26.
#[inline]
pub fn sin_cos(theta: f64) -> (f64, f64) {
    let a = theta.abs();
    let t2 = theta * theta;
    if a <= 1e-4 {
        (
            theta - theta * t2 * (1.0 / 6.0),
            1.0 - t2 * 0.5 + t2 * t2 * (1.0 / 24.0),
        )
    } else if a <= 1e-2 {
        // Multiplications by the reciprocals: a division is ~10× slower, and the rounding of 1/6
        // etc. changes the correction terms (≤ 1.7e-5 of θ) by ≤ 1e-16 of themselves.
        let s = theta
            * (1.0 - t2 * (1.0 / 6.0) * (1.0 - t2 * (1.0 / 20.0) * (1.0 - t2 * (1.0 / 42.0))));
        let c = 1.0
            - t2 * 0.5
                * (1.0 - t2 * (1.0 / 12.0) * (1.0 - t2 * (1.0 / 30.0) * (1.0 - t2 * (1.0 / 56.0))));
        (s, c)
    } else {
        theta.sin_cos()
    }
}

/// [`sin_cos`] of nine angles (rad). When every |θ| ≤ 1e-4 (all error motions in practice) one
/// test chooses the short series for all nine, which then run as straight array arithmetic; the
/// values are the same as nine calls would give.
#[inline(always)]
pub(crate) fn sin_cos_9(theta: [f64; 9]) -> ([f64; 9], [f64; 9]) {
    if theta.iter().fold(true, |ok, t| ok & (t.abs() <= 1e-4)) {
        let s = theta.map(|t| t - t * (t * t) * (1.0 / 6.0));
        let c = theta.map(|t| {
            let t2 = t * t;
            1.0 - t2 * 0.5 + t2 * t2 * (1.0 / 24.0)
        });
        (s, c)
    } else {
        let sc = theta.map(sin_cos);
        (sc.map(|(s, _)| s), sc.map(|(_, c)| c))
    }
}

/// Rx(a) · Ry(b) · Rz(c) as rows of plain arrays (the evaluator's form of [`rotation_xyz`]) from
/// the sines and cosines of a, b, c.
#[inline(always)]
pub(crate) fn rotation_rows([sa, sb, sc]: [f64; 3], [ca, cb, cc]: [f64; 3]) -> [[f64; 3]; 3] {
    let (sa_sb, ca_sb) = (sa * sb, ca * sb);
    [
        [cb * cc, -cb * sc, sb],
        [sa_sb * cc + ca * sc, -sa_sb * sc + ca * cc, -sa * cb],
        [-ca_sb * cc + sa * sc, ca_sb * sc + sa * cc, ca * cb],
    ]
}

/// Rx(a) · Ry(b) · Rz(c), angles in rad.
#[inline]
pub fn rotation_xyz(a: f64, b: f64, c: f64) -> Matrix3<f64> {
    let (sa, ca) = sin_cos(a);
    let (sb, cb) = sin_cos(b);
    let (sc, cc) = sin_cos(c);
    Matrix3::new(
        cb * cc,
        -cb * sc,
        sb,
        sa * sb * cc + ca * sc,
        -sa * sb * sc + ca * cc,
        -sa * cb,
        -ca * sb * cc + sa * sc,
        ca * sb * sc + sa * cc,
        ca * cb,
    )
}

/// Rotation by `theta` rad about a coordinate axis.
pub fn rotation_about(axis: Axis, theta: f64) -> Matrix3<f64> {
    match axis {
        Axis::X => rotation_xyz(theta, 0.0, 0.0),
        Axis::Y => rotation_xyz(0.0, theta, 0.0),
        Axis::Z => rotation_xyz(0.0, 0.0, theta),
    }
}

/// The error HTM of one carriage: Trans(δ) · Rot(ε). `delta_mm`, `eps_rad` as named.
#[inline]
pub fn error_htm(delta_mm: [f64; 3], eps_rad: [f64; 3]) -> Matrix4<f64> {
    let r = rotation_xyz(eps_rad[0], eps_rad[1], eps_rad[2]);
    let mut m = r.to_homogeneous();
    m[(0, 3)] = delta_mm[0];
    m[(1, 3)] = delta_mm[1];
    m[(2, 3)] = delta_mm[2];
    m
}

/// One axis as placed in the chain.
#[derive(Clone, Debug, PartialEq)]
pub struct Elem {
    pub axis: Axis,
    pub workpiece_side: bool,
    pub offset_mm: [f64; 3],
    /// Nominal unit direction of motion (the axis' unit vector).
    pub u: [f64; 3],
    /// Direction after squareness tilts (exact rotations).
    pub u_tilted: [f64; 3],
}

impl Elem {
    /// Axis `a` as the model file places it, before any squareness tilt (`u_tilted` = `u`).
    pub fn untilted(a: &AxisSpec) -> Elem {
        let mut u = [0.0; 3];
        u[a.axis.index()] = 1.0;
        Elem {
            axis: a.axis,
            workpiece_side: a.branch == Branch::Workpiece,
            offset_mm: a.offset_mm,
            u,
            u_tilted: u,
        }
    }

    /// Nominal translation of this element in the relative chain for axis position `q_mm`.
    #[inline]
    pub fn nominal(&self, q_mm: f64) -> [f64; 3] {
        let s = if self.workpiece_side { -1.0 } else { 1.0 };
        [
            q_mm * self.u[0] + s * self.offset_mm[0],
            q_mm * self.u[1] + s * self.offset_mm[1],
            q_mm * self.u[2] + s * self.offset_mm[2],
        ]
    }

    /// Actual translation q·ũ ± offset of this element (squareness tilts included), mm.
    #[inline]
    fn actual_translation(&self, q_mm: f64) -> [f64; 3] {
        let s = if self.workpiece_side { -1.0 } else { 1.0 };
        [
            q_mm * self.u_tilted[0] + s * self.offset_mm[0],
            q_mm * self.u_tilted[1] + s * self.offset_mm[1],
            q_mm * self.u_tilted[2] + s * self.offset_mm[2],
        ]
    }
}

/// Abbe arms (mm) of each element for positions `q` (indexed like `elems`) and tool offset `t`.
#[inline(always)]
pub fn arms(elems: &[Elem], q: &[f64; 3], tool_mm: [f64; 3], out: &mut [[f64; 3]; 3]) {
    let mut acc = tool_mm;
    for (j, e) in elems.iter().enumerate().rev() {
        let n = e.nominal(q[j]);
        if e.workpiece_side {
            acc = add(acc, n);
            out[j] = acc;
        } else {
            out[j] = acc;
            acc = add(acc, n);
        }
    }
}

/// Nominal tool tip relative to the workpiece, mm.
#[inline(always)]
pub fn nominal_tip(elems: &[Elem], q: &[f64; 3], tool_mm: [f64; 3]) -> [f64; 3] {
    elems
        .iter()
        .enumerate()
        .fold(tool_mm, |acc, (j, e)| add(acc, e.nominal(q[j])))
}

/// Exact tool tip relative to the workpiece (mm) for per-element errors `delta_um`, `eps_urad`.
#[inline(always)]
pub fn exact_tip(
    elems: &[Elem],
    q: &[f64; 3],
    tool_mm: [f64; 3],
    delta_um: &[[f64; 3]; 3],
    eps_urad: &[[f64; 3]; 3],
) -> [f64; 3] {
    // The HTM product applied to the point, written as R·p + δ: the same algebra as the 4×4
    // matrices above without the multiplications by the constant bottom row.
    let theta: [f64; 9] = std::array::from_fn(|k| eps_urad[k / 3][k % 3] * 1e-6);
    let (sin, cos) = sin_cos_9(theta);
    let mut p = tool_mm;
    for (j, e) in elems.iter().enumerate().rev().take(3) {
        let d = delta_um[j];
        let pick = |v: &[f64; 9]| [v[3 * j], v[3 * j + 1], v[3 * j + 2]];
        let rot = rotation_rows(pick(&sin), pick(&cos));
        let tr = e.actual_translation(q[j]);
        let v = if e.workpiece_side { add(p, tr) } else { p };
        let w = [
            rot[0][0] * v[0] + rot[0][1] * v[1] + rot[0][2] * v[2] + d[0] * 1e-3,
            rot[1][0] * v[0] + rot[1][1] * v[1] + rot[1][2] * v[2] + d[1] * 1e-3,
            rot[2][0] * v[0] + rot[2][1] * v[1] + rot[2][2] * v[2] + d[2] * 1e-3,
        ];
        p = if e.workpiece_side { w } else { add(w, tr) };
    }
    p
}

#[inline]
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

#[inline]
pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector4;

    #[test]
    fn series_sin_cos_matches_libm() {
        for k in -100..=100 {
            let th = f64::from(k) * 1e-4;
            let (s, c) = sin_cos(th);
            assert!(
                (s - th.sin()).abs() <= 2e-18_f64.max(th.sin().abs() * 2e-16),
                "{th}"
            );
            assert!((c - th.cos()).abs() <= 2e-16, "{th}");
        }
    }

    #[test]
    fn rotation_is_orthonormal_and_first_order_matches_small_angle_matrix() {
        let r = rotation_xyz(1e-3, -2e-3, 3e-3);
        assert!((r * r.transpose() - Matrix3::identity()).norm() < 1e-15);
        // Small-angle form [[1,-c,b],[c,1,-a],[-b,a,1]] (Asad Ullah §1.2, Graves §1).
        let small = Matrix3::new(1.0, -3e-3, -2e-3, 3e-3, 1.0, -1e-3, 2e-3, 1e-3, 1.0);
        assert!((r - small).amax() < 1e-5, "differs at second order only");
    }

    fn elem(axis: Axis, wp: bool) -> Elem {
        let mut u = [0.0; 3];
        u[axis.index()] = 1.0;
        Elem {
            axis,
            workpiece_side: wp,
            offset_mm: [0.0; 3],
            u,
            u_tilted: u,
        }
    }

    #[test]
    fn arms_follow_spaan_b_matrix_for_every_stacking() {
        // Spaan 1995 eq 2.5: p_i = l + (b_ix X, b_iy Y, b_iz Z); for an all-workpiece chain
        // "X Y Z F" b_iu = 1 when u is i or after i: p_x = l + (X,Y,Z), p_y = l + (0,Y,Z), p_z = l + (0,0,Z).
        let q = [100.0, 200.0, 300.0];
        let t = [1.0, 2.0, 3.0];
        let mut out = [[0.0; 3]; 3];
        let all_wp = [
            elem(Axis::X, true),
            elem(Axis::Y, true),
            elem(Axis::Z, true),
        ];
        arms(&all_wp, &q, t, &mut out);
        assert_eq!(
            out,
            [
                [101.0, 202.0, 303.0],
                [1.0, 202.0, 303.0],
                [1.0, 2.0, 303.0]
            ]
        );
        // "X F Y Z": the table's arm includes its own travel, the column's do not.
        let mill = [
            elem(Axis::X, true),
            elem(Axis::Y, false),
            elem(Axis::Z, false),
        ];
        arms(&mill, &q, t, &mut out);
        assert_eq!(
            out,
            [[101.0, 202.0, 303.0], [1.0, 2.0, 303.0], [1.0, 2.0, 3.0]]
        );
        // "F X Y Z": nothing on the workpiece side.
        let gantry = [
            elem(Axis::X, false),
            elem(Axis::Y, false),
            elem(Axis::Z, false),
        ];
        arms(&gantry, &q, t, &mut out);
        assert_eq!(
            out,
            [[1.0, 202.0, 303.0], [1.0, 2.0, 303.0], [1.0, 2.0, 3.0]]
        );
        assert_eq!(nominal_tip(&mill, &q, t), [101.0, 202.0, 303.0]);
    }

    #[test]
    fn exact_tip_equals_the_4x4_htm_product() {
        // Reference: the chain's definition with full homogeneous matrices (module comment).
        let mut chain = [
            elem(Axis::X, true),
            elem(Axis::Y, false),
            elem(Axis::Z, false),
        ];
        chain[1].offset_mm = [5.0, -3.0, 20.0];
        chain[2].u_tilted = [1e-5, -2e-5, 1.0];
        let q = [412.5, -140.0, 37.0];
        let t = [0.0, 0.0, -150.0];
        let d = [[3.0, -8.0, 1.5], [-2.0, 4.0, 9.0], [0.5, -6.0, 2.0]];
        // Angles of a few µrad (the series path), then one of 300 µrad (libm for all nine).
        for r in [
            [[12.0, -7.0, 3.0], [-4.0, 15.0, -9.0], [6.0, 2.0, -11.0]],
            [[12.0, -7.0, 3.0], [-4.0, 300.0, -9.0], [6.0, 2.0, -11.0]],
        ] {
            check_exact_tip_against_htm(&chain, q, t, d, r);
        }
    }

    fn check_exact_tip_against_htm(
        chain: &[Elem],
        q: [f64; 3],
        t: [f64; 3],
        d: [[f64; 3]; 3],
        r: [[f64; 3]; 3],
    ) {
        let mut p = Vector4::new(t[0], t[1], t[2], 1.0);
        for j in (0..3).rev() {
            let err = error_htm(
                [d[j][0] * 1e-3, d[j][1] * 1e-3, d[j][2] * 1e-3],
                [r[j][0] * 1e-6, r[j][1] * 1e-6, r[j][2] * 1e-6],
            );
            let a = chain[j].actual_translation(q[j]);
            let tr = Matrix4::new_translation(&Vector3::new(a[0], a[1], a[2]));
            p = if chain[j].workpiece_side {
                err * (tr * p)
            } else {
                tr * (err * p)
            };
        }
        let got = exact_tip(chain, &q, t, &d, &r);
        for k in 0..3 {
            assert!((got[k] - p[k]).abs() < 1e-12, "{k}: {} vs {}", got[k], p[k]);
        }
        let nominal = nominal_tip(chain, &q, t);
        let moved = (0..3)
            .map(|k| (got[k] - nominal[k]).abs())
            .fold(0.0, f64::max);
        assert!(moved > 1e-3, "errors must show: {moved} mm");
    }

    #[test]
    fn exact_tip_without_errors_is_nominal() {
        let mill = [
            elem(Axis::X, true),
            elem(Axis::Y, false),
            elem(Axis::Z, false),
        ];
        let q = [12.5, -40.0, 7.0];
        let z = [[0.0; 3]; 3];
        let r = exact_tip(&mill, &q, [0.0, 0.0, -100.0], &z, &z);
        assert_eq!(r, nominal_tip(&mill, &q, [0.0, 0.0, -100.0]));
    }
}
