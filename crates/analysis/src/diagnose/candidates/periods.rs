//! The cyclic candidates' period scan: the least-squares periodogram's frequency grid over
//! position, its short end from the positions' spacing, and the sin/cos columns (fundamental and
//! second harmonic) swept over the grid by phasor rotation, in fixed chunks that run in parallel
//! and give the same bits as one sweep. The same sweep ([`Candidate::par_sweep_map`]) takes every
//! other candidate's grid too: a thermal lag's time constants (s) in lanes of one pass over the
//! rows, a reversal spike's decay lengths (mm) over one shared distance column. Positions mm,
//! periods mm.

use std::f64::consts::TAU;

use super::super::features::{AxisFeatures, Context};
use super::super::lsq;
use super::{Candidate, Kind, spike_column};
use retrocomp_model::lag;

impl Candidate {
    /// The one-thread sweep [`Candidate::par_sweep_map`] must equal bit for bit: every θ of
    /// `thetas` in order, handed to `f` with its columns.
    #[cfg(test)]
    fn columns_sweep(
        &self,
        ctx: &Context,
        thetas: &[f64],
        mut f: impl FnMut(f64, Vec<Vec<f64>>) -> Vec<Vec<f64>>,
    ) {
        match self.rotation(ctx, thetas) {
            Some(rot) => self.rotated_sweep(ctx, thetas, 0..thetas.len(), &rot, &mut f),
            None => thetas.iter().for_each(|&t| {
                f(t, self.columns(ctx, t));
            }),
        }
    }

    /// `f`'s value at every θ of `thetas` on [`Candidate::columns`] there, in grid order; `f`
    /// hands the column buffers back for the next θ (their contents need not survive).
    ///
    /// For a cyclic candidate on a grid uniform in frequency (`period_grid`) the sin/cos pair
    /// of the next period is the previous one rotated by a fixed angle per distinct position (one
    /// complex multiply instead of two transcendental calls: the period grid's sin/cos were most
    /// of the time of a 1M-row diagnosis), gathered into the reused buffers (a fresh 8 MB column
    /// per period at 1M rows was a page-fault storm). The grid is split into fixed chunks of
    /// `SWEEP_CHUNK` periods run in parallel (rayon): one long cyclic candidate's sweep was most
    /// of a 1M-row diagnosis' screening, on one core. Each chunk starts where one sweep over the
    /// whole grid re-anchors its phasors exactly and shares its rotation, so every θ gets the same
    /// bits with any number of threads. A thermal lag's time constants are lagged
    /// `lag::LANES` at a time ([`Candidate::lag_columns`]); a reversal spike's decay lengths
    /// share one distance-since-reversal column. θ off a uniform grid, and other candidates, are
    /// independent and mapped one by one.
    pub fn par_sweep_map<T: Send>(
        &self,
        ctx: &Context,
        thetas: &[f64],
        f: impl Fn(f64, Vec<Vec<f64>>) -> (T, Vec<Vec<f64>>) + Sync,
    ) -> Vec<T> {
        use rayon::prelude::*;
        if matches!(self.kind, Kind::ThermalLag { .. }) {
            return thetas
                .par_chunks(lag::LANES)
                .flat_map_iter(|taus| {
                    let cols = self.lag_columns(ctx, taus);
                    cols.into_iter()
                        .zip(taus)
                        .map(|(col, &tau_s)| f(tau_s, vec![col]).0)
                        .collect::<Vec<T>>()
                })
                .collect();
        }
        if self.kind == Kind::ReversalSpike {
            // The distance since reversal once for the whole grid, not once per decay length.
            let fa = ctx
                .axis(self.axis)
                .expect("library only lists candidates whose inputs exist");
            let dist_mm = fa.dist_since_rev_mm();
            return thetas
                .par_iter()
                .map(|&decay_mm| f(decay_mm, vec![spike_column(&fa.dir, &dist_mm, decay_mm)]).0)
                .collect();
        }
        let Some(rot) = self.rotation(ctx, thetas) else {
            return thetas
                .par_iter()
                .map(|&t| f(t, self.columns(ctx, t)).0)
                .collect();
        };
        let starts: Vec<usize> = (0..thetas.len()).step_by(SWEEP_CHUNK).collect();
        let chunks: Vec<Vec<T>> = starts
            .par_iter()
            .map(|&s| {
                let range = s..(s + SWEEP_CHUNK).min(thetas.len());
                let mut out = Vec::with_capacity(range.len());
                self.rotated_sweep(ctx, thetas, range, &rot, &mut |t, cols| {
                    let (v, cols) = f(t, cols);
                    out.push(v);
                    cols
                });
                out
            })
            .collect();
        chunks.into_iter().flatten().collect()
    }

