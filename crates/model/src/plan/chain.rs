//! The kinematic chain of three elements compiled per layout: which elements sit on the workpiece
//! side, and whether the chain is plain (three distinct axes along their unit vectors, no carriage
//! offsets), are const parameters chosen once per evaluation by [`layout!`], so the chain runs
//! without a branch per element. Positions mm, errors δ µm and ε µrad, the result µm (actual −
//! nominal).
//!
//! The arithmetic is `kinematics::{arms, nominal_tip, exact_tip}`'s in the same order (the side
//! sign folded into the stored offsets: ±1 · o is exact). A plain chain leaves out the terms that
//! are structurally zero: q · 0 and + 0 offsets in the nominal translations (an arm is then the
//! tool plus the positions its element carries, a nominal tip the tool plus all positions), + 0
//! offsets in the actual ones. Adding or multiplying by zero can only change the sign of a zero,
//! so every non-zero result has the same bits as the general code's.

use crate::kinematics::{Elem, add, rotation_rows, sin_cos_9};

/// A chain of exactly three elements, its constants in the layout the kernels read.
#[derive(Clone, Debug)]
pub(super) struct Chain3 {
    /// Bit j set: element j is on the workpiece side; bit 3 set: the chain is plain.
    pub layout: u8,
    /// Nominal unit direction per element.
    u: [[f64; 3]; 3],
    /// Direction after the squareness tilts per element.
    u_tilted: [[f64; 3]; 3],
    /// ±offset (− on the workpiece side), mm.
    offset_mm: [[f64; 3]; 3],
    /// Plain chain: per element, 1 for each machine axis whose travel its arm includes (the later
    /// elements, and its own on the workpiece side), else 0: arm = tool + mask · position.
    arm_mask: [[f64; 3]; 3],
}

impl Chain3 {
    pub(super) fn new(elems: &[Elem]) -> Option<Chain3> {
        let e: &[Elem; 3] = elems.try_into().ok()?;
        let side = |e: &Elem| if e.workpiece_side { -1.0 } else { 1.0 };
        let axis = e.each_ref().map(|e| e.axis.index());
        #[allow(
            clippy::float_cmp,
            reason = "what a plain chain leaves out must be exactly q · 0 and + 0"
        )]
        let plain = axis[0] != axis[1]
            && axis[1] != axis[2]
            && axis[0] != axis[2]
            && e.iter().all(|e| {
                let mut unit = [0.0; 3];
                unit[e.axis.index()] = 1.0;
                e.u == unit && e.offset_mm == [0.0; 3]
            });
        let arm_mask = std::array::from_fn(|j| {
            let mut m = [0.0; 3];
            for (k, ek) in e.iter().enumerate() {
                if k > j || (k == j && ek.workpiece_side) {
                    m[ek.axis.index()] = 1.0;
                }
            }
            m
        });
        Some(Chain3 {
            layout: e
                .iter()
                .enumerate()
                .map(|(j, e)| u8::from(e.workpiece_side) << j)
                .sum::<u8>()
                | u8::from(plain) << 3,
            u: e.each_ref().map(|e| e.u),
            u_tilted: e.each_ref().map(|e| e.u_tilted),
            offset_mm: e.each_ref().map(|e| e.offset_mm.map(|o| side(e) * o)),
            arm_mask,
        })
    }

    /// `Elem::nominal`.
    #[inline(always)]
    fn nominal(&self, j: usize, q_mm: f64) -> [f64; 3] {
        let (u, o) = (self.u[j], self.offset_mm[j]);
        [q_mm * u[0] + o[0], q_mm * u[1] + o[1], q_mm * u[2] + o[2]]
    }

    /// `Elem::actual_translation`.
    #[inline(always)]
    fn actual(&self, j: usize, q_mm: f64) -> [f64; 3] {
        let (u, o) = (self.u_tilted[j], self.offset_mm[j]);
        [q_mm * u[0] + o[0], q_mm * u[1] + o[1], q_mm * u[2] + o[2]]
    }

    /// `kinematics::arms` for layout (W0, W1, W2, PLAIN); `pos_mm` by machine axis (a plain chain
    /// has all three, so q is `pos_mm` reordered).
    #[inline(always)]
    pub(super) fn arms<const W0: bool, const W1: bool, const W2: bool, const PLAIN: bool>(
        &self,
        q: &[f64; 3],
        pos_mm: &[f64; 3],
        tool_mm: [f64; 3],
    ) -> [[f64; 3]; 3] {
        if PLAIN {
            let (t, p) = (tool_mm, pos_mm);
            return self
                .arm_mask
                .map(|m| [t[0] + p[0] * m[0], t[1] + p[1] * m[1], t[2] + p[2] * m[2]]);
        }
        let mut out = [[0.0; 3]; 3];
        let mut acc = tool_mm;
        for (j, wp) in [(2, W2), (1, W1), (0, W0)] {
            if wp {
                acc = add(acc, self.nominal(j, q[j]));
                out[j] = acc;
            } else {
                out[j] = acc;
                acc = add(acc, self.nominal(j, q[j]));
            }
        }
        out
    }

    /// Exact minus nominal tool tip, µm (`kinematics::exact_tip` − `nominal_tip`, × 1e3).
    #[inline(always)]
    pub(super) fn exact_error<const W0: bool, const W1: bool, const W2: bool, const PLAIN: bool>(
        &self,
        q: &[f64; 3],
        pos_mm: &[f64; 3],
        tool_mm: [f64; 3],
        delta_um: &[[f64; 3]; 3],
        eps_urad: &[[f64; 3]; 3],
    ) -> [f64; 3] {
        let theta: [f64; 9] = std::array::from_fn(|k| eps_urad[k / 3][k % 3] * 1e-6);
        let (sin, cos) = sin_cos_9(theta);
        let mut p = tool_mm;
        for (j, wp) in [(2, W2), (1, W1), (0, W0)] {
            let d = delta_um[j];
            let pick = |v: &[f64; 9]| [v[3 * j], v[3 * j + 1], v[3 * j + 2]];
            let rot = rotation_rows(pick(&sin), pick(&cos));
            let tr = if PLAIN {
                let u = self.u_tilted[j];
                [q[j] * u[0], q[j] * u[1], q[j] * u[2]]
            } else {
                self.actual(j, q[j])
            };
            let v = if wp { add(p, tr) } else { p };
            let w = [
                rot[0][0] * v[0] + rot[0][1] * v[1] + rot[0][2] * v[2] + d[0] * 1e-3,
                rot[1][0] * v[0] + rot[1][1] * v[1] + rot[1][2] * v[2] + d[1] * 1e-3,
                rot[2][0] * v[0] + rot[2][1] * v[1] + rot[2][2] * v[2] + d[2] * 1e-3,
            ];
            p = if wp { w } else { add(w, tr) };
        }
        let r0 = if PLAIN {
            add(tool_mm, *pos_mm)
        } else {
            (0..3).fold(tool_mm, |acc, j| add(acc, self.nominal(j, q[j])))
        };
        [
            (p[0] - r0[0]) * 1e3,
            (p[1] - r0[1]) * 1e3,
            (p[2] - r0[2]) * 1e3,
        ]
    }
}

