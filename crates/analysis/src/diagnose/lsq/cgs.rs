//! Candidates scored against an orthonormal basis without orthonormalised copies of their columns:
//! classical Gram–Schmidt in two read-only passes over the rows, blocked so a block of every
//! column stays in cache. Pass one takes each column's norm and its coefficients on the basis
//! (Bᵀc); pass two forms c − B·Bᵀc one block at a time (never stored whole) and sums its
//! products with the candidate's other such parts and with r0. [`super::orthonormalize_gain`]
//! (modified Gram–Schmidt) reads and writes the whole column once per basis vector, each sum one
//! chain of dependent additions; on a 10⁶-row recording that was most of a selection step's and
//! of the joint refit's time.
//!
//! Against a basis that is orthonormal to working precision (`orthonormalize` with two passes)
//! one classical pass projects as well as one modified pass; the two differ by rounding. The
//! squared norm of the part outside the basis is summed from that part itself, not as
//! ‖c‖² − ‖Bᵀc‖² ([`super::gram_gain`]), so a column nearly in the span keeps its precision.
//! Every sum is split over [`LANES`] partial sums by row in a fixed way and over the fixed spans
//! of rows [`super::spans`] runs in parallel, whatever the number of columns or threads.

use super::spans::sum_spans;

/// Rows per block: one block of a column, the part outside the basis and four basis vectors stay
/// in the first-level cache. A multiple of [`LANES`].
const BLOCK: usize = 1024;

/// Basis vectors summed against a column in one sweep of a block (independent sums).
const GROUP: usize = 4;

/// Partial sums per product: row i goes to lane i mod `LANES`, and the lanes are added in a fixed
/// order at the end. One running sum per product waits on the previous addition at every row (the
/// floating-point latency, not the memory, bounded the sums); four per product run side by side
/// and in vector registers. The order is fixed, so the bits do not depend on the threads.
const LANES: usize = 4;

type Lanes = [f64; LANES];

/// The lanes' total, in a fixed order.
fn total(l: &Lanes) -> f64 {
    (l[0] + l[1]) + (l[2] + l[3])
}

/// The RSS drop [`super::orthonormalize_gain`] reads off for one candidate's `cols` against the
/// orthonormal `basis` and a residual `r0` orthogonal to it, and the number of columns kept: the
/// parts outside the basis, C⊥ = C − B·BᵀC, summed into C⊥ᵀC⊥ and C⊥ᵀr0, then a small Cholesky
/// that drops a column as the modified Gram–Schmidt pass does (what is left of it beside the
/// basis and the columns kept before it is below 1e-7 of its norm, or it is zero or not finite).
pub fn projected_gain(basis: &[Vec<f64>], cols: &[Vec<f64>], r0: &[f64]) -> (f64, usize) {
    let (n, k, q) = (r0.len(), basis.len(), cols.len());
    // Pass one, per span: ‖c‖² (q lanes), then Bᵀc (k lanes per column).
    let one = sum_spans(n, |span| {
        let mut acc = vec![[0.0; LANES]; q + q * k];
        let (norm0, coef) = acc.split_at_mut(q);
        for start in span.clone().step_by(BLOCK) {
            let rows = start..(start + BLOCK).min(span.end);
            for (a, c) in cols.iter().enumerate() {
                let c = &c[rows.clone()];
                add_products(&mut norm0[a], c, c);
                for (j0, group) in basis.chunks(GROUP).enumerate() {
                    let acc = &mut coef[a * k + j0 * GROUP..a * k + j0 * GROUP + group.len()];
                    match group.len() {
                        1 => dots::<1>(acc, group, c, &rows),
                        2 => dots::<2>(acc, group, c, &rows),
                        3 => dots::<3>(acc, group, c, &rows),
                        _ => dots::<GROUP>(acc, group, c, &rows),
                    }
                }
            }
        }
        acc
    });
    let (norm0, coef) = one.split_at(q);
    let coef: Vec<Vec<f64>> = (0..q)
        .map(|a| coef[a * k..a * k + k].iter().map(total).collect())
        .collect();
    // Pass two, per span: C⊥ block by block; its products (lower triangle, row-major q×q), then
    // C⊥ᵀr0 (q lanes).
    let two = sum_spans(n, |span| {
        let mut acc = vec![[0.0; LANES]; q * q + q];
        let (m, h) = acc.split_at_mut(q * q);
        let mut v = vec![0.0; q * BLOCK];
        for start in span.clone().step_by(BLOCK) {
            let rows = start..(start + BLOCK).min(span.end);
            let len = rows.len();
            for (a, c) in cols.iter().enumerate() {
                let va = &mut v[a * BLOCK..a * BLOCK + len];
                va.copy_from_slice(&c[rows.clone()]);
                for (b, d) in basis.chunks(GROUP).zip(coef[a].chunks(GROUP)) {
                    match b.len() {
                        1 => subtract::<1>(va, b, d, &rows),
                        2 => subtract::<2>(va, b, d, &rows),
                        3 => subtract::<3>(va, b, d, &rows),
                        _ => subtract::<GROUP>(va, b, d, &rows),
                    }
                }
                add_products(&mut h[a], va, &r0[rows.clone()]);
            }
            for a in 0..q {
                for a2 in 0..=a {
                    let (x, y) = (
                        &v[a * BLOCK..a * BLOCK + len],
                        &v[a2 * BLOCK..a2 * BLOCK + len],
                    );
                    add_products(&mut m[a * q + a2], x, y);
                }
            }
        }
        acc
    });
    let (m, h) = two.split_at(q * q);
    let m: Vec<f64> = m.iter().map(total).collect();
    let h: Vec<f64> = h.iter().map(total).collect();
    let norm0: Vec<f64> = norm0.iter().map(|l| total(l).sqrt()).collect();
    cholesky_gain(&m, &h, |j, d| {
        let n1 = d.max(0.0).sqrt();
        norm0[j].is_finite() && norm0[j] > 0.0 && n1.is_finite() && n1 >= 1e-7 * norm0[j]
    })
}

