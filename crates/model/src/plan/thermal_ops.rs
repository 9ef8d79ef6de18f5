//! The thermal terms' part of the plan: their formulas with sensor lists resolved to flat
//! (sensor, coefficient) ranges, and their evaluation into the element motions and terms. Values
//! are in the target's unit (µm or µrad), positions mm, ΔT K (`thermal.rs` has the conventions).

use std::ops::Range;

use super::{Plan, Target, apply};
use crate::thermal::ThermalState;

/// A thermal term's formula with sensor lists resolved to flat coefficient ranges (`Plan::linear`,
/// `Plan::quadratic`).
#[derive(Clone, Debug)]
pub(super) enum ThermalOp {
    /// e0 + Σ b ΔT + Σ c ΔT ΔT.
    Polynomial {
        e0: f64,
        linear: Range<usize>,
        quadratic: Range<usize>,
    },
    /// q_target · 1e-3 · (s0 + Σ s ΔT + Σ d ΔT ΔT).
    Slope {
        s0: f64,
        linear: Range<usize>,
        quadratic: Range<usize>,
    },
    /// α · (q_target − origin) · (T_lagged − reference) · 1e-3.
    Expansion {
        sensor: usize,
        alpha_ppm_per_k: f64,
        origin_mm: f64,
        reference_c: f64,
    },
    /// Stations along `along` (a chain element; absent axis = position 0), linear between them.
    Stations {
        along: Option<usize>,
        stations_mm: Vec<f64>,
        /// 1 / (s_{k+1} − s_k).
        inv_gap: Vec<f64>,
        e0: Vec<f64>,
        linear: Vec<Range<usize>>,
    },
}

#[derive(Clone, Debug)]
pub(super) struct ThermalTerm {
    pub target: Target,
    pub op: ThermalOp,
}

/// The thermal terms split by formula, each kind run as its own loop without a per-term `match`.
/// Built only when that order adds every motion's thermal values in the terms' order
/// ([`super::build::thermal_by_kind`]), so every sum, and its bits, stays the same.
#[derive(Clone, Debug, Default)]
pub(super) struct ThermalByKind {
    /// (target, e0, linear, quadratic): e0 + Σ b ΔT + Σ c ΔT ΔT.
    pub polynomial: Vec<(Target, f64, Range<usize>, Range<usize>)>,
    /// (target, s0, linear, quadratic): q_target · 1e-3 · (s0 + Σ s ΔT + Σ d ΔT ΔT).
    pub slope: Vec<(Target, f64, Range<usize>, Range<usize>)>,
    /// (target, sensor, α ppm/K, origin mm, reference °C).
    pub expansion: Vec<(Target, usize, f64, f64, f64)>,
    /// The rest (stations), through [`Plan::thermal_value`].
    pub other: Vec<ThermalTerm>,
}

impl Plan {
    #[inline]
    fn linear(&self, r: &Range<usize>, dt: &[f64]) -> f64 {
        self.linear[r.clone()].iter().map(|&(i, b)| b * dt[i]).sum()
    }

    #[inline]
    fn quadratic(&self, r: &Range<usize>, dt: &[f64]) -> f64 {
        self.quadratic[r.clone()]
            .iter()
            .fold(0.0, |acc, &(i, j, c)| acc + c * dt[i] * dt[j])
    }

    /// A thermal term's value (µm or µrad) at element positions `q`; sets `clamped` for a
    /// position outside the stations.
    #[inline(always)]
    fn thermal_value(
        &self,
        th: &ThermalTerm,
        q: &[f64; 3],
        ts: &ThermalState,
        clamped: &mut [bool; 3],
    ) -> f64 {
        let dt = &ts.delta_c[..];
        let qt = q[th.target.elem];
        match &th.op {
            ThermalOp::Polynomial {
                e0,
                linear,
                quadratic,
            } => e0 + self.linear(linear, dt) + self.quadratic(quadratic, dt),
            ThermalOp::Slope {
                s0,
                linear,
                quadratic,
            } => {
                // Coefficients are per metre of travel: q_mm · 1e-3 m/mm.
                qt * 1e-3 * (s0 + self.linear(linear, dt) + self.quadratic(quadratic, dt))
            }
            ThermalOp::Expansion {
                sensor,
                alpha_ppm_per_k,
                origin_mm,
                reference_c,
            } => {
                let abs_c = ts.lagged_or_c(*sensor, *reference_c);
                // ppm/K · mm · K = 1e-6 mm = 1e-3 µm.
                alpha_ppm_per_k * (qt - origin_mm) * (abs_c - reference_c) * 1e-3
            }
            ThermalOp::Stations {
                along,
                stations_mm,
                inv_gap,
                e0,
                linear,
            } => {
                let x = along.map_or(0.0, |a| q[a]);
                let at = |k: usize| e0[k] + self.linear(&linear[k], dt);
                let n = stations_mm.len();
                if x.is_nan() || x < stations_mm[0] || x > stations_mm[n - 1] {
                    if let Some(a) = along {
                        clamped[*a] = true;
                    }
                    if x > stations_mm[n - 1] {
                        at(n - 1)
                    } else {
                        at(0)
                    }
                } else {
                    let mut k = 0;
                    while k + 2 < n && stations_mm[k + 1] <= x {
                        k += 1;
                    }
                    let w = (x - stations_mm[k]) * inv_gap[k];
                    (1.0 - w) * at(k) + w * at(k + 1)
                }
            }
        }
    }

    /// Every thermal term's value into `acc` and its term (`super::apply`); `q` per element, mm.
    #[inline(always)]
    pub(super) fn thermal_stage(
        &self,
        q: &[f64; 3],
        ts: &ThermalState,
        acc: &mut [f64; 18],
        basis: &[[f64; 3]; 18],
        terms: &mut [[f64; 3]],
        clamped: &mut [bool; 3],
    ) {
        let dt = &ts.delta_c[..];
        match &self.thermal_by_kind {
            Some(k) => {
                for (tg, e0, lin, quad) in &k.polynomial {
                    let v = e0 + self.linear(lin, dt) + self.quadratic(quad, dt);
                    apply(acc, basis, terms, *tg, v);
                }
                for (tg, s0, lin, quad) in &k.slope {
                    // Coefficients are per metre of travel: q_mm · 1e-3 m/mm.
                    let qt = q[tg.elem];
                    let v = qt * 1e-3 * (s0 + self.linear(lin, dt) + self.quadratic(quad, dt));
                    apply(acc, basis, terms, *tg, v);
                }
                for &(tg, sensor, alpha_ppm_per_k, origin_mm, reference_c) in &k.expansion {
                    let abs_c = ts.lagged_or_c(sensor, reference_c);
                    // ppm/K · mm · K = 1e-6 mm = 1e-3 µm.
                    let v =
                        alpha_ppm_per_k * (q[tg.elem] - origin_mm) * (abs_c - reference_c) * 1e-3;
                    apply(acc, basis, terms, tg, v);
                }
                for th in &k.other {
                    let v = self.thermal_value(th, q, ts, clamped);
                    apply(acc, basis, terms, th.target, v);
                }
            }
            None => {
                for th in &self.thermal {
                    let v = self.thermal_value(th, q, ts, clamped);
                    apply(acc, basis, terms, th.target, v);
                }
            }
        }
    }
}
