//! One-dimensional error functions of an axis position: bidirectional tables, polynomials and C¹
//! piecewise quadratics (Spaan 1995 Ch3, truncated-power form).
//!
//! Positions are mm in the axis' own coordinate. Values are in whatever internal unit the owner
//! gives them (µm for translations, µrad for rotations, µm/N for compliances); this module never
//! converts. Direction: +1 = forward table (approach in + direction), −1 = reverse table, 0 = the
//! mean of the two. Outside a table's span, or a polynomial's `range_mm`, the value is clamped to the
//! end value and the evaluation reports `clamped = true`.

/// Interpolation between table points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// Piecewise linear: exact at the nodes, C⁰.
    Linear,
    /// Monotone piecewise cubic Hermite (Fritsch–Carlson/PCHIP slopes): exact at the nodes, C¹, and
    /// never overshoots the data between two nodes (no invented peaks in a correction).
    C1,
}

impl Interpolation {
    pub fn as_str(self) -> &'static str {
        match self {
            Interpolation::Linear => "linear",
            Interpolation::C1 => "c1",
        }
    }
}

/// A bidirectional table: forward and reverse values at the same positions.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    pub positions_mm: Vec<f64>,
    pub forward: Vec<f64>,
    pub reverse: Vec<f64>,
    pub interpolation: Interpolation,
    /// (x0, 1/mean spacing): the first guess of a lookup.
    guide: (f64, f64),
    /// The same data interleaved per node, so one lookup touches one or two cache lines.
    nodes: Vec<Node>,
}

/// One table node: position, forward and reverse value, and their C¹ slopes (0 when linear).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Node {
    x: f64,
    /// 1 / (x_{i+1} − x_i): a multiply instead of a divide per lookup (0 for the last node).
    inv_h: f64,
    f: f64,
    r: f64,
    mf: f64,
    mr: f64,
}

impl Table {
    /// Build a table. The caller has validated: ≥ 2 points, strictly increasing positions, equal
    /// lengths, finite values.
    pub fn new(
        positions_mm: Vec<f64>,
        forward: Vec<f64>,
        reverse: Vec<f64>,
        interpolation: Interpolation,
    ) -> Self {
        let n = positions_mm.len();
        let x0 = positions_mm[0];
        let h = (positions_mm[n - 1] - x0) / (n - 1) as f64;
        let guide = (x0, 1.0 / h);
        let (slopes_fwd, slopes_rev) = match interpolation {
            Interpolation::Linear => (vec![0.0; n], vec![0.0; n]),
            Interpolation::C1 => (
                pchip_slopes(&positions_mm, &forward),
                pchip_slopes(&positions_mm, &reverse),
            ),
        };
        let nodes = (0..n)
            .map(|i| Node {
                x: positions_mm[i],
                inv_h: if i + 1 < n {
                    1.0 / (positions_mm[i + 1] - positions_mm[i])
                } else {
                    0.0
                },
                f: forward[i],
                r: reverse[i],
                mf: slopes_fwd[i],
                mr: slopes_rev[i],
            })
            .collect();
        Table {
            positions_mm,
            forward,
            reverse,
            interpolation,
            guide,
            nodes,
        }
    }

    /// The C¹ slopes per node (forward, reverse); all 0 for a linear table.
    pub fn slopes(&self) -> (Vec<f64>, Vec<f64>) {
        self.nodes.iter().map(|n| (n.mf, n.mr)).unzip()
    }

    pub fn is_bidirectional(&self) -> bool {
        self.forward != self.reverse
    }