/// y = L⁻¹h for the Cholesky factor L of the q×q matrix `m` (lower triangle read), column j
/// kept only where `keep(j, pivot)` holds for its pivot (what is left of its squared norm beside
/// the columns kept before it): (‖y‖², columns kept).
pub(super) fn cholesky_gain(
    m: &[f64],
    h: &[f64],
    keep: impl Fn(usize, f64) -> bool,
) -> (f64, usize) {
    let q = h.len();
    let mut l = vec![0.0; q * q];
    let mut y = vec![0.0; q];
    let mut kept: Vec<usize> = vec![];
    for j in 0..q {
        let d = kept
            .iter()
            .fold(m[j * q + j], |d, &k| d - l[j * q + k] * l[j * q + k]);
        if !keep(j, d) {
            continue;
        }
        let djj = d.sqrt();
        l[j * q + j] = djj;
        for j2 in j + 1..q {
            let v = kept
                .iter()
                .fold(m[j2 * q + j], |v, &k| v - l[j2 * q + k] * l[j * q + k]);
            l[j2 * q + j] = v / djj;
        }
        y[j] = kept.iter().fold(h[j], |v, &k| v - l[j * q + k] * y[k]) / djj;
        kept.push(j);
    }
    (kept.iter().map(|&k| y[k] * y[k]).sum(), kept.len())
}

/// `v -= d_j·b_j` for the `K` basis columns `b` (their rows `rows`), in basis order for every
/// element as one column at a time would: each element read and written once per group, not once
/// per basis column (that load and store was most of pass two).
fn subtract<const K: usize>(
    v: &mut [f64],
    basis: &[Vec<f64>],
    d: &[f64],
    rows: &std::ops::Range<usize>,
) {
    let b: [&[f64]; K] = std::array::from_fn(|j| &basis[j][rows.clone()]);
    let d: [f64; K] = std::array::from_fn(|j| d[j]);
    for (i, vi) in v.iter_mut().enumerate() {
        for j in 0..K {
            *vi -= d[j] * b[j][i];
        }
    }
}

/// Σ x·y of one block (starting at a multiple of [`LANES`]) added onto the lanes.
fn add_products(acc: &mut Lanes, x: &[f64], y: &[f64]) {
    let y = &y[..x.len()];
    let (xs, ys) = (x.chunks_exact(LANES), y.chunks_exact(LANES));
    let (xt, yt) = (xs.remainder(), ys.remainder());
    for (xq, yq) in xs.zip(ys) {
        for l in 0..LANES {
            acc[l] += xq[l] * yq[l];
        }
    }
    for (l, (a, b)) in xt.iter().zip(yt).enumerate() {
        acc[l] += a * b;
    }
}

