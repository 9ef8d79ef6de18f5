//! Locate a residual: where it concentrates (position bin × direction of travel, time, temperature
//! regime, in-cut vs air-cut), when it starts (two-sided CUSUM onset), and whether structure is left
//! after the findings (one-way ANOVA over bins, on the effective sample size).

use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::features::Context;
use super::lsq::effective_n;
use super::report::Mismatch;

const BINS: usize = 8;

fn rms(v: impl Iterator<Item = f64>) -> (f64, usize) {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    ((s / n.max(1) as f64).sqrt(), n)
}

fn bin_edges(v: &[f64]) -> Option<(f64, f64)> {
    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (hi - lo > 1e-9).then_some((lo, hi))
}

fn bin_of(x: f64, lo: f64, hi: f64) -> usize {
    crate::numeric::bin(x, lo, hi, BINS)
}

/// A regime's share of a residual: Σ (r − mean)² over its samples, in row order, and their count.
#[derive(Clone, Copy, Default)]
struct Share {
    sq: f64,
    k: usize,
}

impl Share {
    fn add(&mut self, x: f64) {
        self.sq += x * x;
        self.k += 1;
    }

    /// [`rms`] of the regime's samples (the same bits: the same sum in the same order).
    fn rms(self) -> (f64, usize) {
        ((self.sq / self.k.max(1) as f64).sqrt(), self.k)
    }
}

/// The regimes over which a residual can concentrate, each with its [`Share`] of `r` (less
/// `mean`): (description, share), in a fixed order. One pass over the rows per family of regimes
/// (a position axis' bins × directions, time bins, a temperature's warm half, a load's cut): a
/// membership column per regime was a pass and 1 MB per regime at 10⁶ rows, 60 regimes per
/// signal on a three-axis mill with three temperatures and a cutting force.
fn regime_shares(ctx: &Context, r: &[f64], mean: f64) -> Vec<(String, Share)> {
    let mut out = vec![];
    for (k, f) in ctx.axes.iter().enumerate() {
        let Some(f) = f else { continue };
        let a = ['x', 'y', 'z'][k];
        let Some((lo, hi)) = bin_edges(&f.pos_mm) else {
            continue;
        };
        let mut by = [[Share::default(); 2]; BINS];
        for ((&v, &x), &d) in r.iter().zip(f.pos_mm.iter()).zip(&f.dir) {
            let side = match d {
                1 => 0,
                -1 => 1,
                _ => continue,
            };
            by[bin_of(x, lo, hi)][side].add(v - mean);
        }
        let w = (hi - lo) / BINS as f64;
        for (b, sides) in by.iter().enumerate() {
            for (dname, share) in ["forward", "reverse"].iter().zip(sides) {
                out.push((
                    format!(
                        "{a}_mm in [{:.1}, {:.1}], {dname} direction",
                        lo + w * b as f64,
                        lo + w * (b + 1) as f64
                    ),
                    *share,
                ));
            }
        }
    }
    if let Some((lo, hi)) = bin_edges(&ctx.t_s) {
        let mut by = [Share::default(); BINS];
        for (&v, &t) in r.iter().zip(ctx.t_s.iter()) {
            by[bin_of(t, lo, hi)].add(v - mean);
        }
        let w = (hi - lo) / BINS as f64;
        for (b, share) in by.iter().enumerate() {
            out.push((
                format!(
                    "t_s in [{:.0}, {:.0}]",
                    lo + w * b as f64,
                    lo + w * (b + 1) as f64
                ),
                *share,
            ));
        }
    }
    let share_where = |x: &[f64], member: &dyn Fn(f64) -> bool| {
        let mut share = Share::default();
        for (&v, &xi) in r.iter().zip(x) {
            if member(xi) {
                share.add(v - mean);
            }
        }
        share
    };
    for (name, t) in &ctx.temps {
        if let Some((lo, hi)) = bin_edges(t) {
            let mid = 0.5 * (lo + hi);
            out.push((
                format!("{name} above {mid:.1} °C (warm regime)"),
                share_where(t, &|v| v > mid),
            ));
        }
    }
    for (name, f) in &ctx.loads {
        let peak = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if peak > 0.0 {
            out.push((
                format!("in cut ({name} above 5 % of its peak)"),
                share_where(f, &|v| v.abs() > 0.05 * peak),
            ));
        }
    }
    out
}

