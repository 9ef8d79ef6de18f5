//! Held-out sums over blocks of rows: leave-one-block-out ([`cv_rss`]) and forward, rolling-origin
//! ([`forward_rss`]) validation of a least-squares fit. The blocks' Gram matrices are summed in
//! two passes over the rows (half of the blocks each), independent of each other and of the whole
//! record's, so they run side by side (rayon); every sum is still taken alone in row order: the
//! same bits with any number of threads. Units are the caller's (µm² for the diagnosis'
//! residuals).

use nalgebra::{DMatrix, DVector};

use super::{RowSums, gram, pinv_solve};

/// Held-out RSS: for each block, fit on the other blocks and predict this one. The whole
/// record's sums and each half of the blocks' sums are independent passes over the rows, run
/// side by side (rayon); each sum is still taken alone in row order, so the result is the same
/// bits with any number of threads (at 10⁶ rows, run in turn, they were the largest part of the
/// work a diagnosis did on one thread while the other idled: docs/performance.md).
pub fn cv_rss(cols: &[&[f64]], r: &[f64], block: &[usize], n_blocks: usize) -> f64 {
    let n = r.len();
    let ((g, h), per) = rayon::join(
        || gram(cols, r, 0..n),
        || each_block_gram(cols, r, block, n_blocks),
    );
    let betas: Vec<DVector<f64>> = per
        .iter()
        .map(|(gb, hb)| pinv_solve(&(&g - gb), &(&h - hb)).0)
        .collect();
    (0..n)
        .map(|i| {
            let b = &betas[block[i]];
            (r[i]
                - cols
                    .iter()
                    .enumerate()
                    .map(|(a, c)| b[a] * c[i])
                    .sum::<f64>())
            .powi(2)
        })
        .sum()
}

/// The Gram matrix and right-hand side of each of the `n_blocks` blocks (`block` per row), the
/// two halves of the blocks side by side (rayon): each sum alone in row order, the same bits
/// with any number of threads.
fn each_block_gram(
    cols: &[&[f64]],
    r: &[f64],
    block: &[usize],
    n_blocks: usize,
) -> Vec<(DMatrix<f64>, DVector<f64>)> {
    let half = n_blocks / 2;
    let (mut per, upper) = rayon::join(
        || block_grams(cols, r, block, 0..half),
        || block_grams(cols, r, block, half..n_blocks),
    );
    per.extend(upper);
    per
}

/// The Gram matrix and right-hand side of each block in `blocks` (rows of other blocks
/// skipped), each sum in row order, as [`fn@gram`] sums them.
fn block_grams(
    cols: &[&[f64]],
    r: &[f64],
    block: &[usize],
    blocks: std::ops::Range<usize>,
) -> Vec<(DMatrix<f64>, DVector<f64>)> {
    let p = cols.len();
    let mut per: Vec<RowSums> = blocks.clone().map(|_| RowSums::new(p)).collect();
    for (i, &k) in block.iter().enumerate().take(r.len()) {
        if blocks.contains(&k) {
            per[k - blocks.start].add_row(|a| cols[a][i], r[i]);
        }
    }
    per.into_iter().map(RowSums::into_gram).collect()
}

/// Forward (rolling-origin) validation over time-ordered blocks 0..n_blocks: block k is predicted
/// by the fit on blocks 0..k only, for k ≥ 1, so nothing is judged on data earlier than what
/// chose it. Returns (RSS over the predicted rows, number of predicted rows).
pub fn forward_rss(cols: &[&[f64]], r: &[f64], block: &[usize], n_blocks: usize) -> (f64, usize) {
    forward_rss_pred(cols, cols, r, block, n_blocks)
}

/// [`forward_rss`] with the gains fitted on `cols` and block k predicted from `pred` (the same
/// regressors as a NEW recording starting at block k would compute them: lag states restarted
/// there, see `select::restarted`). `pred` has the layout of `cols`.
pub fn forward_rss_pred(
    cols: &[&[f64]],
    pred: &[&[f64]],
    r: &[f64],
    block: &[usize],
    n_blocks: usize,
) -> (f64, usize) {
    forward_block_rss(cols, pred, r, block, n_blocks)
        .iter()
        .fold((0.0, 0), |(s, m), b| (s + b.0, m + b.1))
}

