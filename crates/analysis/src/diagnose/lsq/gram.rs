//! The row sums behind [`super::gram_gain`]: XᵀX, BᵀX and Xᵀr0 of a candidate's columns X, the
//! orthonormal basis B and the residual r0. Every sum is accumulated over each span of rows
//! ([`super::spans`]) in row order in two partial sums (even and odd rows), as one loop over the
//! rows would, so the blocked sums are that loop's bits whatever the blocks; what differs is that
//! several sums are carried in registers at once (a loop over the rows indexing every column and
//! every sum through the heap was most of a 10⁶-row diagnosis' screening), over blocks of rows
//! that stay in cache while each group of left-hand columns is run over them.

use super::spans::{sum_spans, sum_spans_in_turn};

/// Rows per block: the candidate's columns of one block stay in cache while every group of
/// left-hand columns (r0, X, B) is run over them. Even, so a block starts on lane 0; a divisor of
/// [`super::spans::SPAN`].
const BLOCK: usize = 2048;

/// Partial sums per product: row i is added to lane i mod 2, the lanes added at the end. With one
/// chain per product a row waited for the previous row's additions (the sums were bound by the
/// addition latency); two rows side by side are one two-wide multiply and add.
const LANES: usize = 2;

type Lanes = [f64; LANES];

/// The sums of [`super::gram_gain`]: XᵀX (row-major q×q, lower triangle filled), BᵀX (row k of
/// the basis: entries k·q..k·q+q) and Xᵀr0.
pub(super) fn sums(
    basis: &[Vec<f64>],
    cols: &[Vec<f64>],
    r0: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    // Left-hand columns per pass over a block: eight two-lane sums either way (what the sixteen
    // vector registers of baseline x86-64 hold beside the operands).
    match cols.len() {
        2 => sums_q::<2, 4>(basis, cols, r0),
        4 => sums_q::<4, 2>(basis, cols, r0),
        _ => sums_any(basis, cols, r0),
    }
}

/// [`sums`] for `Q` candidate columns, `G` left-hand columns per pass: every left-hand column y
/// (r0, then each column of X, then each of B) gets Σ_i y_i·x_a,i for every a.
fn sums_q<const Q: usize, const G: usize>(
    basis: &[Vec<f64>],
    cols: &[Vec<f64>],
    r0: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let n = r0.len();
    let xs: [&[f64]; Q] = std::array::from_fn(|a| &cols[a][..n]);
    let ys: Vec<&[f64]> = std::iter::once(r0)
        .chain(xs.iter().copied())
        .chain(basis.iter().map(|b| &b[..n]))
        .collect();
    // Per span: the lanes of every (y, a) sum, y-major.
    let lanes = sum_spans(n, |span| {
        let mut acc = vec![[[0.0; LANES]; Q]; ys.len()];
        let mut yb: Vec<&[f64]> = Vec::with_capacity(ys.len());
        for start in span.clone().step_by(BLOCK) {
            let rows = start..(start + BLOCK).min(span.end);
            let x: [&[f64]; Q] = std::array::from_fn(|a| &xs[a][rows.clone()]);
            yb.clear();
            yb.extend(ys.iter().map(|y| &y[rows.clone()]));
            block_sums::<Q, G>(&mut acc, &yb, x);
        }
        acc.concat()
    });
    assemble::<Q>(&lanes, basis.len())
}

/// One block's sums of every left-hand column `ys` (sliced to the block) against `x`, `G` at a
/// time, onto `acc` (one entry per left-hand column).
fn block_sums<const Q: usize, const G: usize>(
    acc: &mut [[Lanes; Q]],
    ys: &[&[f64]],
    x: [&[f64]; Q],
) {
    for (acc, ys) in acc.chunks_mut(G).zip(ys.chunks(G)) {
        match ys.len() {
            1 => group::<Q, 1>(acc, ys, x),
            2 => group::<Q, 2>(acc, ys, x),
            3 => group::<Q, 3>(acc, ys, x),
            _ => group::<Q, 4>(acc, ys, x),
        }
    }
}

