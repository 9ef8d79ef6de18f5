//! Decimal text for the CSV writers, without allocating and without `core::fmt`'s slow paths:
//! [`push_fixed6`] (`retrocomp eval` writes µm with 6 decimals, i.e. 1 pm) is byte for byte what
//! `format!("{v:.6}")` prints; [`push_shortest`] (the recording writers: the shortest text that
//! parses back to the same value) is byte for byte what `format!("{v}")` prints.
//!
//! Why: `eval` writes ≈ 13 numbers a row; on 10⁶ rows `core::fmt` fixed-precision formatting was
//! about half of the command's CPU. The fast path scales by 10⁶ and rounds in f64, which is exact
//! except when the scaled value lies within rounding error of a half-way point; those (and huge or
//! non-finite values) take `core::fmt`. Unit tests check equality with `format!` on edge cases and
//! on a million random values across magnitudes.

use std::io::Write as _;

/// Append `v` with exactly six decimals, as `format!("{v:.6}")` would.
pub fn push_fixed6(out: &mut Vec<u8>, v: f64) {
    let scaled = (v * 1e6).abs();
    // |scaled| < 2^40 keeps the product's error below 2^-12 of a unit, far from the ±1e-3 band
    // around a half-way point that goes to the exact path. In that range the integer conversion is
    // `trunc` exactly, and inline (`f64::trunc`/`round` are calls into libm without SSE4.1).
    if scaled < 1_099_511_627_776.0 {
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "0 ≤ scaled < 2⁴⁰ (abs, checked above): the conversion is the exact trunc"
        )]
        let whole = scaled as u64;
        let frac = scaled - whole as f64;
        if (frac - 0.5).abs() > 1e-3 {
            let units = whole + u64::from(frac > 0.5);
            if v.is_sign_negative() {
                out.push(b'-');
            }
            let mut buf = itoa::Buffer::new();
            out.extend_from_slice(buf.format(units / 1_000_000).as_bytes());
            out.push(b'.');
            push_6_digits(out, (units % 1_000_000) as u32);
            return;
        }
    }
    // Writing into a Vec cannot fail.
    let _ = write!(out, "{v:.6}");
}

/// Append `n` < 10⁶ as exactly six digits (leading zeros kept), two at a time.
fn push_6_digits(out: &mut Vec<u8>, n: u32) {
    const PAIRS: &[u8; 200] = b"0001020304050607080910111213141516171819\
        2021222324252627282930313233343536373839\
        4041424344454647484950515253545556575859\
        6061626364656667686970717273747576777879\
        8081828384858687888990919293949596979899";
    let pair = |k: u32| {
        let k = 2 * k as usize;
        [PAIRS[k], PAIRS[k + 1]]
    };
    let [a, b] = pair(n / 10_000);
    let [c, d] = pair(n / 100 % 100);
    let [e, f] = pair(n % 100);
    out.extend_from_slice(&[a, b, c, d, e, f]);
}

