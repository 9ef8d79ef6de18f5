//! The row sums behind [`super::gram_gain`]: XᵀX, BᵀX and Xᵀr0 of a candidate's columns X, the
//! orthonormal basis B and the residual r0. Every sum is accumulated over the rows in row order,
//! each product as in one loop over the rows, so the sums are the same bits; what differs is that
//! several sums are carried in registers at once (a loop over the rows indexing every column and
//! every sum through the heap was most of a 10⁶-row diagnosis' screening), over blocks of rows
//! that stay in cache while each group of left-hand columns is run over them.

/// Rows per block: the candidate's columns of one block stay in cache while every group of
/// left-hand columns (r0, X, B) is run over them.
const BLOCK: usize = 2048;

/// Left-hand columns per pass over a block: with two candidate columns, eight independent sums.
const GROUP: usize = 4;

/// The sums of [`super::gram_gain`]: XᵀX (row-major q×q, lower triangle filled), BᵀX (row k of
/// the basis: entries k·q..k·q+q) and Xᵀr0.
pub(super) fn sums(
    basis: &[Vec<f64>],
    cols: &[Vec<f64>],
    r0: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    match cols.len() {
        2 => sums_q::<2>(basis, cols, r0),
        4 => sums_q::<4>(basis, cols, r0),
        _ => sums_any(basis, cols, r0),
    }
}

/// [`sums`] for `Q` candidate columns: every left-hand column y (r0, then each column of X, then
/// each of B) gets Σ_i y_i·x_a,i for every a, carried across the blocks.
fn sums_q<const Q: usize>(
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
    let mut acc = vec![[0.0; Q]; ys.len()];
    for start in (0..n).step_by(BLOCK) {
        let rows = start..(start + BLOCK).min(n);
        let x: [&[f64]; Q] = std::array::from_fn(|a| &xs[a][rows.clone()]);
        for (acc, ys) in acc.chunks_mut(GROUP).zip(ys.chunks(GROUP)) {
            match ys.len() {
                1 => group::<Q, 1>(acc, ys, x, &rows),
                2 => group::<Q, 2>(acc, ys, x, &rows),
                3 => group::<Q, 3>(acc, ys, x, &rows),
                _ => group::<Q, GROUP>(acc, ys, x, &rows),
            }
        }
    }
    let (b, q) = (basis.len(), Q);
    let mut g = vec![0.0; q * q];
    for a in 0..q {
        g[a * q..=a * q + a].copy_from_slice(&acc[1 + a][..=a]);
    }
    let cb = acc[1 + q..1 + q + b].concat();
    (g, cb, acc[0].to_vec())
}

/// `K` left-hand columns' sums against the `Q` candidate columns `x` over one block of rows,
/// added in row order onto `acc`.
fn group<const Q: usize, const K: usize>(
    acc: &mut [[f64; Q]],
    ys: &[&[f64]],
    x: [&[f64]; Q],
    rows: &std::ops::Range<usize>,
) {
    let len = rows.len();
    let y: [&[f64]; K] = std::array::from_fn(|j| &ys[j][rows.clone()]);
    let mut s: [[f64; Q]; K] = std::array::from_fn(|j| acc[j]);
    for i in 0..len {
        let xi: [f64; Q] = std::array::from_fn(|a| x[a][i]);
        for j in 0..K {
            let yj = y[j][i];
            for a in 0..Q {
                s[j][a] += yj * xi[a];
            }
        }
    }
    acc[..K].copy_from_slice(&s);
}

/// [`sums`] for any number of candidate columns: one loop over the rows.
fn sums_any(basis: &[Vec<f64>], cols: &[Vec<f64>], r0: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (q, b) = (cols.len(), basis.len());
    let mut g = vec![0.0; q * q];
    let mut cb = vec![0.0; b * q];
    let mut h = vec![0.0; q];
    for (i, ri) in r0.iter().enumerate() {
        for a in 0..q {
            let xa = cols[a][i];
            h[a] += xa * ri;
            for a2 in 0..=a {
                g[a * q + a2] += xa * cols[a2][i];
            }
            for k in 0..b {
                cb[k * q + a] += basis[k][i] * xa;
            }
        }
    }
    (g, cb, h)
}

#[cfg(test)]
mod tests {
    /// The blocked, grouped sums are the one-loop sums bit for bit, for two and four columns and
    /// basis sizes that leave every group remainder, over a length that is not a whole block.
    #[test]
    fn grouped_sums_are_the_one_loop_sums_bit_for_bit() {
        let n = 3 * super::BLOCK + 77;
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