/// Per block: (RSS, rows) of block k predicted by gains fitted on `cols` over blocks before k
/// (block 0 is never predicted: (0, 0)); prediction from `pred` as in [`forward_rss_pred`].
pub fn forward_block_rss(
    cols: &[&[f64]],
    pred: &[&[f64]],
    r: &[f64],
    block: &[usize],
    n_blocks: usize,
) -> Vec<(f64, usize)> {
    let p = cols.len();
    let per = each_block_gram(cols, r, block, n_blocks);
    // Coefficients fitted on blocks before k, per k.
    let mut betas: Vec<Option<DVector<f64>>> = vec![None; n_blocks];
    let (mut g, mut h) = (DMatrix::zeros(p, p), DVector::zeros(p));
    for k in 0..n_blocks {
        if k > 0 {
            betas[k] = Some(pinv_solve(&g, &h).0);
        }
        g += &per[k].0;
        h += &per[k].1;
    }
    let mut out = vec![(0.0, 0usize); n_blocks];
    for i in 0..r.len() {
        if let Some(b) = &betas[block[i]] {
            let fit: f64 = (0..p).map(|a| b[a] * pred[a][i]).sum();
            out[block[i]].0 += (r[i] - fit).powi(2);
            out[block[i]].1 += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_validation_predicts_each_block_from_earlier_blocks_only() {
        // r = 2·x in blocks 0–1 and 5·x in block 2: the forward fit of block 2 comes from blocks
        // 0–1 only (slope 2), so its error is 3·x there; block 0 is never predicted.
        let n = 30;
        let x: Vec<f64> = (0..n).map(|i| 1.0 + i as f64).collect();
        let block: Vec<usize> = (0..n).map(|i| i / 10).collect();
        let r: Vec<f64> = (0..n)
            .map(|i| if block[i] < 2 { 2.0 } else { 5.0 } * x[i])
            .collect();
        let (rss, m) = forward_rss(&[&x], &r, &block, 3);
        assert_eq!(m, 20);
        let want: f64 = (20..30).map(|i| (3.0 * x[i]).powi(2)).sum();
        assert!((rss - want).abs() < 1e-6 * want, "{rss} vs {want}");
    }

    /// The per-block sums before they ran side by side: every (a, b) summed in row order.
    fn serial_block_grams(
        cols: &[&[f64]],
        r: &[f64],
        block: &[usize],
        n_blocks: usize,
    ) -> Vec<(DMatrix<f64>, DVector<f64>)> {
        let p = cols.len();
        let mut per = vec![(DMatrix::zeros(p, p), DVector::zeros(p)); n_blocks];
        for i in 0..r.len() {
            let (gb, hb) = &mut per[block[i]];
            for a in 0..p {
                hb[a] += cols[a][i] * r[i];
                for b in 0..p {
                    gb[(a, b)] += cols[a][i] * cols[b][i];
                }
            }
        }
        per
    }

    /// Interleaved blocks (as position cells give), an odd count, on one thread and on three:
    /// the block sums are the serial ones bit for bit, and so are both held-out RSS.
    #[test]
    fn block_sums_side_by_side_are_the_serial_sums_bit_for_bit() {
        let n = 4001;
        let col = |w: f64| -> Vec<f64> { (0..n).map(|i| (w * i as f64).sin() * 1e3).collect() };
        let (x1, x2, x3) = (col(0.013), col(0.17), col(2.3));
        let ones = vec![1.0; n];
        let cols: Vec<&[f64]> = vec![&ones, &x1, &x2, &x3];
        let r: Vec<f64> = (0..n)
            .map(|i| 3.0 * x1[i] - 0.5 * x3[i] + (1.7 * i as f64).cos())
            .collect();
        let n_blocks = 7;
        let block: Vec<usize> = (0..n).map(|i| (i * 31 + i / 97) % n_blocks).collect();
        let bits = |per: &[(DMatrix<f64>, DVector<f64>)]| -> Vec<u64> {
            per.iter()
                .flat_map(|(g, h)| g.iter().chain(h.iter()).map(|v| v.to_bits()))
                .collect()
        };
        let want = bits(&serial_block_grams(&cols, &r, &block, n_blocks));
        let ordered: Vec<usize> = (0..n).map(|i| i * n_blocks / n).collect();
        let mut seen = vec![];
        for threads in [1, 3] {
            let pool = crate::diagnose::test_pool(threads);
            pool.install(|| {
                let got = bits(&each_block_gram(&cols, &r, &block, n_blocks));
                assert_eq!(got, want, "block sums on {threads} threads");
                seen.push((
                    cv_rss(&cols, &r, &block, n_blocks).to_bits(),
                    forward_rss(&cols, &r, &ordered, n_blocks).0.to_bits(),
                ));
            });
        }
        assert_eq!(seen[0], seen[1], "held-out RSS on one thread and on three");
        assert!(f64::from_bits(seen[0].0) > 0.0 && f64::from_bits(seen[0].1) > 0.0);
    }
}
