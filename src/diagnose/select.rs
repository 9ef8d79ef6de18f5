//! Forward selection of candidate terms for one residual signal r = measured − sim (µm).
//!
//! Each step: every candidate (at every grid value of its nonlinear parameter) is screened by the RSS
//! drop it gives on top of what is already fitted (score/ERR test via an orthonormal basis); the best
//! by ΔBIC is tested with an F-test whose p-value is multiplied by the number of (candidate, grid)
//! pairs tried (Holm's first step), both on the effective sample size of the AR(1) residual; its
//! nonlinear parameter is refined by golden-section on the profile RSS (linear gains solved inside:
//! variable projection); it is kept only if block cross-validation (leave one run / time block out,
//! or interleaved position cells for a forward + a reverse run: [`Context::blocks_for`]) improves.
//! On thermal-only recordings the blocks are validated forward (rolling origin), each later block
//! scored with lag states carried and restarted at its first row ([`restarted`]), as a new file
//! fed to `retrocomp eval` would start them.
//! Candidates of another family that explain the same residual almost as well and almost
//! collinearly are recorded as ambiguous alternatives.
//!
//! Backlash and reversal profile (functions of position and the latched approach direction only)
//! are screened and tested both as usual and WITHIN own-axis position cells — the cell means are
//! a nuisance in its null model, as in the two-way (position × direction) layout of an ISO 230-2
//! reversal value. Where both directions are read at a position, a direction-odd column is
//! orthogonal to every function of position alone, so an unmodelled positioning error (a shape no
//! candidate names) no longer counts as noise against a reversal. Where the directions are not
//! balanced within cells (one-way passes) the cells also absorb part of a real reversal, so the
//! better of the two nulls (by ΔBIC) is used and both count in the Holm correction (`tried`).
//! Every other candidate keeps the plain test (a reversal spike is not a
//! function of position and direction alone: the cell means near the reversal points would absorb
//! part of it).

use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::candidates::{Candidate, Kind, library};
use super::features::Context;
use super::heldout::Heldout;
use super::lsq::{self, dot};
use super::null_model::{
    NoiseModel, Null, contribution, delta_bic, golden_refine, prewhitened_test, score, score_cols,
    within_cells, without_cell_means,
};

/// Share of the best thermal ΔBIC a driver-column lag needs to be preferred over a sensor.
const DRIVER_SHARE: f64 = 0.0;

/// A thermal candidate read from a driver column (`rpm`, a column with no DESIGN §4 role), not a
/// temperature sensor.
fn is_driver(ctx: &Context, c: &Candidate) -> bool {
    match &c.kind {
        Kind::ThermalLag { sensor } | Kind::ThermalDrift { sensor } => {
            ctx.drivers().iter().any(|(n, _)| n == sensor)
        }
        _ => false,
    }
}

/// How many of a step's strongest candidates compete on forward held-out error.
const FORWARD_CHOICES: usize = 8;

struct Scored {
    idx: usize,
    theta: f64,
    /// RSS drop against the candidate's null (within position cells for the reversal family).
    gain: f64,
    q: usize,
    delta_bic: f64,
    /// Screened within own-axis position cells (else against the plain null).
    cells: bool,
}

pub use super::heldout::restarted;
pub use super::selection::{Alternative, Exchanged, Options, SignalSelection, Term, set_of};

/// Run forward selection on residual `r` of the signal of axis `axis`.
///
/// `sim_inputs`: the simulation's thermal inputs when it is a machine model (else empty); forward
/// validation then refits its gains per fold ([`Heldout`]), and a term is kept only if it improves
/// that score AND does not worsen the forward error against the simulation as given (the guard
/// below).
pub fn select(
    ctx: &Context,
    axis: char,
    r: &[f64],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
) -> SignalSelection {
    select_pooled(ctx, axis, r, sim_inputs, opts, None)
}