/// XᵀX (lower triangle), BᵀX and Xᵀr0 from the lanes of every (y, a) sum, y-major (y: r0, the
/// `Q` columns, the `b` basis columns).
fn assemble<const Q: usize>(lanes: &[Lanes], b: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let acc: Vec<f64> = lanes.iter().map(total).collect();
    let q = Q;
    let mut g = vec![0.0; q * q];
    for a in 0..q {
        g[a * q..=a * q + a].copy_from_slice(&acc[(1 + a) * q..=(1 + a) * q + a]);
    }
    let cb = acc[(1 + q) * q..(1 + q + b) * q].to_vec();
    (g, cb, acc[..q].to_vec())
}

/// Rows per block of [`pair_sums_sweep`]: every period's two columns of a block (32 periods:
/// 256 KB) and the block of r0 and the basis stay in cache. Blocks do not change the sums' bits
/// (only the spans do).
const SWEEP_BLOCK: usize = 512;

/// [`sums`] of `periods` sin/cos pairs at once, the same bits as one call per pair: `fill(rows,
/// cols)` writes each pair's two columns over `rows` (from 0 in `cols[p]`), block by block, so
/// the pairs are never stored whole and r0 and the basis are read once for all of them (one
/// call per pair read them once per pair: the cyclic screening of a 10⁶-row recording was
/// bound by that). The spans run in turn ([`sum_spans_in_turn`]: `fill` carries its phasors from
/// block to block, and the caller runs sweeps side by side).
pub(super) fn pair_sums_sweep(
    basis: &[Vec<f64>],
    r0: &[f64],
    periods: usize,
    mut fill: impl FnMut(std::ops::Range<usize>, &mut [[Vec<f64>; 2]]),
) -> Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let mut cols = pair_blocks(periods);
    sum_spans_in_turn(r0.len(), |span| {
        span_pair_sums(basis, r0, span, &mut cols, &mut fill)
    })
    .chunks(pair_ys(basis) * 2)
    .map(|l| assemble::<2>(l, basis.len()))
    .collect()
}

/// [`sums`] of one sin/cos pair whose row i is `phasors[·][idx[i]]` (a value per distinct
/// position), the same bits, gathered block by block instead of into two whole columns (at 10⁶
/// rows, writing and reading back 16 MB per call of a period's refinement); spans in parallel.
pub(super) fn pair_sums_gathered(
    basis: &[Vec<f64>],
    r0: &[f64],
    phasors: [&[f64]; 2],
    idx: &[u32],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let lanes = sum_spans(r0.len(), |span| {
        let mut gather = |rows: std::ops::Range<usize>, cols: &mut [[Vec<f64>; 2]]| {
            for (q, col) in cols[0].iter_mut().enumerate() {
                for (o, &k) in col.iter_mut().zip(&idx[rows.clone()]) {
                    *o = phasors[q][k as usize];
                }
            }
        };
        span_pair_sums(basis, r0, span, &mut pair_blocks(1), &mut gather)
    });
    assemble::<2>(&lanes, basis.len())
}

/// Left-hand columns of a pair's sums: r0, the pair, the basis.
fn pair_ys(basis: &[Vec<f64>]) -> usize {
    3 + basis.len()
}

/// One block of each of `periods` pairs' two columns.
fn pair_blocks(periods: usize) -> Vec<[Vec<f64>; 2]> {
    (0..periods)
        .map(|_| [vec![0.0; SWEEP_BLOCK], vec![0.0; SWEEP_BLOCK]])
        .collect()
}

/// The lanes of every pair's sums over one span (pair-major, then y-major), the pairs written
/// block by block into `cols` by `fill`.
fn span_pair_sums(
    basis: &[Vec<f64>],
    r0: &[f64],
    span: std::ops::Range<usize>,
    cols: &mut [[Vec<f64>; 2]],
    fill: &mut impl FnMut(std::ops::Range<usize>, &mut [[Vec<f64>; 2]]),
) -> Vec<Lanes> {
    const Q: usize = 2;
    let ny = pair_ys(basis);
    let mut acc = vec![vec![[[0.0; LANES]; Q]; ny]; cols.len()];
    for start in span.clone().step_by(SWEEP_BLOCK) {
        let rows = start..(start + SWEEP_BLOCK).min(span.end);
        let len = rows.len();
        fill(rows.clone(), cols);
        let mut yb: Vec<&[f64]> = Vec::with_capacity(ny);
        for (acc, pair) in acc.iter_mut().zip(&*cols) {
            let x: [&[f64]; Q] = [&pair[0][..len], &pair[1][..len]];
            yb.clear();
            yb.push(&r0[rows.clone()]);
            yb.extend(x);
            yb.extend(basis.iter().map(|b| &b[rows.clone()]));
            block_sums::<Q, 4>(acc, &yb, x);
        }
    }
    acc.concat().concat()
}

