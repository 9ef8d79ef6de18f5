//! The found model run forward once (issue 12 point 1), on every recording: the gains of the
//! final terms and the offset refitted on the first [`FORWARD_FIT_FRACTION`] of the rows (in
//! recording order), RMS of measured − sim − model on the rest, against the offset alone fitted
//! the same way. Selection on recordings with axes is validated leave-one-block-out, so their
//! findings' held-out figures may use later rows to predict earlier ones; this is the forward
//! figure beside them (on thermal tests the held-out figures are forward already, and this is
//! one more, single-origin, split). Not used for selection. Residuals µm (measured − sim), the
//! terms' nonlinear parameters (τ, periods) kept as refitted on every row.

use super::SignalResult;
use super::features::Context;
use super::lsq;
use super::report::ForwardCheck;

/// Fraction of the rows the forward gains are fitted on (the rest is predicted); also the split of
/// `diagnose-bench`'s forward ratio.
pub(super) const FORWARD_FIT_FRACTION: f64 = 0.6;

/// RMS (µm) on the rows after the split of `r` − the least-squares fit of `cols` on the rows before
/// it. `cols` must hold the intercept when an offset is meant.
pub(super) fn forward_rms<C: AsRef<[f64]>>(cols: &[C], r: &[f64]) -> f64 {
    forward_ms_at(cols, r, fit_rows(r.len())).sqrt()
}

/// Mean square (µm²) on rows `split..` of `r` − the least-squares fit of `cols` on rows `..split`.
pub(super) fn forward_ms_at<C: AsRef<[f64]>>(cols: &[C], r: &[f64], split: usize) -> f64 {
    let early: Vec<&[f64]> = cols.iter().map(|c| &c.as_ref()[..split]).collect();
    let coef = lsq::coef(&early, &r[..split]);
    let rss: f64 = (split..r.len())
        .map(|i| {
            let fit: f64 = cols.iter().zip(&coef).map(|(c, b)| b * c.as_ref()[i]).sum();
            (r[i] - fit).powi(2)
        })
        .sum();
    rss / (r.len() - split).max(1) as f64
}

fn fit_rows(n: usize) -> usize {
    crate::numeric::trunc_usize(n as f64 * FORWARD_FIT_FRACTION)
}

/// The forward check of one signal's final model; `None` without terms, or when either side of
/// the split is too short to say anything (fewer rows than columns to fit, or none to score).
pub(super) fn forward_check(ctx: &Context, s: &SignalResult) -> Option<ForwardCheck> {
    if s.terms.is_empty() {
        return None;
    }
    offset_and_terms(ctx, s)
}

/// The forward check of one signal with its terms (the offset alone without any), `None` when a
/// side of the split is too short.
pub(super) fn offset_and_terms(ctx: &Context, s: &SignalResult) -> Option<ForwardCheck> {
    let r = &s.residual_before;
    let n = r.len();
    let (fit, scored) = (fit_rows(n), n - fit_rows(n));
    let mut cols = vec![vec![1.0; n]];
    for (c, theta) in &s.terms {
        cols.extend(c.columns(ctx, *theta));
    }
    if fit <= cols.len() || scored == 0 {
        return None;
    }
    let rms_sim_um = forward_rms(&cols[..1], r);
    let rms_model_um = forward_rms(&cols, r);
    (rms_sim_um.is_finite() && rms_model_um.is_finite()).then(|| ForwardCheck {
        signal: s.signal.clone(),
        fit_rows: fit,
        scored_rows: scored,
        rms_sim_um,
        rms_model_um,
        regimes: None,
    })
}

#[cfg(test)]
mod tests {
    use crate::diagnose::{Options, diagnose};
    use retrocomp_model::recording::Recording;

    /// A recording with axes (selection validated leave-one-block-out) whose residual is a drift
    /// of a temperature that keeps rising: the found term predicts the last 40 % from the first
    /// 60 % (forward RMS a fraction of the offset's), and the split counts every row once. A
    /// residual with no effect gives no finding and no forward check.
    #[test]
    fn the_found_model_is_checked_forward_and_a_null_has_no_check() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let n = 2000;
        let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let x: Vec<f64> = (0..n).map(|i| 10.0 * ((i / 20) % 10) as f64).collect();
        let temp: Vec<f64> = t.iter().map(|s| 20.0 + 3.0 * s / n as f64).collect();
        let noise: Vec<f64> = (0..n).map(|_| rng.random_range(-0.2..0.2)).collect();
        let rec = |with_effect: bool| {
            let ex: Vec<f64> = temp
                .iter()
                .zip(&noise)
                .map(|(c, e)| e + if with_effect { 2.0 * (c - 20.0) } else { 0.0 })
                .collect();
            Recording::from_columns(vec![
                ("t_s".into(), t.clone()),
                ("x_mm".into(), x.clone()),
                ("T_col_C".into(), temp.clone()),
                ("ex_um".into(), ex),
                ("sim_ex_um".into(), vec![0.0; n]),
            ])
            .unwrap()
        };
        let d = diagnose(&rec(true), &Options::default()).unwrap();
        assert!(!d.report.findings.is_empty(), "{:?}", d.report.findings);
        let [fc] = &d.report.forward_check[..] else {
            panic!("one signal, one check: {:?}", d.report.forward_check)
        };
        assert_eq!(fc.signal, "ex_um");
        assert_eq!((fc.fit_rows, fc.fit_rows + fc.scored_rows), (1200, n));
        // The offset fitted on the first 60 % misses the later rise (≈ 2 µm/K × 1.2 K further);
        // the drift's gain carries it on.
        assert!(fc.rms_sim_um > 1.0, "{fc:?}");
        assert!(fc.rms_model_um < 0.2 * fc.rms_sim_um, "{fc:?}");
        let text = d.report.to_text();
        assert!(
            text.contains(&format!(
                "ex_um: fitted on the first 1200 rows, RMS on the 800 after them: {:.3} µm",
                fc.rms_sim_um
            )),
            "{text}"
        );
        let d = diagnose(&rec(false), &Options::default()).unwrap();
        assert!(d.report.findings.is_empty() && d.report.forward_check.is_empty());
    }
}
