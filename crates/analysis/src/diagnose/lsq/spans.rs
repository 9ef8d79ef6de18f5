//! Row sums of the long-recording kernels ([`mod@super::gram`], [`super::cgs`]) over fixed spans of
//! rows run in parallel (rayon). A span's sums are kept as partial sums by row (lanes); the spans'
//! lanes are added in span order, so every sum is the same bits with any number of threads. These
//! kernels are called one candidate or one parameter at a time where little else runs beside them
//! (a peak's golden-section refinement, the joint refit's parameter searches): there a 10⁶-row sum
//! on one core left the other idle.

use std::ops::Range;

/// Rows per span: a multiple of every kernel's block, so spans split no block.
pub(super) const SPAN: usize = 1 << 16;

/// The lanes of every sum `f` returns for one span of `0..n`, added over the spans in order (one
/// empty span when `n` is 0, so the sums always have their length).
pub(super) fn sum_spans<const L: usize>(
    n: usize,
    f: impl Fn(Range<usize>) -> Vec<[f64; L]> + Sync,
) -> Vec<[f64; L]> {
    use rayon::prelude::*;
    let starts: Vec<usize> = (0..n.max(1)).step_by(SPAN).collect();
    add_in_order(
        starts
            .par_iter()
            .map(|&s| f(s..(s + SPAN).min(n)))
            .collect(),
    )
}

/// [`sum_spans`] over a column updated in place: `f` gets each span's first row and its part of
/// `c`.
pub(super) fn sum_spans_mut<const L: usize>(
    c: &mut [f64],
    f: impl Fn(usize, &mut [f64]) -> Vec<[f64; L]> + Sync,
) -> Vec<[f64; L]> {
    use rayon::prelude::*;
    if c.is_empty() {
        return f(0, c);
    }
    add_in_order(
        c.par_chunks_mut(SPAN)
            .enumerate()
            .map(|(k, part)| f(k * SPAN, part))
            .collect(),
    )
}

/// [`sum_spans`] with the spans run one after another on the calling thread, for an `f` that
/// carries state from span to span (a phasor rotated row by row); the same bits. Its callers run
/// several such sums side by side themselves.
pub(super) fn sum_spans_in_turn<const L: usize>(
    n: usize,
    mut f: impl FnMut(Range<usize>) -> Vec<[f64; L]>,
) -> Vec<[f64; L]> {
    add_in_order(
        (0..n.max(1))
            .step_by(SPAN)
            .map(|s| f(s..(s + SPAN).min(n)))
            .collect(),
    )
}

/// The spans' lanes added lane by lane, in span order.
fn add_in_order<const L: usize>(parts: Vec<Vec<[f64; L]>>) -> Vec<[f64; L]> {
    let mut parts = parts.into_iter();
    let mut acc = parts.next().unwrap_or_default();
    for part in parts {
        for (a, p) in acc.iter_mut().zip(part) {
            for l in 0..L {
                a[l] += p[l];
            }
        }
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::{SPAN, sum_spans, sum_spans_in_turn, sum_spans_mut};
    use crate::diagnose::test_pool as pool;

    /// The sums are the spans' sums added in span order, the same bits on one thread and on
    /// several, over a length that is not whole spans; an empty column still has its sums.
    #[test]
    fn span_sums_are_the_same_bits_with_any_number_of_threads() {
        let n = 3 * SPAN + 123;
        let x: Vec<f64> = (0..n)
            .map(|i| (i as f64 * 0.013).sin() * 1e3 + 0.1)
            .collect();
        let per_span = |rows: std::ops::Range<usize>| {
            let mut l = [0.0; 2];
            for i in rows {
                l[i % 2] += x[i] * x[i];
            }
            vec![l]
        };
        let mut want = [0.0; 2];
        for s in (0..n).step_by(SPAN) {
            let part = per_span(s..(s + SPAN).min(n))[0];
            want[0] += part[0];
            want[1] += part[1];
        }
        for threads in [1, 4] {
            let got = pool(threads).install(|| sum_spans(n, per_span));
            assert_eq!(
                got[0].map(f64::to_bits),
                want.map(f64::to_bits),
                "{threads} threads"
            );
            let mut c = x.clone();
            let got_mut = pool(threads).install(|| {
                sum_spans_mut(&mut c, |start, part| {
                    let mut l = [0.0; 2];
                    for (k, v) in part.iter_mut().enumerate() {
                        l[(start + k) % 2] += *v * *v;
                        *v = -*v;
                    }
                    vec![l]
                })
            });
            assert_eq!(got_mut[0].map(f64::to_bits), want.map(f64::to_bits));
            let mut spans_seen = 0;
            let in_turn = pool(threads).install(|| {
                sum_spans_in_turn(n, |rows| {
                    assert_eq!(rows.start, spans_seen * SPAN, "spans in row order");
                    spans_seen += 1;
                    per_span(rows)
                })
            });
            assert_eq!(in_turn[0].map(f64::to_bits), want.map(f64::to_bits));
            assert!(
                c.iter().zip(&x).all(|(a, b)| *a == -*b),
                "every row updated once"
            );
        }
        assert_eq!(sum_spans(0, |r| vec![[r.len() as f64; 2]]), vec![[0.0; 2]]);
        assert_eq!(
            sum_spans_in_turn(0, |r| vec![[r.len() as f64; 2]]),
            vec![[0.0; 2]]
        );
        assert_eq!(
            sum_spans_mut(&mut [], |_, p| vec![[p.len() as f64; 2]]),
            vec![[0.0; 2]]
        );
    }
}
