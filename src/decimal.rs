//! Fixed-point decimal text for the CSV writers (`retrocomp eval` writes µm with 6 decimals, i.e.
//! 1 pm), byte for byte what `format!("{v:.6}")` prints, without `core::fmt`'s exact-rounding path
//! for the common case and without allocating.
//!
//! Why: `eval` writes ≈ 13 numbers a row; on 10⁶ rows `core::fmt` fixed-precision formatting was
//! about half of the command's CPU. The fast path scales by 10⁶ and rounds in f64, which is exact
//! except when the scaled value lies within rounding error of a half-way point; those (and huge or
//! non-finite values) take `core::fmt`. Unit tests check equality with `format!` on edge cases and
//! on a million random values across magnitudes.

use std::io::Write as _;

/// Append `v` with exactly six decimals, as `format!("{v:.6}")` would.
pub fn push_fixed6(out: &mut Vec<u8>, v: f64) {
    let scaled = v * 1e6;
    // |scaled| < 2^40 keeps the product's error below 2^-12 of a unit, far from the ±1e-3 band
    // around a half-way point that goes to the exact path.
    if scaled.abs() < 1_099_511_627_776.0 {
        let frac = (scaled - scaled.trunc()).abs();
        if (frac - 0.5).abs() > 1e-3 {
            let units = scaled.abs().round() as u64;
            if v.is_sign_negative() {
                out.push(b'-');
            }
            let mut buf = itoa::Buffer::new();
            out.extend_from_slice(buf.format(units / 1_000_000).as_bytes());
            out.push(b'.');
            let frac = buf.format(units % 1_000_000 + 1_000_000).as_bytes();
            out.extend_from_slice(&frac[1..]);
            return;
        }
    }
    // Writing into a Vec cannot fail.
    let _ = write!(out, "{v:.6}");
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn same(v: f64) {
        let mut out = Vec::new();
        push_fixed6(&mut out, v);
        assert_eq!(
            std::str::from_utf8(&out).unwrap(),
            format!("{v:.6}"),
            "{v:e}"
        );
    }

    #[test]
    fn edge_cases_print_as_core_fmt_does() {
        for v in [
            0.0,
            -0.0,
            1e-9,
            -1e-9,
            0.5e-6,
            -0.5e-6,
            1.5e-6,
            2.5e-6,
            0.0000005,
            0.0000015,
            0.1234565,
            -0.1234565,
            1.0,
            -1.0,
            999_999.999_999_5,
            1.0995e6,
            1.2e9,
            -3.7e12,
            f64::MAX,
            f64::MIN_POSITIVE,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            same(v);
        }
    }

    #[test]
    fn random_values_across_magnitudes_print_as_core_fmt_does() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..1_000_000 {
            let mag = 10f64.powi(rng.random_range(-8..8));
            let v = rng.random_range(-1.0..1.0) * mag;
            same(v);
            // Values on the 7th decimal's half-way grid are the hard ones.
            same((v * 1e7).round() / 1e7);
        }
    }
}