    /// Segment index i (x_i ≤ q ≤ x_{i+1}) for q inside the span. Guesses from the mean spacing
    /// and walks at most two steps (tables written with rounded, almost even positions), else falls
    /// back to a binary search; always exact.
    #[inline]
    fn segment(&self, q: f64) -> usize {
        let x = &self.nodes;
        let last = x.len() - 2;
        let (x0, inv_h) = self.guide;
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a guess only: `as` saturates (q below x0 gives 0, NaN gives 0) and it is clamped to `last` and checked below"
        )]
        let guess = ((q - x0) * inv_h) as usize;
        let mut i = guess.min(last);
        for _ in 0..2 {
            if x[i].x > q && i > 0 {
                i -= 1;
            } else if x[i + 1].x <= q && i < last {
                i += 1;
            } else {
                return i;
            }
        }
        if x[i].x <= q && (q < x[i + 1].x || i == last) {
            i
        } else {
            x.partition_point(|p| p.x <= q).saturating_sub(1).min(last)
        }
    }

    /// Where `q_mm` falls in the table. Tables with equal `positions_mm` locate alike, so one
    /// [`Location`] serves every component of an axis (one search instead of six).
    #[inline]
    pub(crate) fn locate(&self, q_mm: f64) -> Location {
        let nodes = &self.nodes;
        let n = nodes.len();
        // NaN is clamped and flagged rather than propagated.
        if q_mm.is_nan() || q_mm < nodes[0].x {
            return Location::Clamped(0);
        }
        if q_mm > nodes[n - 1].x {
            return Location::Clamped(n - 1);
        }
        let i = self.segment(q_mm);
        let a = &nodes[i];
        Location::Inside {
            segment: i,
            t: (q_mm - a.x) * a.inv_h,
        }
    }

    /// Whether two tables have the same nodes (then a [`Location`] of one is valid for the other).
    pub(crate) fn same_positions(&self, other: &Table) -> bool {
        self.positions_mm == other.positions_mm
    }

    /// Value at a location found by [`locate`](Self::locate) on a table with the same positions.
    #[inline]
    pub(crate) fn eval_at(&self, loc: Location, dir: i8) -> (f64, bool) {
        let nodes = &self.nodes;
        // Branch-free choice (the approach direction changes often): weights 1/0, 0/1 or ½/½; each
        // is exact, so forward and reverse values come through unchanged.
        let w_fwd = 0.5 * (1.0 + f64::from(dir.signum()));
        let pick = |fwd: f64, rev: f64| w_fwd * fwd + (1.0 - w_fwd) * rev;
        let (i, t) = match loc {
            Location::Clamped(k) => return (pick(nodes[k].f, nodes[k].r), true),
            Location::Inside { segment, t } => (segment, t),
        };
        let (a, b) = (nodes[i], nodes[i + 1]);
        let (vf, vr) = match self.interpolation {
            Interpolation::Linear => (a.f + t * (b.f - a.f), a.r + t * (b.r - a.r)),
            Interpolation::C1 => {
                let h = b.x - a.x;
                let t2 = t * t;
                let t3 = t2 * t;
                let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
                let h10 = (t3 - 2.0 * t2 + t) * h;
                let h01 = -2.0 * t3 + 3.0 * t2;
                let h11 = (t3 - t2) * h;
                (
                    h00 * a.f + h10 * a.mf + h01 * b.f + h11 * b.mf,
                    h00 * a.r + h10 * a.mr + h01 * b.r + h11 * b.mr,
                )
            }
        };
        (pick(vf, vr), false)
    }

    #[inline]
    pub fn eval(&self, q_mm: f64, dir: i8) -> (f64, bool) {
        self.eval_at(self.locate(q_mm), dir)
    }
}

/// A position located in a table: a segment and the fraction t ∈ [0, 1] along it, or the end node
/// it was clamped to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Location {
    Inside { segment: usize, t: f64 },
    Clamped(usize),
}

/// Fritsch–Carlson monotone slopes (the PCHIP rule of Fritsch & Butland 1984).
fn pchip_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let d: Vec<f64> = (0..n - 1)
        .map(|i| (y[i + 1] - y[i]) / (x[i + 1] - x[i]))
        .collect();
    let mut m = vec![0.0; n];
    if n == 2 {
        m[0] = d[0];
        m[1] = d[0];
        return m;
    }
    for i in 1..n - 1 {
        if d[i - 1] * d[i] > 0.0 {
            let (h0, h1) = (x[i] - x[i - 1], x[i + 1] - x[i]);
            let (w1, w2) = (2.0 * h1 + h0, h1 + 2.0 * h0);
            m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i]);
        }
    }
    // One-sided three-point end slopes, limited so the end segments stay monotone.
    let end = |h0: f64, h1: f64, d0: f64, d1: f64| {
        let s = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
        if s * d0 <= 0.0 {
            0.0
        } else if d0 * d1 <= 0.0 && s.abs() > 3.0 * d0.abs() {
            3.0 * d0
        } else {
            s
        }
    };
    m[0] = end(x[1] - x[0], x[2] - x[1], d[0], d[1]);
    m[n - 1] = end(x[n - 1] - x[n - 2], x[n - 2] - x[n - 3], d[n - 2], d[n - 3]);
    m
}