/// `$chain.$kernel::<W0, W1, W2, PLAIN>($args)` for the chain's layout: one jump to the kernel
/// compiled for it.
macro_rules! layout {
    ($chain:expr, $kernel:ident($($arg:expr),*)) => {{
        let c = $chain;
        match c.layout {
            0 => c.$kernel::<false, false, false, false>($($arg),*),
            1 => c.$kernel::<true, false, false, false>($($arg),*),
            2 => c.$kernel::<false, true, false, false>($($arg),*),
            3 => c.$kernel::<true, true, false, false>($($arg),*),
            4 => c.$kernel::<false, false, true, false>($($arg),*),
            5 => c.$kernel::<true, false, true, false>($($arg),*),
            6 => c.$kernel::<false, true, true, false>($($arg),*),
            7 => c.$kernel::<true, true, true, false>($($arg),*),
            8 => c.$kernel::<false, false, false, true>($($arg),*),
            9 => c.$kernel::<true, false, false, true>($($arg),*),
            10 => c.$kernel::<false, true, false, true>($($arg),*),
            11 => c.$kernel::<true, true, false, true>($($arg),*),
            12 => c.$kernel::<false, false, true, true>($($arg),*),
            13 => c.$kernel::<true, false, true, true>($($arg),*),
            14 => c.$kernel::<false, true, true, true>($($arg),*),
            _ => c.$kernel::<true, true, true, true>($($arg),*),
        }
    }};
}
pub(super) use layout;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{arms, exact_tip, nominal_tip};
    use crate::names::Axis;

    fn elem(axis: Axis, workpiece_side: bool, offset_mm: [f64; 3], tilt: [f64; 3]) -> Elem {
        let mut u = [0.0; 3];
        u[axis.index()] = 1.0;
        Elem {
            axis,
            workpiece_side,
            offset_mm,
            u,
            u_tilted: add(u, tilt),
        }
    }

    /// Every layout, plain or with offsets, gives `kinematics`' arms and exact − nominal tip: equal
    /// as numbers (a plain chain may differ in the sign of a zero only).
    #[test]
    fn every_layout_gives_the_general_chain() {
        let q = [412.5, -140.0, 37.0];
        let t = [0.0, 0.0, -150.0];
        let d = [[3.0, -8.0, 1.5], [-2.0, 4.0, 9.0], [0.5, -6.0, 2.0]];
        let r = [[12.0, -7.0, 3.0], [-4.0, 15.0, -9.0], [6.0, 2.0, -11.0]];
        for with_offsets in [false, true] {
            for wp in 0..8u8 {
                let o = |k: f64| {
                    if with_offsets {
                        [k, -2.0 * k, 0.5]
                    } else {
                        [0.0; 3]
                    }
                };
                let side = |j: u8| wp & (1 << j) != 0;
                let elems = [
                    elem(Axis::Y, side(0), o(5.0), [0.0; 3]),
                    elem(Axis::X, side(1), o(-3.0), [2e-5, 0.0, 0.0]),
                    elem(Axis::Z, side(2), o(7.0), [1e-5, -2e-5, 0.0]),
                ];
                let c = Chain3::new(&elems).expect("three elements");
                assert_eq!(c.layout, wp | (u8::from(!with_offsets) << 3));
                let mut want = [[0.0; 3]; 3];
                arms(&elems, &q, t, &mut want);
                // q by element for the chain Y X Z, by machine axis.
                let pos = [q[1], q[0], q[2]];
                assert_eq!(layout!(&c, arms(&q, &pos, t)), want, "layout {wp}");
                let (r1, r0) = (exact_tip(&elems, &q, t, &d, &r), nominal_tip(&elems, &q, t));
                let want: [f64; 3] = std::array::from_fn(|k| (r1[k] - r0[k]) * 1e3);
                let got = layout!(&c, exact_error(&q, &pos, t, &d, &r));
                assert_eq!(got, want, "layout {wp}");
            }
        }
    }
}
