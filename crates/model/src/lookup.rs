//! Table lookups compiled for the evaluation plan (`plan.rs`): node search and per-direction
//! values, the same results as `function::Table` / `ErrorFunction::eval` to rounding.
//!
//! Positions are mm; values are in the function's unit (µm, µrad, µm/N, …). A position outside a
//! table (or NaN) is clamped to the end node and flagged, as everywhere in the model. The approach
//! direction (−1 reverse, 0 unknown, +1 forward) selects one of three precomputed value sets instead
//! of weighting forward and reverse per call.

use super::function::{ErrorFunction, Interpolation, clamp_range};

/// Table node positions with what a lookup needs precomputed.
#[derive(Clone, Debug)]
pub(crate) struct Nodes {
    /// Node positions (≥ 2, strictly increasing), mm.
    pub x: Vec<f64>,
    /// 1 / (x_{i+1} − x_i) per segment.
    inv_h: Vec<f64>,
    /// 1 / mean spacing: the first guess of a lookup.
    inv_mean_h: f64,
}

impl Nodes {
    pub(crate) fn new(x: &[f64]) -> Nodes {
        let n = x.len();
        Nodes {
            x: x.to_vec(),
            inv_h: x.windows(2).map(|w| 1.0 / (w[1] - w[0])).collect(),
            inv_mean_h: (n - 1) as f64 / (x[n - 1] - x[0]),
        }
    }

    /// (node a, node b, fraction f, clamped): the value is a + f · (b − a). The same segment and
    /// fraction as `Table::locate`: segment i with x_i ≤ q < x_{i+1} (the last one up to its end);
    /// outside the span (or NaN) both nodes are the end node and f = 0.
    #[inline(always)]
    pub(crate) fn locate(&self, q: f64) -> (usize, usize, f64, bool) {
        let x = &self.x[..];
        let n = x.len();
        if q.is_nan() || q < x[0] {
            return (0, 0, 0.0, true);
        }
        if q > x[n - 1] {
            return (n - 1, n - 1, 0.0, true);
        }
        let last = n - 2;
        // Near-even tables (positions rounded when written): the guess from the mean spacing is
        // right or one off. Which way it is off is random from call to call, so the correction is
        // arithmetic on the comparisons rather than a branch (a mispredicted branch costs more than
        // the whole interpolation); anything further off falls back to a binary search.
        // Through i32: a float → u64 conversion has no single x86-64 instruction (≈ 10 instead of 1
        // here), and a table of 2³¹ nodes is not a table.
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a guess only: `as` saturates, `max(0)` makes it ≥ 0, `min(last)` keeps it in the table, and the lines below check it"
        )]
        let mut i = ((((q - x[0]) * self.inv_mean_h) as i32).max(0) as usize).min(last);
        i -= usize::from(x[i] > q); // x[0] ≤ q, so i > 0 whenever x[i] > q
        i += usize::from((i < last) & (x[i + 1] <= q));
        if x[i] > q || (q >= x[i + 1] && i != last) {
            i = x.partition_point(|&p| p <= q).saturating_sub(1).min(last);
        }
        (i, i + 1, (q - x[i]) * self.inv_h[i], false)
    }
}

/// Index of the per-direction node values for an approach direction −1 / 0 / +1: reverse, the
/// mean ½·forward + ½·reverse, forward (the weights `Table::eval_at` applies, folded in once).
#[inline(always)]
pub(crate) fn dir_slot(dir: i8) -> usize {
    usize::from((dir.signum() + 1).unsigned_abs())
}

/// Per-direction node values: [reverse, mean, forward], each `pick(f, r)` as in `Table::eval_at`.
pub(crate) fn by_dir(f: &[f64], r: &[f64]) -> [Vec<f64>; 3] {
    [-1i8, 0, 1].map(|d| {
        let w_fwd = 0.5 * (1.0 + f64::from(d));
        f.iter()
            .zip(r)
            .map(|(f, r)| w_fwd * f + (1.0 - w_fwd) * r)
            .collect()
    })
}

/// A function the groups do not cover, compiled for one evaluation per call.
#[derive(Clone, Debug)]
pub(crate) enum Curve {
    /// A C¹ (cubic Hermite, PCHIP slopes) or linear table with the direction choice folded in:
    /// per direction slot ([`dir_slot`]), each segment as a cubic in the fraction t ∈ [0, 1]
    /// (c0 + c1 t + c2 t² + c3 t³, the Hermite basis multiplied out; c2 = c3 = 0 when linear), and
    /// the node values for a clamped position.
    Table {
        nodes: Nodes,
        cubic: [Vec<[f64; 4]>; 3],
        values: [Vec<f64>; 3],
    },
    /// Σ a_i q^i, q clamped to `range_mm` (flagged), as `ErrorFunction::Polynomial`.
    Polynomial {
        coefficients: Vec<f64>,
        range_mm: Option<(f64, f64)>,
    },
    /// The piecewise quadratic: evaluated as written.
    Other(ErrorFunction),
}

