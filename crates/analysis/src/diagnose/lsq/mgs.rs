//! Modified Gram–Schmidt ([`orthonormalize`]) with each subtraction fused into the pass that
//! forms the next dot product. A dot product's sum is one chain of dependent additions in row
//! order (its bits are that order), so a pass over the rows waits on the adder; the subtraction
//! of the previous basis column, the squared norms and the first dot product ride along in the
//! same pass instead of a pass of their own (screening a 10⁶-row recording's non-cyclic
//! candidates was a fifth of its CPU here). Every value is the one the two-pass form computes.

/// Orthonormalise `cols` against `basis` and each other (modified Gram–Schmidt, `passes` sweeps).
/// Columns that are (numerically) in the span already are dropped: they can explain nothing new.
pub fn orthonormalize(basis: &[Vec<f64>], cols: Vec<Vec<f64>>, passes: usize) -> Vec<Vec<f64>> {
    orthonormalize_dots(basis, cols, passes, None).0
}

/// [`orthonormalize`] (one sweep) and the RSS drop [`super::gain`] reads off for `r0`, each
/// column's dot product with `r0` taken in the pass that scales it.
pub fn orthonormalize_gain(
    basis: &[Vec<f64>],
    cols: Vec<Vec<f64>>,
    r0: &[f64],
) -> (Vec<Vec<f64>>, f64) {
    let (u, dots) = orthonormalize_dots(basis, cols, 1, Some(r0));
    (u, dots.iter().map(|d| d.powi(2)).sum())
}

/// [`orthonormalize`], and with `r0` each kept column's dot product with it.
fn orthonormalize_dots(
    basis: &[Vec<f64>],
    cols: Vec<Vec<f64>>,
    passes: usize,
    r0: Option<&[f64]>,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let mut out: Vec<Vec<f64>> = vec![];
    let mut dots = vec![];
    for mut c in cols {
        let n = c.len();
        let per_pass = basis.len() + out.len();
        let steps = passes * per_pass;
        let along = |j: usize| -> &[f64] {
            let k = j % per_pass;
            if k < basis.len() {
                &basis[k]
            } else {
                &out[k - basis.len()]
            }
        };
        let long = n >= super::FFT_MIN_N;
        let (n0_sq, mut d) = if long {
            long_norm_and_dot(&mut c, (steps > 0).then(|| along(0)))
        } else {
            norm_and_dot(&c, (steps > 0).then(|| along(0)))
        };
        let n0 = n0_sq.sqrt();
        if n0.is_nan() || n0 <= 0.0 {
            continue;
        }
        for j in 1..steps {
            let (prev, next) = (along(j - 1), along(j));
            d = if long {
                lane_sum(&mut c, |i, v| {
                    *v += -d * prev[i];
                    next[i] * *v
                })
            } else {
                subtract_then_dot(&mut c, -d, prev, next)
            };
        }
        let n1 = match (steps, long) {
            (0, _) => n0_sq,
            (_, true) => {
                let prev = along(steps - 1);
                lane_sum(&mut c, |i, v| {
                    *v += -d * prev[i];
                    *v * *v
                })
            }
            (_, false) => subtract_then_norm(&mut c, -d, along(steps - 1)),
        }
        .sqrt();
        if n1 < 1e-7 * n0 {
            continue;
        }
        match r0 {
            Some(r0) if r0.len() == n && long => {
                dots.push(lane_sum(&mut c, |i, v| {
                    *v /= n1;
                    *v * r0[i]
                }));
            }
            Some(r0) if r0.len() == n => {
                dots.push(c.iter_mut().zip(r0).fold(-0.0, |d, (v, r)| {
                    *v /= n1;
                    d + *v * r
                }));
            }
            _ => {
                c.iter_mut().for_each(|v| *v /= n1);
                dots.extend(r0.map(|r0| super::dot(&c, r0)));
            }
        }
        out.push(c);
    }
    (out, dots)
}

/// Partial sums per row of the long-recording passes: row i → lane i mod 4.
const LANES: usize = 4;

/// Σ_i `row(i, c_i)` (the row updating c_i in place) over the rows of a long recording: four
/// partial sums by row per span, the spans in parallel and added in order
/// ([`super::spans::sum_spans_mut`]), so the same bits with any number of threads. One running
/// sum per pass waited on the adder at every row, on one core (orthonormalising a 10⁶-row
/// basis held the other core idle); these sums differ from it by rounding.
fn lane_sum(c: &mut [f64], row: impl Fn(usize, &mut f64) -> f64 + Sync) -> f64 {
    let lanes = super::spans::sum_spans_mut(c, |start, part| {
        let mut l = [0.0; LANES];
        let whole = part.len() / LANES * LANES;
        let mut quads = part.chunks_exact_mut(LANES);
        for (q, quad) in quads.by_ref().enumerate() {
            for (k, v) in quad.iter_mut().enumerate() {
                l[k] += row(start + q * LANES + k, v);
            }
        }
        for (k, v) in quads.into_remainder().iter_mut().enumerate() {
            l[k] += row(start + whole + k, v);
        }
        vec![l]
    });
    let l = lanes[0];
    (l[0] + l[1]) + (l[2] + l[3])
}

/// [`norm_and_dot`] of a long recording, as [`lane_sum`]s (`c` is not changed).
fn long_norm_and_dot(c: &mut [f64], b: Option<&[f64]>) -> (f64, f64) {
    let norm = lane_sum(c, |_, v| *v * *v);
    (norm, b.map_or(-0.0, |b| lane_sum(c, |i, v| b[i] * *v)))
}