/// Append `v` as `format!("{v}")` would: the shortest digits that parse back to the same `f64`,
/// laid out without an exponent (`1`, `0.0000001`, `100000000000000000000`, `-0`, `NaN`, `inf`).
///
/// Why `ryu`: its shortest digits are `core::fmt`'s (both pick the shortest string that round-trips,
/// the nearest one if several) at a fraction of the cost, except on exact ties, which only values
/// with a short exact expansion can hit and which go to `core::fmt`; its layout (`1.0`, `1e-7`)
/// differs, so the digits and decimal exponent are read back from its text and laid out as
/// `core::fmt` does. Checked against `format!` on edge cases, ties and ≥ 10⁶ random values and bit
/// patterns below.
pub fn push_shortest(out: &mut Vec<u8>, v: f64) {
    // v = m·2^e exactly. When its exact decimal expansion is short (≤ 18 significant digits: only
    // if e ≥ −26 once m's trailing zero bits are moved into e, as 5^26 alone has 19 digits), v can
    // lie exactly half-way between the two nearest shortest candidates; ryu breaks that tie to
    // even, core::fmt upwards (2^50 + 0.25 differs), so such values, zero and non-finite ones
    // take core::fmt. Recorded measurements (full mantissas) take the fast path.
    let bits = v.to_bits();
    let biased = i32::from(u16::try_from((bits >> 52) & 0x7ff).expect("11 bits"));
    let frac = bits & ((1u64 << 52) - 1);
    let (m, e) = match biased {
        0 => (frac, -1074),
        _ => (frac | (1u64 << 52), biased - 1075),
    };
    if !v.is_finite() || m == 0 || e + m.trailing_zeros().cast_signed() >= -26 {
        // Writing into a Vec cannot fail.
        let _ = write!(out, "{v}");
        return;
    }
    let mut buf = ryu::Buffer::new();
    let text = buf.format_finite(v).as_bytes();
    let (neg, text) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, text),
    };
    let (mantissa, exp10) = match text.iter().position(|&b| b == b'e') {
        Some(i) => {
            // ryu writes a plain integer exponent (`e-7`, `e20`).
            let e = std::str::from_utf8(&text[i + 1..])
                .ok()
                .and_then(|e| e.parse::<i32>().ok())
                .unwrap_or(0);
            (&text[..i], e)
        }
        None => (text, 0),
    };
    // Digits without the point; `point` = how many of them precede the decimal point.
    let mut digits = [0u8; 40];
    let mut n = 0usize;
    let mut point = None;
    for &b in mantissa {
        if b == b'.' {
            point = Some(n);
        } else if n < digits.len() {
            digits[n] = b;
            n += 1;
        }
    }
    // n ≤ digits.len(), a small buffer: the point position fits i32.
    let mut point = i32::try_from(point.unwrap_or(n)).expect("a short digit buffer") + exp10;
    // Leading zeros (`0.001`) move the point; trailing zeros (`1.0`, `1.50`) are dropped.
    let mut first = 0;
    while first < n && digits[first] == b'0' {
        first += 1;
        point -= 1;
    }
    while n > first && digits[n - 1] == b'0' {
        n -= 1;
    }
    let digits = &digits[first..n];
    if neg {
        out.push(b'-');
    }
    if digits.is_empty() {
        out.push(b'0');
    } else if point <= 0 {
        out.extend_from_slice(b"0.");
        out.extend(std::iter::repeat_n(b'0', point.unsigned_abs() as usize));
        out.extend_from_slice(digits);
    } else if point.unsigned_abs() as usize >= digits.len() {
        // point > 0 in this branch and the next.
        out.extend_from_slice(digits);
        out.extend(std::iter::repeat_n(
            b'0',
            point.unsigned_abs() as usize - digits.len(),
        ));
    } else {
        let (int, frac) = digits.split_at(point.unsigned_abs() as usize);
        out.extend_from_slice(int);
        out.push(b'.');
        out.extend_from_slice(frac);
    }
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

    fn same_shortest(v: f64) {
        let mut out = Vec::new();
        push_shortest(&mut out, v);
        assert_eq!(std::str::from_utf8(&out).unwrap(), format!("{v}"), "{v:e}");
    }

    #[test]
    fn shortest_edge_cases_print_as_core_fmt_does() {
        for v in [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.1,
            1.5,
            100.0,
            1e15,
            1e16,
            1e17,
            1.2345e20,
            1e-5,
            1e-6,
            1e-7,
            -2.5e-12,
            123.456,
            0.000123,
            5e-324,
            f64::MIN_POSITIVE,
            f64::MAX,
            f64::MIN,
            f64::EPSILON,
            // Exact ties at 17 digits (the first found by the random test below).
            1_658_206_780_088_562.0 + 0.25,
            2f64.powi(50) + 0.25,
            2f64.powi(51) + 0.5,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            same_shortest(v);
        }
    }

    #[test]
    fn shortest_random_values_and_bit_patterns_print_as_core_fmt_does() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for _ in 0..500_000 {
            // Typical recording values (times on a grid, positions, µm errors) …
            let mag = 10f64.powi(rng.random_range(-9..9));
            let v = rng.random_range(-1.0..1.0) * mag;
            same_shortest(v);
            same_shortest((v * 1e3).round() / 1e3);
            // … any bit pattern (every exponent, subnormals) …
            let bits = rng.random::<u64>();
            same_shortest(f64::from_bits(bits));
            // … and short binary fractions, where exact ties live (a few mantissa bits kept).
            let keep = rng.random_range(1..53u32);
            same_shortest(f64::from_bits(bits & !((1u64 << (52 - keep)) - 1)));
        }
    }
}