    /// [`lsq::gram_gain`] of this cyclic pair at every period of `periods_mm` against `basis` and `r0`,
    /// the same bits as [`Candidate::par_sweep_map`] with `gram_gain` on each period's columns, when
    /// the grid is uniform in frequency (else `None`): each chunk's phasors are rotated per row
    /// (a row's value is its distinct position's, by the same arithmetic) block by block, every
    /// period of the chunk at once, so the columns never leave cache and r0 and the basis are
    /// read once per chunk instead of once per period.
    pub fn par_sweep_gram_gains(
        &self,
        ctx: &Context,
        periods_mm: &[f64],
        basis: &[Vec<f64>],
        r0: &[f64],
    ) -> Option<Vec<(f64, usize)>> {
        use rayon::prelude::*;
        if self.kind != Kind::Cyclic {
            return None;
        }
        let rot = self.rotation(ctx, periods_mm)?;
        let fa = ctx.axis(self.axis)?;
        let starts: Vec<usize> = (0..periods_mm.len()).step_by(SWEEP_CHUNK).collect();
        let chunks: Vec<Vec<(f64, usize)>> = starts
            .par_iter()
            .map(|&s| {
                let periods = SWEEP_CHUNK.min(periods_mm.len() - s);
                let (sv, cv) = exact_phasors(fa, rot.w[s]);
                lsq::gram_gains_sweep(basis, r0, periods, |rows, cols| {
                    for (o, i) in rows.enumerate() {
                        let k = fa.distinct_idx[i] as usize;
                        let (rs, rc) = (rot.rs[k], rot.rc[k]);
                        let (mut s0, mut c0) = (sv[k], cv[k]);
                        for (p, pair) in cols.iter_mut().enumerate() {
                            if p > 0 {
                                (s0, c0) = rotate(s0, c0, rs, rc);
                            }
                            pair[0][o] = s0;
                            pair[1][o] = c0;
                        }
                    }
                })
            })
            .collect();
        Some(chunks.into_iter().flatten().collect())
    }

    /// [`lsq::gram_gain`] of this cyclic pair at period `period_mm` against `basis` and `r0`, the
    /// same bits as on its [`Candidate::columns`], which are not built: each row's value is
    /// gathered from its distinct position's block by block (`None` for other candidates).
    pub fn pair_gram_gain(
        &self,
        ctx: &Context,
        period_mm: f64,
        basis: &[Vec<f64>],
        r0: &[f64],
    ) -> Option<(f64, usize)> {
        if self.kind != Kind::Cyclic {
            return None;
        }
        let fa = ctx.axis(self.axis)?;
        let (sv, cv) = cyclic_phasors(fa, period_mm);
        Some(lsq::gram_gain_gathered(
            basis,
            r0,
            [&sv, &cv],
            &fa.distinct_idx,
        ))
    }