/// (Σ c², Σ b·c) in one pass; the second is −0 (an empty sum) without `b`. Sums start at −0,
/// as `Iterator::sum` does, so each is the bits of `dot`.
fn norm_and_dot(c: &[f64], b: Option<&[f64]>) -> (f64, f64) {
    match b {
        None => (c.iter().fold(-0.0, |s, v| s + v * v), -0.0),
        Some(b) => c
            .iter()
            .zip(&b[..c.len()])
            .fold((-0.0, -0.0), |(n, d), (v, w)| (n + v * v, d + w * v)),
    }
}

/// c += k·prev (`axpy`), and Σ next·c of the updated c, in one pass.
fn subtract_then_dot(c: &mut [f64], k: f64, prev: &[f64], next: &[f64]) -> f64 {
    let n = c.len();
    c.iter_mut()
        .zip(&prev[..n])
        .zip(&next[..n])
        .fold(-0.0, |d, ((v, p), w)| {
            *v += k * p;
            d + w * *v
        })
}

/// c += k·prev (`axpy`), and Σ c² of the updated c, in one pass.
fn subtract_then_norm(c: &mut [f64], k: f64, prev: &[f64]) -> f64 {
    let n = c.len();
    c.iter_mut().zip(&prev[..n]).fold(-0.0, |s, (v, p)| {
        *v += k * p;
        s + *v * *v
    })
}

#[cfg(test)]
mod tests {
    use super::super::{axpy, dot};

    /// The two-pass modified Gram–Schmidt the fused one must equal bit for bit.
    fn two_pass(basis: &[Vec<f64>], cols: Vec<Vec<f64>>, passes: usize) -> Vec<Vec<f64>> {
        let mut out: Vec<Vec<f64>> = vec![];
        for mut c in cols {
            let n0 = dot(&c, &c).sqrt();
            if n0.is_nan() || n0 <= 0.0 {
                continue;
            }
            for _ in 0..passes {
                for b in basis.iter().chain(out.iter()) {
                    let d = dot(b, &c);
                    axpy(-d, b, &mut c);
                }
            }
            let n1 = dot(&c, &c).sqrt();
            if n1 < 1e-7 * n0 {
                continue;
            }
            c.iter_mut().for_each(|v| *v /= n1);
            out.push(c);
        }
        out
    }

    #[test]
    fn fused_gram_schmidt_is_the_two_pass_one_bit_for_bit() {
        let n = 5000;
        let col = |w: f64, p: f64| -> Vec<f64> {
            (0..n)
                .map(|i| (w * i as f64 + p).sin() + 1e-4 * i as f64)
                .collect()
        };
        let basis = two_pass(&[], vec![vec![1.0; n], col(0.001, 0.2)], 2);
        let bits = |u: &[Vec<f64>]| -> Vec<Vec<u64>> {
            u.iter()
                .map(|c| c.iter().map(|v| v.to_bits()).collect())
                .collect()
        };
        let cases: Vec<Vec<Vec<f64>>> = vec![
            vec![col(0.05, 0.0)],
            vec![col(0.05, 0.0), col(0.05, 1.0), col(0.3, 0.5)],
            // One column in the basis' span, one zero column: both dropped.
            vec![vec![2.0; n], vec![0.0; n], col(0.02, 0.1)],
        ];
        for b in [&basis[..0], &basis[..1], &basis[..]] {
            for cols in &cases {
                for passes in [0, 1, 2] {
                    let want = two_pass(b, cols.clone(), passes);
                    let got = super::orthonormalize(b, cols.clone(), passes);
                    assert_eq!(bits(&got), bits(&want), "basis {} passes {passes}", b.len());
                }
                let r0 = col(0.05, 0.3);
                let want = two_pass(b, cols.clone(), 1);
                let (got, g) = super::orthonormalize_gain(b, cols.clone(), &r0);
                assert_eq!(bits(&got), bits(&want), "basis {}", b.len());
                assert_eq!(g.to_bits(), super::super::gain(&want, &r0).to_bits());
            }
        }
    }

    /// From `FFT_MIN_N` rows the passes' sums are four partial sums per span: the columns are
    /// the two-pass ones to rounding (same columns kept), and the same bits on one thread and
    /// on several.
    #[test]
    fn long_recordings_orthonormalise_as_the_two_pass_one_on_any_number_of_threads() {
        let n = super::super::FFT_MIN_N + 77;
        let col = |w: f64, p: f64| -> Vec<f64> {
            (0..n)
                .map(|i| (w * i as f64 + p).sin() + 1e-6 * i as f64)
                .collect()
        };
        let basis = two_pass(&[], vec![vec![1.0; n], col(1e-5, 0.2)], 2);
        let cols = vec![col(0.05, 0.0), vec![3.0; n], col(0.3, 0.5)];
        let r0 = col(0.05, 0.3);
        let want = two_pass(&basis, cols.clone(), 2);
        let run = |threads: usize| {
            crate::diagnose::test_pool(threads).install(|| {
                (
                    super::orthonormalize(&basis, cols.clone(), 2),
                    super::orthonormalize_gain(&basis, cols.clone(), &r0),
                )
            })
        };
        let (one, (one_u, one_g)) = run(1);
        assert_eq!(one.len(), want.len(), "the constant column is dropped");
        for (a, b) in one.iter().zip(&want) {
            let err = a
                .iter()
                .zip(b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-12, "{err}");
        }
        let g = super::super::gain(&two_pass(&basis, cols.clone(), 1), &r0);
        assert!((one_g - g).abs() <= 1e-9 * g, "{one_g} vs {g}");
        let (four, (four_u, four_g)) = run(4);
        let bits =
            |u: &[Vec<f64>]| -> Vec<u64> { u.concat().iter().map(|v| v.to_bits()).collect() };
        assert_eq!(bits(&one), bits(&four));
        assert_eq!(bits(&one_u), bits(&four_u));
        assert_eq!(one_g.to_bits(), four_g.to_bits());
    }
}