fn total(l: &Lanes) -> f64 {
    l[0] + l[1]
}

/// `K` left-hand columns' sums against the `Q` candidate columns `x` over one block of rows,
/// each row onto its lane of `acc`.
fn group<const Q: usize, const K: usize>(acc: &mut [[Lanes; Q]], ys: &[&[f64]], x: [&[f64]; Q]) {
    let len = x[0].len();
    let y: [&[f64]; K] = std::array::from_fn(|j| &ys[j][..len]);
    let mut s: [[Lanes; Q]; K] = std::array::from_fn(|j| acc[j]);
    let whole = len / LANES * LANES;
    for i in (0..whole).step_by(LANES) {
        let xi: [Lanes; Q] = std::array::from_fn(|a| std::array::from_fn(|l| x[a][i + l]));
        for j in 0..K {
            let yj: Lanes = std::array::from_fn(|l| y[j][i + l]);
            for a in 0..Q {
                for l in 0..LANES {
                    s[j][a][l] += yj[l] * xi[a][l];
                }
            }
        }
    }
    for i in whole..len {
        for j in 0..K {
            for a in 0..Q {
                s[j][a][i - whole] += y[j][i] * x[a][i];
            }
        }
    }
    acc[..K].copy_from_slice(&s);
}

/// [`sums`] for any number of candidate columns: one loop over each span's rows, the same lanes.
fn sums_any(basis: &[Vec<f64>], cols: &[Vec<f64>], r0: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (q, b) = (cols.len(), basis.len());
    // Per span: XᵀX (q·q), then BᵀX (b·q), then Xᵀr0 (q).
    let lanes = sum_spans(r0.len(), |span| {
        let mut acc = vec![[0.0; LANES]; q * q + b * q + q];
        let (g, rest) = acc.split_at_mut(q * q);
        let (cb, h) = rest.split_at_mut(b * q);
        for i in span {
            let l = i % LANES;
            for a in 0..q {
                let xa = cols[a][i];
                h[a][l] += xa * r0[i];
                for a2 in 0..=a {
                    g[a * q + a2][l] += xa * cols[a2][i];
                }
                for k in 0..b {
                    cb[k * q + a][l] += basis[k][i] * xa;
                }
            }
        }
        acc
    });
    let acc: Vec<f64> = lanes.iter().map(total).collect();
    let (g, rest) = acc.split_at(q * q);
    let (cb, h) = rest.split_at(b * q);
    (g.to_vec(), cb.to_vec(), h.to_vec())
}

#[cfg(test)]
mod tests {
    /// The blocked, grouped sums are the one-loop sums bit for bit, for two and four columns and
    /// basis sizes that leave every group remainder, over two spans and a length that is not a
    /// whole block.
    #[test]
    fn grouped_sums_are_the_one_loop_sums_bit_for_bit() {
        let n = super::super::spans::SPAN + 3 * super::BLOCK + 77;
        let col = |w: f64, p: f64| -> Vec<f64> {
            (0..n)
                .map(|i| (w * i as f64 + p).sin() * (1.0 + 1e-3 * i as f64))
                .collect()
        };
        let r0 = col(0.013, 0.4);
        for q in [2usize, 4] {
            let cols: Vec<Vec<f64>> = (0..q).map(|a| col(0.07 + 0.01 * a as f64, 1.0)).collect();
            for b in 0..7u8 {
                let basis: Vec<Vec<f64>> = (0..b).map(|k| col(0.002 * f64::from(k), 0.3)).collect();
                let want = super::sums_any(&basis, &cols, &r0);
                let got = super::sums(&basis, &cols, &r0);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got.0), bits(&want.0), "XᵀX q {q} b {b}");
                assert_eq!(bits(&got.1), bits(&want.1), "BᵀX q {q} b {b}");
                assert_eq!(bits(&got.2), bits(&want.2), "Xᵀr0 q {q} b {b}");
            }
        }
    }
}