/// Where residual `r` (mean removed) concentrates: the regime with the largest RMS, if it is at least
/// 1.3× the overall RMS and holds ≥ 2 % of the samples; plus the CUSUM onset of a level change.
pub(super) fn locate(ctx: &Context, signal: &str, r: &[f64]) -> Vec<Mismatch> {
    let mean = r.iter().sum::<f64>() / r.len().max(1) as f64;
    let (total, n) = rms(r.iter().map(|v| v - mean));
    let mut out = vec![Mismatch {
        signal: signal.into(),
        where_: "whole recording (mean removed)".into(),
        rms_um: total,
    }];
    let best = regime_shares(ctx, r, mean)
        .into_iter()
        .filter_map(|(desc, share)| {
            let (v, k) = share.rms();
            (k * 50 >= n).then_some((desc, v))
        })
        .max_by(|a, b| a.1.total_cmp(&b.1));
    if let Some((desc, v)) = best
        && v > 1.3 * total
    {
        out.push(Mismatch {
            signal: signal.into(),
            where_: desc,
            rms_um: v,
        });
    }
    if let Some(t_on) = cusum_onset(&ctx.t_s, r) {
        out.push(Mismatch {
            signal: signal.into(),
            where_: format!("level change (CUSUM) from t_s ≈ {t_on:.0}"),
            rms_um: total,
        });
    }
    out
}

/// Two-sided CUSUM against the level of the first 10 % of the residual: k = 0.5σ, h = max(5, ln n)·σ.
/// Returns the estimated onset time (where the alarming sum last left zero).
pub(super) fn cusum_onset(t_s: &[f64], r: &[f64]) -> Option<f64> {
    let n = r.len();
    if n < 50 {
        return None;
    }
    let m0 = r[..n / 10].iter().sum::<f64>() / (n / 10) as f64;
    // σ of the first 10 % (the reference level); h grows with ln n so a long stationary recording
    // does not raise a false alarm just by its length (ARL₀ ≫ n).
    let var0 = r[..n / 10].iter().map(|v| (v - m0).powi(2)).sum::<f64>() / (n / 10) as f64;
    let sigma = var0.sqrt().max(1e-12);
    let (k, h) = (0.5 * sigma, (5.0f64).max((n as f64).ln()) * sigma);
    let (mut sp, mut sn) = (0.0f64, 0.0f64);
    let (mut start_p, mut start_n) = (0, 0);
    for (i, ri) in r.iter().enumerate() {
        let z = ri - m0;
        if sp == 0.0 {
            start_p = i;
        }
        if sn == 0.0 {
            start_n = i;
        }
        sp = (sp + z - k).max(0.0);
        sn = (sn - z - k).max(0.0);
        if sp > h {
            return Some(t_s[start_p]);
        }
        if sn > h {
            return Some(t_s[start_n]);
        }
    }
    None
}