    /// The phasor rotation of a cyclic candidate's sweep over `thetas` when they are uniform in
    /// frequency: the angular frequencies (rad/mm) and the sin/cos of the fixed step at every
    /// distinct position; `None` for other candidates and grids.
    fn rotation(&self, ctx: &Context, thetas: &[f64]) -> Option<Rotation> {
        let w: Vec<f64> = thetas.iter().map(|p| TAU / p).collect();
        let dw = if w.len() >= 3 { w[1] - w[0] } else { 0.0 };
        let uniform = self.is_cyclic()
            && dw != 0.0
            && w.windows(2)
                .all(|p| ((p[1] - p[0]) - dw).abs() <= 1e-9 * w[0].abs());
        if !uniform {
            return None;
        }
        let fa = ctx
            .axis(self.axis)
            .expect("library only lists candidates whose inputs exist");
        let (rs, rc) = exact_phasors(fa, dw);
        Some(Rotation { w, rs, rc })
    }

    /// The rotated sweep over `thetas[range]`: exact phasors at the range's start and every
    /// [`REANCHOR_EVERY`]-th grid index, rotated in between.
    fn rotated_sweep(
        &self,
        ctx: &Context,
        thetas: &[f64],
        range: std::ops::Range<usize>,
        rot: &Rotation,
        f: &mut dyn FnMut(f64, Vec<Vec<f64>>) -> Vec<Vec<f64>>,
    ) {
        let fa = ctx
            .axis(self.axis)
            .expect("library only lists candidates whose inputs exist");
        let Rotation { w, rs, rc } = rot;
        let (mut sv, mut cv) = (vec![], vec![]);
        let harmonic = self.kind == Kind::CyclicHarmonic;
        let (mut s2, mut c2) = (vec![], vec![]);
        let mut spare: Vec<Vec<f64>> = vec![];
        let first = range.start;
        for j in range {
            if j == first || j % REANCHOR_EVERY == 0 {
                (sv, cv) = exact_phasors(fa, w[j]);
            } else {
                for k in 0..sv.len() {
                    (sv[k], cv[k]) = rotate(sv[k], cv[k], rs[k], rc[k]);
                }
            }
            let mut cols = std::mem::take(&mut spare);
            cols.resize_with(if harmonic { 4 } else { 2 }, Vec::new);
            let gather = |v: &[f64], out: &mut Vec<f64>| {
                out.clear();
                out.extend(fa.distinct_idx.iter().map(|&k| v[k as usize]));
            };
            gather(&sv, &mut cols[0]);
            gather(&cv, &mut cols[1]);
            if harmonic {
                // The second harmonic from the fundamental's phasor (double angle).
                s2.clear();
                s2.extend(sv.iter().zip(&cv).map(|(s, c)| 2.0 * s * c));
                c2.clear();
                c2.extend(sv.iter().zip(&cv).map(|(s, c)| c * c - s * s));
                gather(&s2, &mut cols[2]);
                gather(&c2, &mut cols[3]);
            }
            spare = f(thetas[j], cols);
        }
    }
}

/// A uniform-frequency sweep's angular frequencies (rad/mm) and its step's sin/cos per distinct
/// position.
struct Rotation {
    w: Vec<f64>,
    rs: Vec<f64>,
    rc: Vec<f64>,
}

/// sin and cos of `w_rad_per_mm` × every distinct position.
fn exact_phasors(fa: &AxisFeatures, w_rad_per_mm: f64) -> (Vec<f64>, Vec<f64>) {
    fa.distinct_mm
        .iter()
        .map(|&x| (w_rad_per_mm * x).sin_cos())
        .unzip()
}

/// The phasor `(sin θ, cos θ)` advanced by the step whose sin/cos are `(rs, rc)`: the angle-sum
/// formulas. Both sweeps rotate through this one expression, so their phasors (and the sums the
/// bit-identity tests compare) are the same bits.
#[inline(always)]
fn rotate(s: f64, c: f64, rs: f64, rc: f64) -> (f64, f64) {
    (s * rc + c * rs, c * rc - s * rs)
}

/// Grid periods per parallel chunk of [`Candidate::par_sweep_map`]: one re-anchoring interval,
/// so the chunks start exactly where the one-thread sweep recomputes its phasors.
pub(crate) const SWEEP_CHUNK: usize = REANCHOR_EVERY;

/// Shortest period a cyclic candidate scans (mm): lead-screw pitches and scale periods that
/// matter at the µm level are ≥ 2 mm.
pub const MIN_PITCH_MM: f64 = 2.0;

