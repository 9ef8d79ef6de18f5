//! Float → count and index conversions of the analysis code and of hil-sim, in one place. Each
//! rounds as its name says and saturates as Rust's `as` does (NaN → 0; negatives → 0 for the
//! unsigned ones; beyond the type → its minimum or maximum): the right answer for a count, rank or
//! bin of a non-negative quantity, whose callers then bound it by the length they index, and for
//! a simulated count (encoder, register LSBs) whose physics keeps it far inside `i64`.

/// `x` rounded toward zero as a count or index (0 for a negative or NaN `x`).
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "saturating by design (module comment): the caller bounds the result"
)]
pub fn trunc_usize(x: f64) -> usize {
    x as usize
}

/// ⌈x⌉ as a count (0 for a negative or NaN `x`).
pub fn ceil_usize(x: f64) -> usize {
    trunc_usize(x.ceil())
}

/// `x` rounded half away from zero as a count or index (0 for a negative or NaN `x`).
pub fn round_usize(x: f64) -> usize {
    trunc_usize(x.round())
}

/// `x` rounded toward zero as an unsigned count (0 for a negative or NaN `x`).
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "saturating by design (module comment)"
)]
pub fn trunc_u64(x: f64) -> u64 {
    x as u64
}

/// `x` rounded half away from zero as an unsigned count (0 for a negative or NaN `x`).
pub fn round_u64(x: f64) -> u64 {
    trunc_u64(x.round())
}

/// `x` rounded toward zero as a signed count (0 for NaN, saturating at `i64`'s ends).
#[allow(
    clippy::cast_possible_truncation,
    reason = "saturating by design (module comment)"
)]
pub fn trunc_i64(x: f64) -> i64 {
    x as i64
}

/// `x` rounded half away from zero as a signed count (0 for NaN, saturating at `i64`'s ends).
pub fn round_i64(x: f64) -> i64 {
    trunc_i64(x.round())
}

/// The nearest-rank index of quantile `p` (0 … 1) among `n ≥ 1` sorted values.
pub fn rank(n: usize, p: f64) -> usize {
    round_usize((n - 1) as f64 * p).min(n - 1)
}

/// Which of `bins` equal bins over [`lo`, `hi`] (`hi > lo`) holds `x`; `hi` itself is in the last.
pub fn bin(x: f64, lo: f64, hi: f64, bins: usize) -> usize {
    trunc_usize((x - lo) / (hi - lo) * bins as f64).min(bins - 1)
}

/// A pixel size (plotters' `u32`) as a drawing coordinate (`i32`): figures are a few thousand
/// pixels, so this saturates only on sizes no figure has.
pub fn px(size: u32) -> i32 {
    i32::try_from(size).unwrap_or(i32::MAX)
}

/// A small count (a line or panel index) as a drawing coordinate factor, saturating.
pub fn px_count(k: usize) -> i32 {
    i32::try_from(k).unwrap_or(i32::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_saturate_and_bound() {
        assert_eq!(trunc_usize(2.9), 2);
        assert_eq!(trunc_usize(-3.0), 0);
        assert_eq!(trunc_usize(f64::NAN), 0);
        assert_eq!(ceil_usize(2.1), 3);
        assert_eq!(round_usize(2.5), 3);
        assert_eq!(trunc_u64(-0.5), 0);
        assert_eq!(round_u64(2.5), 3);
        assert_eq!(trunc_i64(-2.9), -2);
        assert_eq!(round_i64(-2.5), -3);
        assert_eq!(round_i64(1e300), i64::MAX);
        assert_eq!(round_i64(f64::NAN), 0);
        assert_eq!(rank(11, 0.5), 5);
        assert_eq!(rank(11, 1.5), 10);
        assert_eq!(bin(10.0, 0.0, 10.0, 4), 3);
        assert_eq!(bin(2.6, 0.0, 10.0, 4), 1);
    }
}
