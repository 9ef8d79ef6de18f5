//! The floor's evaluation: lags, lookups, the ten thermal and load terms, the first-order sum and
//! the exact chain, each sum formed in `Plan::run`'s order (see the parent module).

use retrocomp_model::kinematics::sin_cos;
use retrocomp_model::{ErrorBreakdown, EvalFlags, ModelInput};

use super::{Floor, FloorState};

/// Rx(a) · Ry(b) · Rz(c) as rows, from the sines and cosines of a, b, c.
#[inline(always)]
fn rotation_rows([sa, sb, sc]: [f64; 3], [ca, cb, cc]: [f64; 3]) -> [[f64; 3]; 3] {
    let (sa_sb, ca_sb) = (sa * sb, ca * sb);
    [
        [cb * cc, -cb * sc, sb],
        [sa_sb * cc + ca * sc, -sa_sb * sc + ca * cc, -sa * cb],
        [-ca_sb * cc + sa * sc, ca_sb * sc + sa * cc, ca * cb],
    ]
}

/// sin, cos of nine error angles: the two-term series when all are ≤ 1e-4 rad (always, in
/// practice), else `kinematics::sin_cos` each.
#[inline(always)]
fn sin_cos_9(theta: [f64; 9]) -> ([f64; 9], [f64; 9]) {
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

#[inline(always)]
fn mul_add(r: &[[f64; 3]; 3], v: [f64; 3], d: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2] + d[i] * 1e-3)
}

/// The thermal and load values: spindle_growth, x_slope, scale_y, scale_z, scale_x,
/// column_drift_y, column_tilt, deflection_x, deflection_y, weight_roll; and the Z clamp flag.
type Extra = ([f64; 10], bool, bool);