/// The frequency grid of the residual's least-squares periodogram over position (Lomb–Scargle
/// / least-squares spectral analysis: each period's sin/cos pair is fitted to the residual at the
/// positions where it was read, so uneven target spacing needs no FFT grid). From `travel/1.5` down
/// to [`shortest_period`] (≈ 2 samples per period), uniform in frequency with Δ(1/p) = 1/(3L):
/// neighbouring periods drift apart by a third of a cycle over the travel L, so the scan cannot step
/// over a peak, and uniform frequency steps let [`Candidate::par_sweep_map`] rotate phasors instead
/// of evaluating sin/cos at every period. The screening (`select_step.rs`) takes the periodogram's
/// highest peak against the step's null and refines it between its neighbours.
pub(super) fn period_grid(travel_mm: f64, min_period_mm: f64) -> Vec<f64> {
    let lo = min_period_mm.max(MIN_PITCH_MM);
    let hi = travel_mm / 1.5;
    let step = 1.0 / (3.0 * travel_mm);
    (0..)
        .map(|k| 1.0 / (1.0 / lo - f64::from(k) * step))
        .take_while(|p| *p > 0.0 && *p <= hi)
        .collect()
}

/// The shortest period the positions can show: two samples per period at the median gap between
/// neighbouring distinct positions (`distinct_mm`, sorted). Uneven targets of several runs
/// interleave, so their median gap is finer than any one run's step, as the least-squares
/// periodogram's resolving power is; no count of targets enters.
pub fn shortest_period(distinct_mm: &[f64]) -> f64 {
    let mut gaps: Vec<f64> = distinct_mm
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > super::super::features::DIRECTION_DEADBAND_MM)
        .collect();
    if gaps.is_empty() {
        return f64::INFINITY;
    }
    let mid = gaps.len() / 2;
    let (_, m, _) = gaps.select_nth_unstable_by(mid, f64::total_cmp);
    2.0 * *m
}

/// Phasors are recomputed exactly every this many rotations (rounding drift stays ≤ 1e-14).
const REANCHOR_EVERY: usize = 32;

/// The sin/cos pair of period `period_mm` in position. Computed over positions and rows in
/// parallel (rayon, pieces of at least [`ELEMENT_CHUNK`]): every value is computed alone, so the
/// columns are the same bits with any number of threads, and a period's refinement (one call
/// per golden-section step, at 1M rows a cosine per distinct position) uses every core.
pub(super) fn cyclic_columns(f: &AxisFeatures, period_mm: f64) -> Vec<Vec<f64>> {
    use rayon::prelude::*;
    let (sv, cv) = cyclic_phasors(f, period_mm);
    // Collected in place (rayon writes each piece where it belongs): zeroing 8 MB before
    // overwriting it was most of the 4 % of a 10⁶-row diagnosis' CPU spent in memset.
    let gather = |v: &[f64]| -> Vec<f64> {
        f.distinct_idx
            .par_iter()
            .with_min_len(ELEMENT_CHUNK)
            .map(|&k| v[k as usize])
            .collect()
    };
    vec![gather(&sv), gather(&cv)]
}

/// [`cyclic_columns`]' values at every distinct position (sin, cos), before they are gathered
/// into rows.
fn cyclic_phasors(f: &AxisFeatures, period_mm: f64) -> (Vec<f64>, Vec<f64>) {
    use rayon::prelude::*;
    let w = TAU / period_mm;
    let (mut sv, mut cv) = (vec![], vec![]);
    // One transcendental per distinct position: sin from cos with the half-cycle sign.
    f.distinct_mm
        .par_iter()
        .with_min_len(ELEMENT_CHUNK)
        .map(|&x| {
            let ph = rem_euclid(w * x, TAU);
            let c = ph.cos();
            let s =
                (1.0 - c * c).max(0.0).sqrt() * if ph < std::f64::consts::PI { 1.0 } else { -1.0 };
            (s, c)
        })
        .unzip_into_vecs(&mut sv, &mut cv);
    (sv, cv)
}