impl Curve {
    pub(crate) fn new(f: &ErrorFunction) -> Curve {
        let t = match f {
            ErrorFunction::Table(t) => t,
            ErrorFunction::Polynomial {
                coefficients,
                range_mm,
            } => {
                return Curve::Polynomial {
                    coefficients: coefficients.clone(),
                    range_mm: *range_mm,
                };
            }
            ErrorFunction::PiecewiseQuadratic { .. } => return Curve::Other(f.clone()),
        };
        let nodes = Nodes::new(&t.positions_mm);
        let c1 = t.interpolation == Interpolation::C1;
        let (mf, mr) = t.slopes();
        let values = by_dir(&t.forward, &t.reverse);
        let slopes = by_dir(&mf, &mr);
        let cubic = std::array::from_fn(|slot| {
            let (v, m) = (&values[slot], &slopes[slot]);
            (0..v.len() - 1)
                .map(|i| {
                    let (va, vb) = (v[i], v[i + 1]);
                    if !c1 {
                        return [va, vb - va, 0.0, 0.0];
                    }
                    // h00 va + h10 h ma + h01 vb + h11 h mb with h00 = 2t³ − 3t² + 1,
                    // h10 = t³ − 2t² + t, h01 = −2t³ + 3t², h11 = t³ − t².
                    let h = nodes.x[i + 1] - nodes.x[i];
                    let (hma, hmb) = (h * m[i], h * m[i + 1]);
                    [
                        va,
                        hma,
                        3.0 * (vb - va) - 2.0 * hma - hmb,
                        2.0 * (va - vb) + hma + hmb,
                    ]
                })
                .collect()
        });
        Curve::Table {
            nodes,
            cubic,
            values,
        }
    }

    /// (value, clamped) at `q` for approach direction `dir`: `ErrorFunction::eval` to rounding.
    /// Inlined into the plan (a call per load curve cost ≈ 80 instructions); the piecewise
    /// quadratic stays a call.
    #[inline(always)]
    pub(crate) fn eval(&self, q: f64, dir: i8) -> (f64, bool) {
        match self {
            Curve::Table {
                nodes,
                cubic,
                values,
            } => {
                let (a, _, t, clamped) = nodes.locate(q);
                if clamped {
                    return (values[dir_slot(dir)][a], true);
                }
                let [c0, c1, c2, c3] = cubic[dir_slot(dir)][a];
                (c0 + t * (c1 + t * (c2 + t * c3)), false)
            }
            Curve::Polynomial {
                coefficients,
                range_mm,
            } => {
                let (q, clamped) = clamp_range(q, *range_mm);
                let v = coefficients.iter().rev().fold(0.0, |acc, &a| acc * q + a);
                (v, clamped)
            }
            Curve::Other(f) => eval_other(f, q, dir),
        }
    }
}

#[inline(never)]
fn eval_other(f: &ErrorFunction, q: f64, dir: i8) -> (f64, bool) {
    f.eval(q, dir)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::function::Table;

    /// Every compiled curve gives `ErrorFunction::eval`'s value and flag, for every direction, at
    /// nodes, between them, at and beyond both ends and for NaN.
    fn assert_same(f: &ErrorFunction, lo: f64, hi: f64) {
        let c = Curve::new(f);
        let mut qs: Vec<f64> = (0..=400)
            .map(|k| lo + (hi - lo) * f64::from(k) / 400.0)
            .collect();
        qs.extend([
            lo - 7.0,
            hi + 7.0,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ]);
        if let ErrorFunction::Table(t) = f {
            qs.extend(t.positions_mm.iter().copied());
        }
        for q in qs {
            for dir in [-1i8, 0, 1] {
                let (want, want_cl) = f.eval(q, dir);
                let (got, got_cl) = c.eval(q, dir);
                assert_eq!(got_cl, want_cl, "{q} dir {dir}");
                assert!(
                    (got - want).abs() <= 1e-12,
                    "{q} dir {dir}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn curves_equal_the_functions_they_compile() {
        // Uneven positions (the guess from the mean spacing is several segments off: binary search).
        let x = vec![0.0, 10.0, 11.0, 55.0, 300.0, 301.5, 500.0];
        let fwd = vec![0.0, 3.0, 2.5, -4.0, 7.0, 7.2, 1.0];
        let rev = vec![1.0, 2.0, 3.5, -2.0, 5.0, 8.0, 0.0];
        for interp in [Interpolation::Linear, Interpolation::C1] {
            let t = Table::new(x.clone(), fwd.clone(), rev.clone(), interp);
            assert_same(&ErrorFunction::Table(t), 0.0, 500.0);
        }
        // Even positions (the usual case: the guess is right or one off).
        let x: Vec<f64> = (0..100).map(|k| f64::from(k) * 8.08).collect();
        let fwd: Vec<f64> = x.iter().map(|q| (q * 0.03).sin() * 5.0).collect();
        let rev: Vec<f64> = fwd.iter().map(|v| v - 1.5).collect();
        for interp in [Interpolation::Linear, Interpolation::C1] {
            let t = Table::new(x.clone(), fwd.clone(), rev.clone(), interp);
            assert_same(&ErrorFunction::Table(t), 0.0, 99.0 * 8.08);
        }
        for range_mm in [None, Some((0.0, 500.0))] {
            let p = ErrorFunction::Polynomial {
                coefficients: vec![0.005, 8e-6, -1e-9],
                range_mm,
            };
            assert_same(&p, 0.0, 500.0);
        }
    }

    #[test]
    fn direction_slots_pick_reverse_mean_forward() {
        assert_eq!(by_dir(&[4.0], &[2.0]), [vec![2.0], vec![3.0], vec![4.0]]);
        assert_eq!([-5i8, -1, 0, 1, 7].map(dir_slot), [0, 0, 1, 2, 2]);
    }
}