/// The shape of one error function.
#[derive(Clone, Debug, PartialEq)]
pub enum ErrorFunction {
    Table(Table),
    /// value = Σ a_i q^i (q in mm). Outside `range_mm`, if given, q is clamped and flagged.
    Polynomial {
        coefficients: Vec<f64>,
        range_mm: Option<(f64, f64)>,
    },
    /// Spaan's truncated-power form with degree 2 and C¹ continuity:
    /// value = b0 + b1 q + b2 q² + Σ_i c_i (q − t_i)₊².
    PiecewiseQuadratic {
        base: [f64; 3],
        knots_mm: Vec<f64>,
        knot_coefficients: Vec<f64>,
        range_mm: Option<(f64, f64)>,
    },
}

impl ErrorFunction {
    /// Value at `q_mm` for approach direction `dir`, and whether the position was clamped.
    #[inline]
    pub fn eval(&self, q_mm: f64, dir: i8) -> (f64, bool) {
        match self {
            ErrorFunction::Table(t) => t.eval(q_mm, dir),
            ErrorFunction::Polynomial {
                coefficients,
                range_mm,
            } => {
                let (q, clamped) = clamp_range(q_mm, *range_mm);
                (
                    coefficients.iter().rev().fold(0.0, |acc, &a| acc * q + a),
                    clamped,
                )
            }
            ErrorFunction::PiecewiseQuadratic {
                base,
                knots_mm,
                knot_coefficients,
                range_mm,
            } => {
                let (q, clamped) = clamp_range(q_mm, *range_mm);
                let mut v = base[0] + q * (base[1] + q * base[2]);
                for (&t, &c) in knots_mm.iter().zip(knot_coefficients) {
                    let d = q - t;
                    if d > 0.0 {
                        v += c * d * d;
                    }
                }
                (v, clamped)
            }
        }
    }

    pub fn kind_name(&self) -> &'static str {
        match self {
            ErrorFunction::Table(_) => "table",
            ErrorFunction::Polynomial { .. } => "polynomial",
            ErrorFunction::PiecewiseQuadratic { .. } => "piecewise_quadratic",
        }
    }

    /// Multiply every value by `k` (unit conversion at load, sign flips in fixtures).
    pub fn scaled(&self, k: f64) -> ErrorFunction {
        let s = |v: &[f64]| v.iter().map(|x| x * k).collect::<Vec<_>>();
        match self {
            ErrorFunction::Table(t) => ErrorFunction::Table(Table::new(
                t.positions_mm.clone(),
                s(&t.forward),
                s(&t.reverse),
                t.interpolation,
            )),
            ErrorFunction::Polynomial {
                coefficients,
                range_mm,
            } => ErrorFunction::Polynomial {
                coefficients: s(coefficients),
                range_mm: *range_mm,
            },
            ErrorFunction::PiecewiseQuadratic {
                base,
                knots_mm,
                knot_coefficients,
                range_mm,
            } => ErrorFunction::PiecewiseQuadratic {
                base: [base[0] * k, base[1] * k, base[2] * k],
                knots_mm: knots_mm.clone(),
                knot_coefficients: s(knot_coefficients),
                range_mm: *range_mm,
            },
        }
    }
}