/// `x.rem_euclid(y)` for a finite `y > 0`, the same bits: the remainder `x − n·y` of the true
/// quotient n is exact (representable), so one fused multiply-add of the exact integer n gives it
/// with no rounding, instead of the bit-serial long division of the software `fmod` (2 % of a
/// 10⁶-row diagnosis' CPU, one call per distinct position per period). A quotient estimate off by
/// one shows as a remainder outside `fmod`'s range (x's sign, smaller than y) and is stepped back;
/// a quotient too large for an exact integer, and non-finite values, go to `rem_euclid` itself.
fn rem_euclid(x: f64, y: f64) -> f64 {
    let q = (x / y).trunc();
    if !(q.abs() < 4_503_599_627_370_496.0 && y.is_finite() && y > 0.0) {
        return x.rem_euclid(y);
    }
    // fmod's remainder carries x's sign; it lies in (−y, y).
    let mut r = (-q).mul_add(y, x);
    if x >= 0.0 && r < 0.0 || x < 0.0 && r > 0.0 {
        r = (-(q - x.signum())).mul_add(y, x);
    } else if r.abs() >= y {
        r = (-(q + x.signum())).mul_add(y, x);
    }
    if r == 0.0 {
        r = 0.0f64.copysign(x);
    }
    // Then `rem_euclid`'s own step for a negative remainder.
    if r < 0.0 { r + y } else { r }
}

/// Fewest positions or rows per parallel piece of [`cyclic_columns`].
const ELEMENT_CHUNK: usize = 1 << 15;

#[cfg(test)]
mod tests {
    use super::super::{Candidate, library};
    use super::{Context, SWEEP_CHUNK};
    use retrocomp_model::recording::Recording;

    /// The context of a recording read at positions `x` (mm), one row per second.
    fn context_of(x: Vec<f64>) -> Context {
        let n = x.len();
        let rec = Recording::from_columns(vec![
            ("t_s".into(), (0..n).map(|i| i as f64).collect()),
            ("x_mm".into(), x),
            ("ex_um".into(), vec![0.0; n]),
        ])
        .unwrap();
        Context::from_recording(&rec)
    }

    /// Every column's bits at one θ, folded (order-sensitive) into one word.
    fn bits(cols: &[Vec<f64>]) -> u64 {
        cols.iter()
            .flatten()
            .fold(0u64, |h, v| h.rotate_left(5) ^ v.to_bits())
    }