/// `K` basis vectors' products with the block `c` of one column (rows `rows`, starting at a
/// multiple of [`LANES`]), added onto their lanes.
fn dots<const K: usize>(
    acc: &mut [Lanes],
    basis: &[Vec<f64>],
    c: &[f64],
    rows: &std::ops::Range<usize>,
) {
    let b: [&[f64]; K] = std::array::from_fn(|j| &basis[j][rows.clone()]);
    let mut s: [Lanes; K] = std::array::from_fn(|j| acc[j]);
    let whole = c.len() / LANES * LANES;
    for i in (0..whole).step_by(LANES) {
        let cq = &c[i..i + LANES];
        for j in 0..K {
            let bq = &b[j][i..i + LANES];
            for l in 0..LANES {
                s[j][l] += bq[l] * cq[l];
            }
        }
    }
    for i in whole..c.len() {
        for j in 0..K {
            s[j][i - whole] += b[j][i] * c[i];
        }
    }
    acc[..K].copy_from_slice(&s);
}

#[cfg(test)]
mod tests {
    use super::super::{dot, orthonormalize, orthonormalize_gain};
    use super::projected_gain;

    fn col(n: usize, w: f64, p: f64) -> Vec<f64> {
        (0..n)
            .map(|i| (w * i as f64 + p).sin() + 1e-4 * i as f64)
            .collect()
    }

    /// The classical two-pass gain is the modified Gram–Schmidt gain to rounding, and keeps the
    /// same columns: basis sizes that leave every group remainder, two spans and a length that is
    /// not whole blocks, one and several columns, a column nearly in the span (≈1e-5 of its norm outside
    /// it), a column in the span of the basis, one in the span of the candidate's other columns,
    /// a zero column.
    #[test]
    fn classical_gains_are_the_modified_gram_schmidt_gains() {
        let n = super::super::spans::SPAN + 3 * super::BLOCK + 77;
        let raw: Vec<Vec<f64>> = std::iter::once(vec![1.0; n])
            .chain((0..6).map(|k| col(n, 0.001 * f64::from(k + 1), 0.2)))
            .collect();
        let full = orthonormalize(&[], raw, 2);
        let mut r = col(n, 0.05, 0.3);
        for c in &full {
            let d = dot(c, &r);
            r.iter_mut().zip(c).for_each(|(ri, ci)| *ri -= d * ci);
        }
        let rss0 = dot(&r, &r);
        let near: Vec<f64> = full[1]
            .iter()
            .zip(col(n, 0.2, 0.0))
            .map(|(b, x)| 50.0 * b + 1e-5 * x)
            .collect();
        let (a, b) = (col(n, 0.05, 0.0), col(n, 0.3, 0.5));
        let sum: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 2.0 * x - y).collect();
        let candidates: Vec<(Vec<Vec<f64>>, usize)> = vec![
            (vec![a.clone()], 1),
            (vec![near.clone()], 1),
            (vec![vec![3.0; n]], 0),
            (vec![vec![0.0; n]], 0),
            (vec![a.clone(), b.clone()], 2),
            (vec![a.clone(), vec![0.0; n], b.clone(), sum], 2),
            (vec![vec![3.0; n], near, col(n, 0.011, 0.4)], 2),
        ];
        for k in 0..=full.len() {
            let basis = &full[..k];
            for (i, (cols, kept)) in candidates.iter().enumerate() {
                let (g, q) = projected_gain(basis, cols, &r);
                let (u, want) = orthonormalize_gain(basis, cols.clone(), &r);
                assert_eq!(q, u.len(), "basis {k} candidate {i}: columns kept");
                // Without the intercept the constant column is kept by both.
                let constant = cols.iter().any(|c| c[0] == 3.0);
                assert_eq!(
                    q,
                    kept + usize::from(k == 0 && constant),
                    "basis {k} candidate {i}"
                );
                // Both are differences from r0's RSS: rounding is relative to it.
                assert!(
                    (g - want).abs() <= 1e-9 * want + 1e-13 * rss0,
                    "basis {k} candidate {i}: {g} against {want}"
                );
            }
        }
    }
}