/// Structure left in a residual: bins of each position axis and of time whose means differ beyond
/// noise (ANOVA on n_eff, p < 1e-3) and explain ≥ 10 % of the residual variance.
pub(super) fn unexplained(ctx: &Context, signal: &str, r: &[f64]) -> Vec<Mismatch> {
    let n = r.len();
    let mean = r.iter().sum::<f64>() / n.max(1) as f64;
    let sst: f64 = r.iter().map(|v| (v - mean).powi(2)).sum();
    if sst.is_nan() || sst <= 0.0 || n < 4 * BINS {
        return vec![];
    }
    let mut feats: Vec<(String, &[f64])> = ctx
        .axes
        .iter()
        .enumerate()
        .filter_map(|(k, f)| {
            f.as_ref()
                .map(|f| (format!("{}_mm", ['x', 'y', 'z'][k]), &f.pos_mm[..]))
        })
        .collect();
    feats.push(("t_s".into(), &ctx.t_s[..]));
    let mut out = vec![];
    for (name, v) in feats {
        let Some((lo, hi)) = bin_edges(v) else {
            continue;
        };
        let mut s = [0.0; BINS];
        let mut c = [0usize; BINS];
        for (vi, ri) in v.iter().zip(r) {
            let b = bin_of(*vi, lo, hi);
            s[b] += ri;
            c[b] += 1;
        }
        // n_eff of the within-bin residual: the between-bin structure under test is not "noise".
        let within: Vec<f64> = v
            .iter()
            .zip(r)
            .map(|(x, ri)| ri - s[bin_of(*x, lo, hi)] / c[bin_of(*x, lo, hi)] as f64)
            .collect();
        let n_eff = effective_n(&within);
        let groups = c.iter().filter(|&&k| k > 0).count();
        if groups < 2 {
            continue;
        }
        let ssb: f64 = (0..BINS)
            .filter(|&b| c[b] > 0)
            .map(|b| c[b] as f64 * (s[b] / c[b] as f64 - mean).powi(2))
            .sum();
        let df1 = (groups - 1) as f64;
        let df2 = n_eff - groups as f64;
        if df2 < 1.0 || ssb / sst < 0.10 {
            continue;
        }
        let f = (ssb / df1) / ((sst - ssb).max(1e-300) / df2);
        let p = FisherSnedecor::new(df1, df2).map_or(1.0, |d| d.sf(f));
        if p < 1e-3 {
            let w = (hi - lo) / BINS as f64;
            let worst = (0..BINS)
                .filter(|&b| c[b] > 0)
                .max_by(|&a, &b| {
                    (s[a] / c[a] as f64 - mean)
                        .abs()
                        .total_cmp(&(s[b] / c[b] as f64 - mean).abs())
                })
                .expect("groups ≥ 2");
            let dev = s[worst] / c[worst] as f64 - mean;
            out.push(Mismatch {
                signal: signal.into(),
                where_: format!(
                    "unexplained structure vs {name}: largest in {name} in [{:.1}, {:.1}] (bin mean {dev:+.2} µm; {:.0} % of residual variance, p {p:.1e})",
                    lo + w * worst as f64,
                    lo + w * (worst + 1) as f64,
                    100.0 * ssb / sst
                ),
                rms_um: ((sst - ssb) / n as f64).sqrt(),
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::{BINS, Context, bin_edges, bin_of, regime_shares, rms};
    use retrocomp_model::recording::Recording;

    /// Each regime's share is what a membership column per regime gives (the sum over its
    /// samples in row order), bit for bit, in the listed order; stationary rows are in no
    /// position regime.
    #[test]
    fn one_pass_shares_are_the_per_regime_sums_bit_for_bit() {
        let n = 5000;
        let x: Vec<f64> = (0..n)
            .map(|i| ((i / 7) % 40) as f64 * 2.5)
            .map(|v| if v > 50.0 { 100.0 - v } else { v })
            .collect();
        let col = |f: &dyn Fn(f64) -> f64| (0..n).map(|i| f(i as f64)).collect::<Vec<f64>>();
        let rec = Recording::from_columns(vec![
            ("t_s".into(), col(&|i| i * 0.5)),
            ("x_mm".into(), x),
            ("y_mm".into(), col(&|i| (i * 0.01).sin() * 30.0)),
            ("T_spindle_C".into(), col(&|i| 20.0 + (i * 0.002).sin())),
            (
                "F_cut_N".into(),
                col(&|i| {
                    if (i / 300.0).rem_euclid(3.0) < 1.0 {
                        250.0
                    } else {
                        1.0
                    }
                }),
            ),
            ("ex_um".into(), col(&|i| (i * 0.37).sin() + 0.2)),
        ])
        .unwrap();
        let ctx = Context::from_recording(&rec);
        let r: Vec<f64> = col(&|i| (i * 0.37).sin() * 3.0 + (i * 0.001).cos());
        let mean = r.iter().sum::<f64>() / n as f64;
        let of = |m: &dyn Fn(usize) -> bool| rms((0..n).filter(|&i| m(i)).map(|i| r[i] - mean));
        let mut want = vec![];
        for f in ctx.axes.iter().flatten() {
            let (lo, hi) = bin_edges(&f.pos_mm).unwrap();
            for b in 0..BINS {
                for dv in [1, -1] {
                    want.push(of(&|i| bin_of(f.pos_mm[i], lo, hi) == b && f.dir[i] == dv));
                }
            }
        }
        let (lo, hi) = bin_edges(&ctx.t_s).unwrap();
        for b in 0..BINS {
            want.push(of(&|i| bin_of(ctx.t_s[i], lo, hi) == b));
        }
        for (_, t) in &ctx.temps {
            let (lo, hi) = bin_edges(t).unwrap();
            want.push(of(&|i| t[i] > 0.5 * (lo + hi)));
        }
        for (_, f) in &ctx.loads {
            let peak = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            want.push(of(&|i| f[i].abs() > 0.05 * peak));
        }
        let got: Vec<(f64, usize)> = regime_shares(&ctx, &r, mean)
            .into_iter()
            .map(|(_, s)| s.rms())
            .collect();
        assert_eq!(
            got.len(),
            2 * 2 * BINS + BINS + 2,
            "two axes, time, a temperature, a load"
        );
        let bits = |v: &[(f64, usize)]| -> Vec<(u64, usize)> {
            v.iter().map(|(s, k)| (s.to_bits(), *k)).collect()
        };
        assert_eq!(bits(&got), bits(&want));
        let stationary = ctx.axes[0]
            .as_ref()
            .unwrap()
            .dir
            .iter()
            .filter(|&&d| d == 0)
            .count();
        let x_members: usize = got[..2 * BINS].iter().map(|s| s.1).sum();
        assert_eq!(x_members + stationary, n);
    }
}