    /// The fused remainder is `f64::rem_euclid`'s bits: random phases over a long travel,
    /// multiples of the period and their neighbours (where the quotient estimate is off by
    /// one), negatives, zeros of both signs, huge and non-finite values.
    #[test]
    fn the_fused_remainder_is_rem_euclid_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        use std::f64::consts::TAU;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut xs: Vec<f64> = (0..200_000).map(|_| rng.random_range(-5e3..5e3)).collect();
        for k in -2000..2000 {
            let m = f64::from(k) * TAU;
            xs.extend([m, m.next_up(), m.next_down(), f64::from(k) * 3.0]);
        }
        xs.extend([
            0.0,
            -0.0,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
        ]);
        for y in [TAU, 3.0, 0.1, 7.25e-3] {
            for &x in &xs {
                let (got, want) = (super::rem_euclid(x, y), x.rem_euclid(y));
                assert_eq!(
                    got.to_bits(),
                    want.to_bits(),
                    "{x:e} mod {y}: {got:e} ≠ {want:e}"
                );
            }
        }
    }

    /// The chunked parallel sweep hands `f` the same columns, bit for bit, as one sweep, on one
    /// thread and on three: its chunks start at the sweep's exact re-anchors (issue 39 point 3).
    #[test]
    fn the_parallel_sweep_is_the_one_thread_sweep_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 3000;
        // Uneven targets over 900 mm: a period grid of several hundred periods.
        let x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..900.0)).collect();
        let ctx = context_of(x);
        let cyclic: Vec<Candidate> = library(&ctx, 'x')
            .into_iter()
            .filter(Candidate::is_cyclic)
            .collect();
        assert_eq!(cyclic.len(), 2, "the fundamental and the harmonic form");
        for c in &cyclic {
            assert!(c.rotation(&ctx, &c.grid).is_some(), "a uniform grid");
            assert!(c.grid.len() > 4 * SWEEP_CHUNK + 1, "{}", c.grid.len());
            let mut one_sweep = vec![];
            c.columns_sweep(&ctx, &c.grid, |th, cols| {
                one_sweep.push((th.to_bits(), bits(&cols)));
                cols
            });
            for threads in [1, 3] {
                let pool = crate::diagnose::test_pool(threads);
                let chunked = pool.install(|| {
                    c.par_sweep_map(&ctx, &c.grid, |th, cols| {
                        ((th.to_bits(), bits(&cols)), cols)
                    })
                });
                assert_eq!(chunked, one_sweep, "{} on {threads}", c.label());
            }
            // The rotation is what is compared: it differs from fresh sin/cos in the last bits.
            let fresh: Vec<(u64, u64)> = c
                .grid
                .iter()
                .map(|&th| (th.to_bits(), bits(&c.columns(&ctx, th))))
                .collect();
            assert_ne!(fresh, one_sweep, "{}", c.label());
        }
    }

    /// The pair sweep's gains are `gram_gain` on each period's swept columns, bit for bit, on one
    /// thread and on three, over two spans of rows and blocks that do not divide them; so is one
    /// period's gain gathered from its distinct positions (`pair_gram_gain`, off the grid, as a
    /// refinement asks for it) against `gram_gain` on its `columns`. Only the fundamental is
    /// scored so.
    #[test]
    fn the_pair_sweep_gains_are_each_periods_gains_bit_for_bit() {
        use super::super::super::lsq;
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let n = 70_001;
        let x: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..900.0)).collect();
        let r: Vec<f64> = x
            .iter()
            .map(|p| (p / 7.3).sin() + rng.random_range(-0.5..0.5))
            .collect();
        let ramp: Vec<f64> = (0..n).map(|i| i as f64 / n as f64).collect();
        let ctx = context_of(x);
        let basis = lsq::orthonormalize(&[], vec![vec![1.0; n], ramp], 2);
        let r0 = lsq::deflate(&basis, &r);
        for c in library(&ctx, 'x').iter().filter(|c| c.is_cyclic()) {
            let thetas = &c.grid[..(3 * SWEEP_CHUNK + 5).min(c.grid.len())];
            if c.kind != super::Kind::Cyclic {
                assert!(c.par_sweep_gram_gains(&ctx, thetas, &basis, &r0).is_none());
                assert!(c.pair_gram_gain(&ctx, thetas[1], &basis, &r0).is_none());
                continue;
            }
            assert!(thetas.len() > 2 * SWEEP_CHUNK);
            let key = |v: Vec<(f64, usize)>| -> Vec<(u64, usize)> {
                v.into_iter().map(|(g, q)| (g.to_bits(), q)).collect()
            };
            let want = key(c.par_sweep_map(&ctx, thetas, |_, cols| {
                (lsq::gram_gain(&basis, &cols, &r0), cols)
            }));
            assert!(want.iter().all(|&(_, q)| q == 2));
            for threads in [1, 3] {
                let pool = crate::diagnose::test_pool(threads);
                let got = pool.install(|| c.par_sweep_gram_gains(&ctx, thetas, &basis, &r0));
                assert_eq!(key(got.expect("a uniform grid")), want, "on {threads}");
                for th in [0.5 * (thetas[0] + thetas[1]), thetas[7] * 1.000_3] {
                    let want = key(vec![lsq::gram_gain(&basis, &c.columns(&ctx, th), &r0)]);
                    let got = pool.install(|| c.pair_gram_gain(&ctx, th, &basis, &r0));
                    assert_eq!(key(got.into_iter().collect()), want, "{th} on {threads}");
                }
            }
        }
    }
}