#[inline]
pub(crate) fn clamp_range(q: f64, range: Option<(f64, f64)>) -> (f64, bool) {
    match range {
        Some((lo, _)) if q.is_nan() || q < lo => (lo, true),
        Some((_, hi)) if q > hi => (hi, true),
        Some(_) => (q, false),
        None if q.is_finite() => (q, false),
        None => (0.0, true),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(interp: Interpolation) -> Table {
        Table::new(
            vec![0.0, 10.0, 20.0, 40.0],
            vec![0.0, 1.0, 3.0, 2.0],
            vec![1.0, 2.0, 2.0, 0.0],
            interp,
        )
    }

    #[test]
    fn exact_at_nodes_both_directions_and_mean() {
        for interp in [Interpolation::Linear, Interpolation::C1] {
            let t = table(interp);
            for (i, &x) in t.positions_mm.iter().enumerate() {
                assert_eq!(t.eval(x, 1), (t.forward[i], false));
                assert_eq!(t.eval(x, -1), (t.reverse[i], false));
                assert!((t.eval(x, 0).0 - 0.5 * (t.forward[i] + t.reverse[i])).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn linear_midpoint_and_clamp_outside() {
        let t = table(Interpolation::Linear);
        assert!((t.eval(15.0, 1).0 - 2.0).abs() < 1e-12);
        assert!((t.eval(30.0, -1).0 - 1.0).abs() < 1e-12);
        assert_eq!(t.eval(-5.0, 1), (0.0, true));
        assert_eq!(t.eval(45.0, -1), (0.0, true));
        assert_eq!(t.eval(f64::NAN, 1), (0.0, true));
    }

    #[test]
    fn c1_is_continuous_in_slope_and_does_not_overshoot() {
        let t = table(Interpolation::C1);
        // Slope left and right of an interior node agree.
        let e = 1e-6;
        let d = |q: f64| (t.eval(q + e, 1).0 - t.eval(q - e, 1).0) / (2.0 * e);
        let left = (t.eval(10.0, 1).0 - t.eval(10.0 - e, 1).0) / e;
        let right = (t.eval(10.0 + e, 1).0 - t.eval(10.0, 1).0) / e;
        assert!((left - right).abs() < 1e-4, "{left} vs {right}");
        assert!(d(5.0) > 0.0);
        // Between 20 (3.0) and 40 (2.0) the curve stays inside [2, 3].
        for k in 0..=100 {
            let v = t.eval(20.0 + 0.2 * f64::from(k), 1).0;
            assert!((2.0 - 1e-12..=3.0 + 1e-12).contains(&v), "overshoot {v}");
        }
    }

    #[test]
    fn lookup_finds_the_right_segment_for_even_rounded_and_uneven_tables() {
        let even: Vec<f64> = (0..100).map(|i| f64::from(i) * 800.0 / 99.0).collect();
        let rounded: Vec<f64> = even.iter().map(|x| (x * 1e4).round() / 1e4).collect();
        let uneven: Vec<f64> = (0..40).map(|i| f64::from(i).powi(2) * 0.7).collect();
        for xs in [even, rounded, uneven] {
            let t = Table::new(xs.clone(), xs.clone(), xs.clone(), Interpolation::Linear);
            let (lo, hi) = (xs[0], xs[xs.len() - 1]);
            for k in 0..=5000 {
                let q = lo + (hi - lo) * f64::from(k) / 5000.0;
                let i = t.segment(q);
                assert!(xs[i] <= q && (q <= xs[i + 1]), "q {q} got segment {i}");
                // The table is the identity function: interpolation must return q itself.
                assert!((t.eval(q, 1).0 - q).abs() < 1e-9 * hi.max(1.0));
            }
            for &x in &xs {
                assert_eq!(t.eval(x, -1), (x, false));
            }
        }
    }

    #[test]
    fn polynomial_and_truncated_power() {
        let p = ErrorFunction::Polynomial {
            coefficients: vec![1.0, -2.0, 0.5],
            range_mm: Some((0.0, 10.0)),
        };
        assert_eq!(p.eval(2.0, 0), (1.0 - 4.0 + 2.0, false));
        assert_eq!(p.eval(12.0, 0), (1.0 - 20.0 + 50.0, true));
        let pq = ErrorFunction::PiecewiseQuadratic {
            base: [0.0, 1.0, 0.0],
            knots_mm: vec![5.0],
            knot_coefficients: vec![2.0],
            range_mm: None,
        };
        assert_eq!(pq.eval(4.0, 0).0, 4.0);
        assert_eq!(pq.eval(7.0, 0).0, 7.0 + 2.0 * 4.0);
        // C¹ at the knot: the truncated square has zero value and slope there.
        let e = 1e-7;
        let sl = (pq.eval(5.0, 0).0 - pq.eval(5.0 - e, 0).0) / e;
        let sr = (pq.eval(5.0 + e, 0).0 - pq.eval(5.0, 0).0) / e;
        assert!((sl - sr).abs() < 1e-5);
    }
}