impl Floor {
    /// The 16 lags stepped to `t` (time moving forward; every reading finite).
    #[inline(always)]
    #[allow(
        clippy::needless_range_loop,
        reason = "five arrays of 16 indexed alike"
    )]
    fn step(&self, st: &mut FloorState, temps: &[f64], t_s: f64) {
        let temps: &[f64; 16] = temps[..16].try_into().expect("16 temperatures");
        if let Some(last) = st.last_t_s {
            let dt = t_s - last;
            let mut d = dt - st.dt0;
            if d.is_nan() || d.abs() > 1e-6 * st.dt0 {
                for (k0, tau) in st.keep0.iter_mut().zip(&self.tau) {
                    *k0 = tau.map_or(0.0, |tau| (-dt / tau).exp());
                }
                st.dt0 = dt;
                d = 0.0;
            }
            for i in 0..16 {
                let x = d * self.inv_tau[i];
                let keep = st.keep0[i] * (1.0 - x * (1.0 - x * (0.5 - x * (1.0 / 6.0))));
                let t = temps[i];
                let new = t + keep * (st.lagged[i] - t);
                st.lagged[i] = new;
                st.dt_c[i] = new - self.reference_c[i];
            }
        } else {
            for i in 0..16 {
                st.lagged[i] = temps[i];
                st.dt_c[i] = temps[i] - self.reference_c[i];
            }
        }
        st.last_t_s = Some(t_s);
    }

    #[inline(always)]
    fn extra(&self, st: &FloorState, input: &ModelInput) -> Extra {
        let [x, y, z] = input.pos_mm;
        let (d, l) = (&st.dt_c, &st.lagged);
        let b = &self.sg_b;
        let sg_lin = b[0] * d[0] + b[1] * d[1] + b[2] * d[2] + b[3] * d[3];
        let sg = self.sg_e0 + sg_lin + self.sg_c00 * d[0] * d[0];
        let s = &self.xs_s;
        let xs = x * 1e-3 * (self.xs_s0 + (s[0] * d[15] + s[1] * d[9] + s[2] * d[13]) + 0.0);
        let ex = |k: usize, q: f64, sensor: usize| {
            let (alpha, origin, reference) = self.exp[k];
            alpha * (q - origin) * (l[sensor] - reference) * 1e-3
        };
        let (sy, sz, sx) = (ex(0, y, 11), ex(1, z, 12), ex(2, x, 10));
        let at = |k: usize| {
            let b = &self.cd_b[k];
            self.cd_e0[k]
                + (b[0] * d[4]
                    + b[1] * d[5]
                    + b[2] * d[6]
                    + b[3] * d[7]
                    + b[4] * d[8]
                    + b[5] * d[14])
        };
        let st_ = &self.cd_st;
        let (cd, cd_cl) = if z.is_nan() || z < st_[0] || z > st_[2] {
            (if z > st_[2] { at(2) } else { at(0) }, true)
        } else {
            let k = usize::from(st_[1] <= z);
            let w = (z - st_[k]) * self.cd_inv_gap[k];
            ((1.0 - w) * at(k) + w * at(k + 1), false)
        };
        let ct = self.ct_e0 + (self.ct_b[0] * d[4] + self.ct_b[1] * d[5]) + 0.0;
        let (fx, fy) = (input.forces_n[0], input.forces_n[1]);
        let fw = self.strain.0 * (input.strains_ue[0] - self.strain.1);
        let (vx, clx) = self.defl_x.eval(z, input.dir[2]);
        let (a0, a1, lo, hi) = self.defl_y;
        let (qy, cly) = if z.is_nan() || z < lo {
            (lo, true)
        } else if z > hi {
            (hi, true)
        } else {
            (z, false)
        };
        let vy = a1 * qy + a0;
        let (vr, clr) = self.roll.eval(x, input.dir[0]);
        let v = [
            sg,
            xs,
            sy,
            sz,
            sx,
            cd,
            ct,
            vx * fx,
            vy * fy,
            vr * fw * self.roll_scale,
        ];
        (v, cd_cl | clx | cly, clr)
    }

    /// One exact evaluation with its 32-term breakdown (`out` sized by `new_breakdown`).
    #[inline]
    pub(crate) fn run(&self, input: &ModelInput, st: &mut FloorState, out: &mut ErrorBreakdown) {
        let [x, y, z] = input.pos_mm;
        let [dx, dy, dz] = input.dir;
        let tz = input
            .tool_mm
            .map_or_else(|| self.tools_z[input.tool], |len| -len);
        self.step(st, &input.temps_c, input.t_s);
        let (gx, clx) = self.blocks[0].eval(x, dx);
        let (gy, cly) = self.blocks[1].eval(y, dy);
        let (gz, clz) = self.blocks[2].eval(z, dz);
        let ([sg, xs, sy, sz, sx, cd, ct, dfx, dfy, roll], clz2, clx2) = self.extra(st, input);

        let h = tz + z;
        let (ax, ay, az) = (x * 1e-3, y * 1e-3, h * 1e-3);
        let (hm, tm) = (h * 1e-3, tz * 1e-3);
        let t: &mut [[f64; 3]; 32] = (&mut out.terms_um[..]).try_into().expect("32 terms");
        t[..6].copy_from_slice(&[
            [gx[0], 0.0, 0.0],
            [0.0, gx[1], 0.0],
            [0.0, 0.0, gx[2]],
            [0.0, gx[3] * -az, gx[3] * ay],
            [gx[4] * az, 0.0, gx[4] * -ax],
            [gx[5] * -ay, gx[5] * ax, 0.0],
        ]);
        for (block, g, a) in [(6, gy, hm), (12, gz, tm)] {
            t[block..block + 6].copy_from_slice(&[
                [g[0], 0.0, 0.0],
                [0.0, g[1], 0.0],
                [0.0, 0.0, g[2]],
                [0.0, g[3] * -a, 0.0],
                [g[4] * a, 0.0, 0.0],
                [0.0, 0.0, 0.0],
            ]);
        }
        let sq = [self.sq[0] * y, self.sq[1] * z, self.sq[2] * z];
        t[18..31].copy_from_slice(&[
            [sq[0], 0.0, 0.0],
            [sq[1], 0.0, 0.0],
            [0.0, sq[2], 0.0],
            [0.0, 0.0, sg],
            [xs, 0.0, 0.0],
            [0.0, sy, 0.0],
            [0.0, 0.0, sz],
            [sx, 0.0, 0.0],
            [0.0, cd, 0.0],
            [0.0, ct * -tm, 0.0],
            [dfx, 0.0, 0.0],
            [0.0, dfy, 0.0],
            [0.0, roll * -az, roll * ay],
        ]);
        // The chain elements' motions, accumulated in the plan's order.
        let d_x = [gx[0] + xs + sx, gx[1], gx[2]];
        let e_x = [gx[3] + roll, gx[4], gx[5]];
        let d_y = [gy[0], gy[1] + sy, gy[2]];
        let e_y = [gy[3], gy[4], gy[5]];
        let d_z = [gz[0] + dfx, gz[1] + cd + dfy, gz[2] + sg + sz];
        let e_z = [gz[3] + ct, gz[4], gz[5]];

        // First order: Σ δ + ε × arm (arms [x, y, h], [0, 0, h], [0, 0, tz] mm), + squareness.
        let e = e_x.map(|v| v * 1e-3);
        let mut f = [
            d_x[0] + (e[1] * h - e[2] * y),
            d_x[1] + (e[2] * x - e[0] * h),
            d_x[2] + (e[0] * y - e[1] * x),
        ];
        for (d, e, arm) in [(d_y, e_y, h), (d_z, e_z, tz)] {
            let e = e.map(|v| v * 1e-3);
            f = [
                f[0] + d[0] + e[1] * arm,
                f[1] + d[1] + -(e[0] * arm),
                f[2] + d[2],
            ];
        }
        let first = [f[0] + (sq[0] + sq[1]), f[1] + sq[2], f[2]];

        let total = self.chain(x, y, z, tz, [d_x, d_y, d_z], [e_x, e_y, e_z]);
        t[31] = std::array::from_fn(|i| total[i] - first[i]);
        out.total_um = total;
        out.flags = EvalFlags {
            clamped: [clx | clx2, cly, clz | clz2],
            outside_travel: std::array::from_fn(|a| {
                let (lo, hi) = self.travel[a];
                input.pos_mm[a] < lo || input.pos_mm[a] > hi
            }),
            ..EvalFlags::default()
        };
    }

    /// Exact tool tip minus nominal, µm: Z and Y on the tool side, X on the workpiece side.
    #[inline(always)]
    fn chain(
        &self,
        x: f64,
        y: f64,
        z: f64,
        tz: f64,
        d: [[f64; 3]; 3],
        e: [[f64; 3]; 3],
    ) -> [f64; 3] {
        let theta: [f64; 9] = std::array::from_fn(|k| e[k / 3][k % 3] * 1e-6);
        let (s, c) = sin_cos_9(theta);
        let rot = |j: usize| {
            rotation_rows(
                [s[3 * j], s[3 * j + 1], s[3 * j + 2]],
                [c[3 * j], c[3 * j + 1], c[3 * j + 2]],
            )
        };
        let (rz, ry, rx) = (rot(2), rot(1), rot(0));
        let p: [f64; 3] = std::array::from_fn(|i| rz[i][2] * tz + d[2][i] * 1e-3);
        let p: [f64; 3] = std::array::from_fn(|i| p[i] + z * self.u_z[i]);
        let w = mul_add(&ry, p, d[1]);
        let p: [f64; 3] = std::array::from_fn(|i| w[i] + y * self.u_y[i]);
        let r = mul_add(&rx, [p[0] + x, p[1], p[2]], d[0]);
        [(r[0] - x) * 1e3, (r[1] - y) * 1e3, (r[2] - (tz + z)) * 1e3]
    }
}