/// [`select`] with the recording's pooled noise statistic (`null_model::recording_tau`).
pub fn select_pooled(
    ctx: &Context,
    axis: char,
    r: &[f64],
    sim_inputs: &[Vec<f64>],
    opts: &Options,
    pooled_tau: Option<f64>,
) -> SignalSelection {
    let n = r.len();
    let lib = library(ctx, axis);
    let mut tried: usize = lib.iter().map(|c| c.grid.len().max(1)).sum();
    let cell_of = ctx.position_cells(axis);
    if cell_of.is_some() {
        tried += lib.iter().filter(|c| within_cells(c)).count();
    }
    let mut basis = lsq::orthonormalize(&[], vec![vec![1.0; n]], 2);
    // Raw columns fitted so far (intercept + every term's): only their count is needed (the
    // columns themselves are in `terms`; a copy was 8 MB a column on a 1M-row recording).
    let mut n_raw = 1;
    let mut terms: Vec<Term> = vec![];
    let mut runners_up = vec![];
    let mut used = vec![false; lib.len()];
    // Held-out error (forward on thermal tests, both feeding modes): `heldout.rs`.
    let heldout = Heldout::new(ctx, axis, r, sim_inputs, opts);
    let forward = heldout.forward;
    let cv_of = |set: &[(&Candidate, f64)]| heldout.rms(set);
    let mut cv_before = cv_of(&[]);
    // The guard when the simulation is refitted per fold: the written model keeps the
    // simulation's gains as given (fitted on every row) and adds the term's gain fitted on that
    // residual, so a term must not make THAT model predict later blocks worse. A term can win the
    // refitted score by standing in for a change of the simulation's gains (a sensor collinear
    // with the simulation's, e.g. FL_THERMAL's T_8 on d1/d2): the model as written does not get
    // that change, only the term. Without simulation inputs both scores are the same.
    let in_sample = |set: &[(&Candidate, f64)]| heldout.rms_in_sample(set);
    let mut guard_before = in_sample(&[]);
    let guard_ok =
        |set: &[(&Candidate, f64)], before: f64| !heldout.refits_sim() || in_sample(set) <= before;
    let mut exchanges = 0;
    let mut first_choice = None;
    let mut exchanged = vec![];
    loop {
        while terms.len() < opts.max_terms && n > n_raw + 3 {
            let r0 = lsq::deflate(&basis, r);
            let rss0 = dot(&r0, &r0);
            if rss0.is_nan() || rss0 <= 0.0 {
                break;
            }
            let plain = Null {
                basis: basis.as_slice().into(),
                r0,
                rss0,
                extra: 0,
                cells: None,
            };
            let r0 = &plain.r0;
            let cells = match &cell_of {
                Some((cell, k)) => Null::within_cells(&basis, r, cell, *k),
                None => Null {
                    basis: vec![].into(),
                    r0: vec![],
                    rss0: 0.0,
                    extra: 0,
                    cells: None,
                },
            };
            let cells_ok = cells.extra > 0 && cells.rss0 > 0.0 && n > basis.len() + cells.extra + 3;
            let null_of = |blocked: bool| if blocked { &cells } else { &plain };
            // Profile every candidate over its grid (best θ by RSS drop: q is fixed within a candidate).
            let mut scored: Vec<Scored> = vec![];
            for (idx, c) in lib.iter().enumerate() {
                if used[idx] {
                    continue;
                }
                let thetas: Vec<f64> = if c.grid.is_empty() {
                    vec![f64::NAN]
                } else {
                    c.grid.clone()
                };
                for blocked in [false, true] {
                    if blocked && !(cells_ok && within_cells(c)) {
                        continue;
                    }
                    let nl = null_of(blocked);
                    let mut best: Option<Scored> = None;
                    c.columns_sweep(ctx, &thetas, |th, cols| {
                        if let Some((g, q)) = score_cols(c, cols, nl)
                            && best.as_ref().is_none_or(|b| g > b.gain)
                        {
                            best = Some(Scored {
                                idx,
                                theta: th,
                                gain: g,
                                q,
                                delta_bic: 0.0,
                                cells: blocked,
                            });
                        }
                    });
                    scored.extend(best);
                }
            }
            if scored.is_empty() {
                break;
            }
            // One effective sample size for the whole step (from the residual left by the candidate that
            // explains the largest share of its null's RSS), so candidates are ranked on the same scale.
            let share = |s: &Scored| s.gain / null_of(s.cells).rss0;
            let top = scored
                .iter()
                .max_by(|a, b| share(a).total_cmp(&share(b)))
                .expect("non-empty");
            let top_contrib = contribution(ctx, &lib[top.idx], top.theta, &basis, r0);
            let r1_top: Vec<f64> = r0.iter().zip(&top_contrib).map(|(a, b)| a - b).collect();
            let noise_top = without_cell_means(ctx, axis, &r1_top);
            let n_eff = lsq::effective_n(&noise_top);
            // The error model of the prewhitened test, once per step (see `NoiseModel`).
            let noise_model = (!forward).then(|| {
                NoiseModel::of(&without_cell_means(ctx, axis, r0), &noise_top, pooled_tau)
            });
            drop(noise_top);
            for s in &mut scored {
                s.delta_bic = delta_bic(n_eff, null_of(s.cells).rss0, s.gain, s.q);
            }
            scored.sort_by(|a, b| b.delta_bic.total_cmp(&a.delta_bic));
            // A candidate screened under both nulls keeps its better one.
            let mut seen = vec![false; lib.len()];
            scored.retain(|s| !std::mem::replace(&mut seen[s.idx], true));
            if terms.is_empty() {
                runners_up = scored
                    .iter()
                    .map(|s| (lib[s.idx].clone(), s.delta_bic))
                    .collect();
            }
            // With forward folds, the strong candidates (ΔBIC above the bar, at most
            // FORWARD_CHOICES of them) compete on forward held-out error: the one that best
            // predicts later blocks from earlier ones wins, not the best in-sample fit (a sensor
            // with a large gain fits a warm-up well and extrapolates badly).
            if forward {
                let k = scored
                    .iter()
                    .take(FORWARD_CHOICES)
                    .take_while(|s| s.delta_bic > opts.min_delta_bic)
                    .count();
                let cv_with = |s: &Scored| {
                    let mut trial = set_of(&terms);
                    trial.push((&lib[s.idx], s.theta));
                    if guard_ok(&trial, guard_before) {
                        cv_of(&trial)
                    } else {
                        f64::NAN
                    }
                };
                if let Some(best) = (0..k)
                    .map(|i| (i, cv_with(&scored[i])))
                    .filter(|(_, v)| v.is_finite())
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .map(|(i, _)| i)
                {
                    let s = scored.remove(best);
                    scored.insert(0, s);
                }
            }
            // Heat source before its symptoms: when the winner is a thermal term read from a
            // temperature sensor and a driver column (rpm, or a named heat source) explains the
            // same family with strong evidence of its own (ΔBIC above the bar), the driver's lag
            // is taken. A sensor is itself a lagged response of the source; the source term
            // extrapolates to regimes the fit never saw (another spindle speed), a re-weighted
            // sensor with a large gain does not. The sensor stays a candidate for what is left.
            if lib[scored[0].idx].family() == "thermal_offset"
                && !is_driver(ctx, &lib[scored[0].idx])
            {
                let top = scored[0].delta_bic;
                let cv_with = |s: &Scored| {
                    let mut trial = set_of(&terms);
                    trial.push((&lib[s.idx], s.theta));
                    cv_of(&trial)
                };
                let guard_with = |s: &Scored| {
                    let mut trial = set_of(&terms);
                    trial.push((&lib[s.idx], s.theta));
                    guard_ok(&trial, guard_before)
                };
                // Validated leave-one-block-out (recordings with axes), the driver must also
                // predict the held-out blocks no worse than the sensor: a measured temperature
                // that is the true input (a node heated by friction as well as by the spindle)
                // is not replaced by a lag of rpm that only resembles it. Forward-validated
                // recordings chose the winner by forward error already.
                let sensor_cv = if forward {
                    f64::INFINITY
                } else {
                    cv_with(&scored[0])
                };
                let passes_heldout = |s: &Scored| {
                    let cv = cv_with(s);
                    cv < cv_before * (1.0 - opts.cv_min_gain) && cv <= sensor_cv && guard_with(s)
                };
                if let Some(j) = scored.iter().position(|s| {
                    is_driver(ctx, &lib[s.idx])
                        && s.delta_bic > opts.min_delta_bic
                        && s.delta_bic >= DRIVER_SHARE * top
                        && passes_heldout(s)
                }) {
                    let _ = top;
                    let s = scored.remove(j);
                    scored.insert(0, s);
                }
            }
            // Slow noise where the held-out check is leave-one-block-out (see below): the
            // strongest candidate that also passes the bar under the noise model
            // (null_model::prewhitened_test) is the step's winner, so a spurious smooth term
            // ranked above a real effect does not end the step.
            if let Some(model) = &noise_model {
                let passes = |s: &Scored| {
                    let nl = null_of(s.cells);
                    prewhitened_test(ctx, &lib[s.idx], s.theta, nl, n_raw + nl.extra, model)
                        .is_some_and(|(dbic, p)| {
                            dbic > opts.min_delta_bic && p * (tried as f64) < opts.alpha
                        })
                };
                let Some(j) = scored
                    .iter()
                    .take(FORWARD_CHOICES)
                    .take_while(|s| s.delta_bic > opts.min_delta_bic)
                    .position(passes)
                else {
                    break;
                };
                let s = scored.remove(j);
                scored.insert(0, s);
            }
            // Refine the winner's nonlinear parameter between its grid neighbours.
            let mut win = scored.remove(0);
            let cand = &lib[win.idx];
            let nl = null_of(win.cells);
            if cand.is_nonlinear() {
                let g = &cand.grid;
                let i = g.iter().position(|&v| v == win.theta).unwrap_or(0);
                let lo = g[i.saturating_sub(1)];
                let hi = g[(i + 1).min(g.len() - 1)];
                if hi > lo {
                    let th = golden_refine(
                        |t| score(ctx, cand, t, nl).map_or(f64::NEG_INFINITY, |s| s.0),
                        lo,
                        hi,
                        18,
                    );
                    if let Some((g2, q)) = score(ctx, cand, th, nl)
                        && g2 >= win.gain
                    {
                        win = Scored {
                            idx: win.idx,
                            theta: th,
                            gain: g2,
                            q,
                            delta_bic: delta_bic(n_eff, nl.rss0, g2, q),
                            cells: win.cells,
                        };
                    }
                }
            }
            let p_cols = (n_raw + nl.extra) as f64;
            let df2 = n_eff - p_cols - win.q as f64;
            let p_value = if df2 >= 1.0 {
                let rss1 = nl.rss0 - win.gain;
                let f = (win.gain / win.q as f64) / (rss1 / df2);
                FisherSnedecor::new(win.q as f64, df2).map_or(1.0, |d| d.sf(f))
            } else {
                1.0
            };
            if !(win.delta_bic > opts.min_delta_bic && p_value * (tried as f64) < opts.alpha) {
                break;
            }
            // The same bar under an AR(1) error model (slow noise: null_model::prewhitened_test),
            // where the held-out check is leave-one-block-out (it rewards a smooth term tracking
            // smooth noise); forward-validated (thermal-only) recordings keep the forward test as
            // their guard (on FL_THERMAL the extra test dropped every d3/d4 finding).
            if let Some(model) = &noise_model {
                let whitened = prewhitened_test(ctx, cand, win.theta, nl, n_raw + nl.extra, model);
                if !whitened.is_some_and(|(dbic, p)| {
                    dbic > opts.min_delta_bic && p * (tried as f64) < opts.alpha
                }) {
                    break;
                }
            }
            // What the term explains of the residual as it is (no nuisance): its importance and RMS.
            let plain_gain = score(ctx, cand, win.theta, &plain).map_or(0.0, |s| s.0);
            let rss1 = rss0 - plain_gain;
            let new_cols = cand.columns(ctx, win.theta);
            let mut trial = set_of(&terms);
            trial.push((cand, win.theta));
            let cv_after = cv_of(&trial);
            if cv_after.is_nan()
                || cv_after >= cv_before * (1.0 - opts.cv_min_gain)
                || !guard_ok(&trial, guard_before)
            {
                break;
            }
            // Ambiguity: another family, nearly as good, explaining the same shape.
            let win_contrib = contribution(ctx, cand, win.theta, &basis, r0);
            let wn = dot(&win_contrib, &win_contrib).sqrt();
            let ambiguous_with = scored
                .iter()
                .filter(|s| lib[s.idx].family() != cand.family())
                .filter(|s| {
                    s.delta_bic > opts.min_delta_bic
                        && win.delta_bic - s.delta_bic < opts.ambiguity_bic
                })
                .filter_map(|s| {
                    let sc = contribution(ctx, &lib[s.idx], s.theta, &basis, r0);
                    let corr = dot(&sc, &win_contrib) / (wn * dot(&sc, &sc).sqrt());
                    (corr > opts.ambiguity_corr).then(|| Alternative {
                        cand: lib[s.idx].clone(),
                        theta: s.theta,
                        delta_bic: s.delta_bic,
                        corr,
                    })
                })
                .collect();
            used[win.idx] = true;
            // Nested forms of the same family are not tried again once one is in.
            for (j, c) in lib.iter().enumerate() {
                if c.family() == cand.family()
                    && c.effect_id() != "reversal_spike"
                    && cand.effect_id() != "reversal_spike"
                {
                    used[j] = true;
                }
            }
            basis.extend(lsq::orthonormalize(&basis, new_cols.clone(), 2));
            n_raw += new_cols.len();
            first_choice.get_or_insert_with(|| (cand.label(), win.delta_bic));
            terms.push(Term {
                cand: cand.clone(),
                theta: win.theta,
                cols: new_cols,
                delta_bic: win.delta_bic,
                p_value,
                gain_rss: plain_gain,
                rms_after_um: (rss1 / n as f64).sqrt(),
                heldout_rms_before_um: cv_before,
                heldout_rms_after_um: cv_after,
                ambiguous_with,
                within_cells: win.cells,
            });
            cv_before = cv_after;
            guard_before = in_sample(&set_of(&terms));
        }
        // Exchange step (swap.rs), then forward selection again; at most two exchanges per signal.
        if terms.is_empty() || exchanges >= 2 {
            break;
        }
        // The terms' own columns, borrowed (a copy of them was the peak of a 1M-row diagnosis).
        let ones = vec![1.0; n];
        let mut refs: Vec<&[f64]> = vec![&ones];
        for t in &terms {
            refs.extend(t.cols.iter().map(Vec::as_slice));
        }
        let resid = lsq::fit(&refs, r).resid;
        // Only where structure is left that no candidate explains (the same test as the report's
        // "unexplained structure"): a clean fit is not revisited, which keeps the cost where it helps.
        if super::locate::unexplained(ctx, &format!("e{axis}_um"), &resid).is_empty() {
            break;
        }
        let n_eff = lsq::effective_n(&without_cell_means(ctx, axis, &resid));
        drop(resid);
        // The running basis is rebuilt after an exchange and not read without one: freed while
        // the exchange search builds its own (75 MB each on a 1M-row recording).
        drop(std::mem::take(&mut basis));
        let Some(ex) = super::swap::best_exchange(
            ctx,
            r,
            &lib,
            &terms,
            n_eff,
            tried,
            opts,
            cv_before,
            // The same guard as a new term: an exchange must not worsen the forward error
            // against the simulation as given (on FL_THERMAL d2 at 50 % an unguarded exchange
            // brought in T_3 + T_16 + T_8 and made the later rows 51 % worse).
            &|set: &[(&Candidate, f64)]| {
                if guard_ok(set, guard_before) {
                    cv_of(set)
                } else {
                    f64::INFINITY
                }
            },
        ) else {
            break;
        };
        exchanges += 1;
        let by = ex.terms.iter().map(|t| t.cand.label()).collect();
        let old = terms.remove(ex.k);
        terms.extend(ex.terms);
        let mut raw_cols = vec![vec![1.0; n]];
        for t in &terms {
            raw_cols.extend(t.cols.iter().cloned());
        }
        n_raw = raw_cols.len();
        basis = lsq::orthonormalize(&[], raw_cols, 2);
        let cv_after = cv_of(&set_of(&terms));
        exchanged.push(Exchanged {
            term: old,
            by,
            heldout_rms_before_um: cv_before,
            heldout_rms_after_um: cv_after,
        });
        cv_before = cv_after;
        guard_before = in_sample(&set_of(&terms));
        used = vec![false; lib.len()];
        for t in &terms {
            for (j, c) in lib.iter().enumerate() {
                if c.kind == t.cand.kind
                    || (c.family() == t.cand.family()
                        && c.effect_id() != "reversal_spike"
                        && t.cand.effect_id() != "reversal_spike")
                {
                    used[j] = true;
                }
            }
        }
    }
    SignalSelection {
        axis,
        n,
        terms,
        runners_up,
        tried,
        first_choice,
        exchanged,
    }
}

#[cfg(test)]
mod tests;
