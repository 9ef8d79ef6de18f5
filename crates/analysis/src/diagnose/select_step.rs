//! One signal's forward selection as named steps on its state ([`Selector`], driven by
//! [`super::select::select`], whose module comment describes the method): screen every candidate
//! against the step's nulls, put them on one scale (n_eff, the slow-noise model), choose and
//! refine the winner, test it, append it. The exchange step is in `select.rs`.
//! Residuals are measured − sim, µm.

use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::candidates::{Candidate, Kind, library};
use super::features::{Context, lowpass, power_of};
use super::heldout::Heldout;
use super::lsq::{self, dot};
use super::null_model::{
    NoiseModel, Null, contribution, delta_bic, prewhitened_test, score, within_cells,
};
use super::selection::{Alternative, Exchanged, Options, Term, set_of};

mod noise;
mod peaks;
mod screen;

/// Share of the best thermal ΔBIC a driver-column lag needs to be preferred over a sensor.
const DRIVER_SHARE: f64 = 0.0;

/// A thermal candidate read from a driver column (`rpm`, a column with no docs/recording-csv.md role), not a
/// temperature sensor.
fn is_driver(ctx: &Context, c: &Candidate) -> bool {
    match &c.kind {
        Kind::ThermalLag { sensor } | Kind::ThermalDrift { sensor } => {
            ctx.drivers().iter().any(|(n, _)| n == sensor)
        }
        _ => false,
    }
}

/// Residual RMS (µm) below which nothing is left to explain (see [`Selector::step`]).
const ROUNDING_FLOOR_UM: f64 = 1e-6;

/// How many of a step's strongest candidates compete on forward held-out error.
const FORWARD_CHOICES: usize = 8;

/// The first step's screening of one signal (every candidate against the intercept alone), kept
/// from the unit-root pre-pass (`select::unit_root_taus`) so selection does not screen again: the
/// screening is most of a step's cost (9 s of a 1M-row diagnosis).
#[derive(Debug)]
pub struct FirstScreen(Vec<Scored>);

#[derive(Debug)]
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

/// The state of one signal's selection between steps.
pub(super) struct Selector<'a> {
    pub(super) ctx: &'a Context,
    pub(super) axis: char,
    pub(super) r: &'a [f64],
    pub(super) opts: &'a Options,
    pub(super) lib: Vec<Candidate>,
    /// (candidate, grid value) pairs tried per step: the Holm factor.
    pub(super) tried: usize,
    cell_of: Option<(Vec<usize>, usize)>,
    /// Held-out error (forward on thermal tests, both feeding modes): `heldout.rs`.
    heldout: Heldout<'a>,
    /// Whether the recording as a whole rejects a unit root (`NoiseModel::of`).
    recording_rejects: Option<bool>,
    /// The first step's screening, done once by the unit-root pre-pass ([`FirstScreen`]).
    first_screen: Option<Vec<Scored>>,
    pub(super) basis: Vec<Vec<f64>>,
    /// Raw columns fitted so far (intercept + every term's): only their count is needed (the
    /// columns themselves are in `terms`; a copy was 8 MB a column on a 1M-row recording).
    pub(super) n_raw: usize,
    pub(super) terms: Vec<Term>,
    pub(super) runners_up: Vec<(Candidate, f64)>,
    pub(super) used: Vec<bool>,
    pub(super) cv_before: f64,
    /// The in-sample guard's score of the terms so far ([`Selector::guard_ok`]).
    pub(super) guard_before: f64,
    pub(super) exchanges: usize,
    pub(super) first_choice: Option<(String, f64)>,
    pub(super) exchanged: Vec<Exchanged>,
}

/// A step's two nulls: plain, and with the own-axis position-cell means (`cells_ok`: usable).
struct Nulls<'b> {
    plain: Null<'b>,
    cells: Null<'b>,
    cells_ok: bool,
}

impl<'b> Nulls<'b> {
    fn of(&self, blocked: bool) -> &Null<'b> {
        if blocked { &self.cells } else { &self.plain }
    }
}

/// A step's winner that passed every test, ready to be appended.
struct Accepted {
    win: Scored,
    p_value: f64,
    plain_gain: f64,
    rss1: f64,
    cv_after: f64,
    ambiguous_with: Vec<Alternative>,
}

impl<'a> Selector<'a> {
    pub(super) fn new(
        ctx: &'a Context,
        axis: char,
        r: &'a [f64],
        sim_inputs: &'a [Vec<f64>],
        opts: &'a Options,
        recording_rejects: Option<bool>,
        first_screen: Option<FirstScreen>,
    ) -> Self {
        let lib = library(ctx, axis);
        // The cyclic family's periodogram is one scan: the second-harmonic form tests the same
        // fundamental periods as the pure sine (nested, not further hypotheses).
        let mut tried: usize = lib
            .iter()
            .filter(|c| c.kind != Kind::CyclicHarmonic)
            .map(|c| c.grid.len().max(1))
            .sum();
        let cell_of = ctx.position_cells(axis);
        if cell_of.is_some() {
            tried += lib.iter().filter(|c| within_cells(c)).count();
        }
        let heldout = Heldout::new(ctx, axis, r, sim_inputs, opts);
        let used = vec![false; lib.len()];
        let mut s = Selector {
            ctx,
            axis,
            r,
            opts,
            lib,
            tried,
            cell_of,
            heldout,
            recording_rejects,
            first_screen: first_screen.map(|f| f.0),
            basis: lsq::orthonormalize(&[], vec![vec![1.0; r.len()]], 2),
            n_raw: 1,
            terms: vec![],
            runners_up: vec![],
            used,
            cv_before: 0.0,
            guard_before: 0.0,
            exchanges: 0,
            first_choice: None,
            exchanged: vec![],
        };
        s.cv_before = s.cv(&[]);
        s.guard_before = s.in_sample(&[]);
        s
    }

    pub(super) fn cv(&self, set: &[(&Candidate, f64)]) -> f64 {
        self.heldout.rms(set)
    }

    pub(super) fn in_sample(&self, set: &[(&Candidate, f64)]) -> f64 {
        self.heldout.rms_in_sample(set)
    }

    /// The guard when the simulation is refitted per fold: the written model keeps the
    /// simulation's gains as given (fitted on every row) and adds the term's gain fitted on that
    /// residual, so a term must not make THAT model predict later blocks worse. A term can win the
    /// refitted score by standing in for a change of the simulation's gains (a sensor collinear
    /// with the simulation's, e.g. FL_THERMAL's T_8 on d1/d2): the model as written does not get
    /// that change, only the term. Without simulation inputs both scores are the same.
    pub(super) fn guard_ok(&self, set: &[(&Candidate, f64)], before: f64) -> bool {
        !self.heldout.refits_sim() || self.in_sample(set) <= before
    }

    /// Held-out RMS (µm) of the terms so far plus `s`, or `None` when adding `s` fails the
    /// in-sample guard.
    fn guarded_cv(&self, s: &Scored) -> Option<f64> {
        let trial = self.trial(s);
        self.guard_ok(&trial, self.guard_before)
            .then(|| self.cv(&trial))
    }

    /// The terms so far plus scored candidate `s`.
    fn trial(&self, s: &Scored) -> Vec<(&Candidate, f64)> {
        let mut trial = set_of(&self.terms);
        trial.push((&self.lib[s.idx], s.theta));
        trial
    }

    /// One forward-selection step; false when no term passes (selection goes to the exchange).
    pub(super) fn step(&mut self) -> bool {
        let r0 = lsq::deflate(&self.basis, self.r);
        let rss0 = dot(&r0, &r0);
        // A residual below a picometre RMS is the rounding of the error and simulation columns
        // (a model that states the error exactly), not a measurement: with periods scanned down
        // to 2 samples a cyclic term fitted the rounding pattern of integer positions.
        if rss0.is_nan() || rss0 <= (ROUNDING_FLOOR_UM * ROUNDING_FLOOR_UM) * self.r.len() as f64 {
            return false;
        }
        // The pre-pass screened against the same null (intercept alone, nothing used).
        let first = self.first_screen.take().filter(|_| self.terms.is_empty());
        let nulls = self.nulls(r0, rss0);
        let mut scored = first.unwrap_or_else(|| self.screen(&nulls));
        if scored.is_empty() {
            return false;
        }
        let (n_eff, noise_model) = self.scale(&scored, &nulls);
        for s in &mut scored {
            s.delta_bic = delta_bic(n_eff, nulls.of(s.cells).rss0, s.gain, s.q);
        }
        self.refine_cyclic_peaks(&mut scored, &nulls, n_eff);
        scored.sort_by(|a, b| b.delta_bic.total_cmp(&a.delta_bic));
        // A candidate screened under both nulls keeps its better one.
        let mut seen = vec![false; self.lib.len()];
        scored.retain(|s| !std::mem::replace(&mut seen[s.idx], true));
        let runners_up = self.terms.is_empty().then(|| {
            scored
                .iter()
                .map(|s| (self.lib[s.idx].clone(), s.delta_bic))
                .collect()
        });
        let acc = self.choose(scored, &nulls, n_eff, noise_model.as_ref());
        drop(nulls);
        if let Some(runners_up) = runners_up {
            self.runners_up = runners_up;
        }
        let Some(acc) = acc else {
            return false;
        };
        self.accept(acc);
        true
    }

    /// The step's nulls: the fitted terms, and the same plus the position-cell means.
    fn nulls(&self, r0: Vec<f64>, rss0: f64) -> Nulls<'_> {
        let basis = &self.basis;
        let plain = Null {
            basis: basis.as_slice().into(),
            r0,
            rss0,
            extra: 0,
            cells: None,
        };
        let cells = match &self.cell_of {
            Some((cell, k)) => Null::within_cells(basis, self.r, cell, *k),
            None => Null {
                basis: vec![].into(),
                r0: vec![],
                rss0: 0.0,
                extra: 0,
                cells: None,
            },
        };
        let cells_ok =
            cells.extra > 0 && cells.rss0 > 0.0 && self.r.len() > basis.len() + cells.extra + 3;
        Nulls {
            plain,
            cells,
            cells_ok,
        }
    }

    /// The step's winner among the ranked `scored`, refined and tested; `None` ends the forward
    /// selection.
    fn choose(
        &self,
        mut scored: Vec<Scored>,
        nulls: &Nulls<'_>,
        n_eff: f64,
        noise_model: Option<&NoiseModel>,
    ) -> Option<Accepted> {
        let opts = self.opts;
        if self.heldout.forward {
            self.forward_choice(&mut scored);
        }
        self.prefer_driver(&mut scored);
        self.prefer_power(&mut scored);
        self.prefer_simpler(&mut scored);
        // Slow noise where the held-out check is leave-one-block-out (see below): the
        // strongest candidate that also passes the bar under the noise model
        // (null_model::prewhitened_test) is the step's winner, so a spurious smooth term
        // ranked above a real effect does not end the step.
        if let Some(model) = noise_model {
            let j = scored
                .iter()
                .take(FORWARD_CHOICES)
                .take_while(|s| s.delta_bic > opts.min_delta_bic)
                .position(|s| self.passes_whitened(s, nulls.of(s.cells), model))?;
            let s = scored.remove(j);
            scored.insert(0, s);
        }
        let win = scored.remove(0);
        let nl = nulls.of(win.cells);
        let win = self.refine(win, nl, n_eff);
        let cand = &self.lib[win.idx];
        let p_cols = (self.n_raw + nl.extra) as f64;
        let df2 = n_eff - p_cols - win.q as f64;
        let p_value = if df2 >= 1.0 {
            let rss1 = nl.rss0 - win.gain;
            let f = (win.gain / win.q as f64) / (rss1 / df2);
            FisherSnedecor::new(win.q as f64, df2).map_or(1.0, |d| d.sf(f))
        } else {
            1.0
        };
        // A reversal term's column changes only in steps at the reversals: under slow noise
        // its information is in those steps, which the GLS test below sees and the plain fit's
        // n_eff (a mean's information) does not (AR(0.99) step-and-dwell backlash at effect/noise
        // 3: plain p·tried 0.011, GLS test passed). Its F-test is the GLS one there.
        let p_bar = match noise_model {
            Some(m) if cand.family() == "reversal" => {
                prewhitened_test(self.ctx, cand, win.theta, nl, self.n_raw + nl.extra, m)
                    .map_or(1.0, |(_, p)| p)
            }
            _ => p_value,
        };
        if !(win.delta_bic > opts.min_delta_bic && p_bar * (self.tried as f64) < opts.alpha) {
            return None;
        }
        // The same bar under an AR(1) error model (slow noise: null_model::prewhitened_test),
        // where the held-out check is leave-one-block-out (it rewards a smooth term tracking
        // smooth noise); forward-validated (thermal-only) recordings keep the forward test as
        // their guard (on FL_THERMAL the extra test dropped every d3/d4 finding).
        if let Some(model) = noise_model
            && !self.passes_whitened(&win, nl, model)
        {
            return None;
        }
        // What the term explains of the residual as it is (no nuisance): its importance and RMS.
        let plain_gain = score(self.ctx, cand, win.theta, &nulls.plain).map_or(0.0, |s| s.0);
        let rss1 = nulls.plain.rss0 - plain_gain;
        let cv_after = self
            .guarded_cv(&win)
            .filter(|cv| *cv < self.cv_before * (1.0 - opts.cv_min_gain))?;
        let ambiguous_with = self.ambiguous_with(&win, &scored, &nulls.plain.r0);
        Some(Accepted {
            win,
            p_value,
            plain_gain,
            rss1,
            cv_after,
            ambiguous_with,
        })
    }

    /// The bar (ΔBIC and the Holm-corrected F-test) under the step's noise model.
    fn passes_whitened(&self, s: &Scored, nl: &Null<'_>, model: &NoiseModel) -> bool {
        let c = &self.lib[s.idx];
        prewhitened_test(self.ctx, c, s.theta, nl, self.n_raw + nl.extra, model).is_some_and(
            |(dbic, p)| dbic > self.opts.min_delta_bic && p * (self.tried as f64) < self.opts.alpha,
        )
    }

    /// With forward folds, the strong candidates (ΔBIC above the bar, at most FORWARD_CHOICES of
    /// them) compete on forward held-out error: the one that best predicts later blocks from
    /// earlier ones wins, not the best in-sample fit (a sensor with a large gain fits a warm-up
    /// well and extrapolates badly).
    fn forward_choice(&self, scored: &mut Vec<Scored>) {
        let k = scored
            .iter()
            .take(FORWARD_CHOICES)
            .take_while(|s| s.delta_bic > self.opts.min_delta_bic)
            .count();
        if let Some(best) = (0..k)
            .filter_map(|i| Some((i, self.guarded_cv(&scored[i])?)))
            .filter(|(_, v)| v.is_finite())
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i)
        {
            let s = scored.remove(best);
            scored.insert(0, s);
        }
    }

    /// Heat source before its symptoms: when the winner is a thermal term read from a
    /// temperature sensor and a driver column (rpm, or a named heat source) explains the
    /// same family with strong evidence of its own (ΔBIC above the bar), the driver's lag
    /// is taken. A sensor is itself a lagged response of the source; the source term
    /// extrapolates to regimes the fit never saw (another spindle speed), a re-weighted
    /// sensor with a large gain does not. The sensor stays a candidate for what is left.
    fn prefer_driver(&self, scored: &mut Vec<Scored>) {
        let (ctx, lib, opts) = (self.ctx, &self.lib, self.opts);
        if lib[scored[0].idx].family() != "thermal_offset" || is_driver(ctx, &lib[scored[0].idx]) {
            return;
        }
        let top = scored[0].delta_bic;
        // Validated leave-one-block-out (recordings with axes), the driver must also
        // predict the held-out blocks no worse than the sensor: a measured temperature
        // that is the true input (a node heated by friction as well as by the spindle)
        // is not replaced by a lag of rpm that only resembles it. Forward-validated
        // recordings chose the winner by forward error already.
        let sensor_cv = if self.heldout.forward {
            f64::INFINITY
        } else {
            self.cv(&self.trial(&scored[0]))
        };
        let passes_heldout = |s: &Scored| {
            self.guarded_cv(s).is_some_and(|cv| {
                cv < self.cv_before * (1.0 - opts.cv_min_gain)
                    && cv < sensor_cv * (1.0 - opts.cv_min_gain)
            })
        };
        if let Some(j) = scored.iter().position(|s| {
            is_driver(ctx, &lib[s.idx])
                && s.delta_bic > opts.min_delta_bic
                && s.delta_bic >= DRIVER_SHARE * top
                && passes_heldout(s)
        }) {
            let s = scored.remove(j);
            scored.insert(0, s);
        }
    }

    /// The form of one driver: when the winner is a lag of a driver column read as it is (or
    /// through a power) and the same column through a power (or as it is: `rpm` ↔ `krpm^2`,
    /// `<name>_A` ↔ `<name>_A^2`, [`power_of`]) fits clearly better in-sample (ΔBIC above the
    /// winner's by the ambiguity margin; the two have the same parameters, so that is a
    /// likelihood ratio), that form is taken. Forward folds chose the driver; they restart the
    /// lag states at each block's first row, an error of the order of what separates I from I²
    /// when τ is long, so they cannot choose the exponent (issue 36 point 5: I² heating found
    /// as a lag of I with τ off by 15–37 %). The form taken must still pass the forward gate.
    fn prefer_power(&self, scored: &mut Vec<Scored>) {
        let (ctx, lib, opts) = (self.ctx, &self.lib, self.opts);
        let column_of = |c: &Candidate| match &c.kind {
            Kind::ThermalLag { sensor } if is_driver(ctx, c) => {
                Some(power_of(sensor).map_or(sensor.clone(), |(col, ..)| col.to_string()))
            }
            _ => None,
        };
        let win = &lib[scored[0].idx];
        let Some(column) = column_of(win) else {
            return;
        };
        let bar = scored[0].delta_bic + opts.ambiguity_bic;
        if let Some(j) = scored.iter().position(|s| {
            let c = &lib[s.idx];
            c.label() != win.label()
                && column_of(c).as_deref() == Some(column.as_str())
                && s.delta_bic > bar
                && self.guarded_cv(s).is_some()
        }) {
            let s = scored.remove(j);
            scored.insert(0, s);
        }
    }

    /// Parsimony between the two thermal forms: when the winner is a lag (gain and τ) and a
    /// reading taken as it is (`thermal_drift`, gain only) is nearly as strong (ΔBIC within the
    /// ambiguity margin) and predicts the held-out data as well (within `cv_min_gain`), the
    /// drift is taken. A lag that wins in-sample by smoothing a sensor's own 0.1 °C steps or its
    /// few seconds of lag, or a lag of `rpm` that equals a measured temperature, is not evidence
    /// that the error lags that temperature. When the lag stays within the reading's resolution
    /// ([`within_resolution`]) the two are the same term as far as the sensor can tell: the drift
    /// of that reading is taken whenever it passes the bar itself (ΔBIC; the held-out gate
    /// follows in `choose`), with no margin. The lag's edge there is the smoothing of the steps
    /// (a regressor read with error), worth a few % of held-out error, not a time constant.
    fn prefer_simpler(&self, scored: &mut Vec<Scored>) {
        let (lib, opts) = (&self.lib, self.opts);
        let Kind::ThermalLag { sensor: lagged } = &lib[scored[0].idx].kind else {
            return;
        };
        let top = scored[0].delta_bic;
        let drift_of_lagged = |s: &Scored| {
            matches!(&lib[s.idx].kind, Kind::ThermalDrift { sensor } if sensor == lagged)
                && s.delta_bic > opts.min_delta_bic
        };
        // The lag's column is computed only when the same reading's drift passes the bar.
        let same_reading = scored.iter().any(drift_of_lagged)
            && within_resolution(self.ctx, lagged, scored[0].theta);
        let same = |s: &Scored| same_reading && drift_of_lagged(s);
        let near = |s: &Scored| {
            matches!(lib[s.idx].kind, Kind::ThermalDrift { .. })
                && s.delta_bic > opts.min_delta_bic
                && (top - s.delta_bic < opts.ambiguity_bic || same(s))
        };
        // The winner's held-out error only when some drift is near enough to need it.
        if !scored.iter().any(near) {
            return;
        }
        let top_cv = self.cv(&self.trial(&scored[0]));
        if let Some(j) = scored.iter().position(|s| {
            near(s)
                && self
                    .guarded_cv(s)
                    .is_some_and(|cv| same(s) || cv <= top_cv * (1.0 + opts.cv_min_gain))
        }) {
            let s = scored.remove(j);
            scored.insert(0, s);
        }
    }

    /// Ambiguity: another family, nearly as good, explaining the same shape.
    fn ambiguous_with(&self, win: &Scored, scored: &[Scored], r0: &[f64]) -> Vec<Alternative> {
        let (ctx, lib, opts) = (self.ctx, &self.lib, self.opts);
        let cand = &lib[win.idx];
        let win_contrib = contribution(ctx, cand, win.theta, &self.basis, r0);
        let wn = dot(&win_contrib, &win_contrib).sqrt();
        scored
            .iter()
            .filter(|s| lib[s.idx].family() != cand.family())
            .filter(|s| {
                s.delta_bic > opts.min_delta_bic && win.delta_bic - s.delta_bic < opts.ambiguity_bic
            })
            .filter_map(|s| {
                let sc = contribution(ctx, &lib[s.idx], s.theta, &self.basis, r0);
                let corr = dot(&sc, &win_contrib) / (wn * dot(&sc, &sc).sqrt());
                (corr > opts.ambiguity_corr).then(|| Alternative {
                    cand: lib[s.idx].clone(),
                    theta: s.theta,
                    delta_bic: s.delta_bic,
                    corr,
                })
            })
            .collect()
    }

    /// Append the step's winner: mark its family used, extend the basis, record the term.
    fn accept(&mut self, acc: Accepted) {
        let win = &acc.win;
        let cand = self.lib[win.idx].clone();
        let new_cols = cand.columns(self.ctx, win.theta);
        self.used[win.idx] = true;
        // Nested forms of the same family are not tried again once one is in.
        for (j, c) in self.lib.iter().enumerate() {
            if c.family() == cand.family()
                && c.effect_id() != "reversal_spike"
                && cand.effect_id() != "reversal_spike"
            {
                self.used[j] = true;
            }
        }
        let more = lsq::orthonormalize(&self.basis, new_cols.clone(), 2);
        self.basis.extend(more);
        self.n_raw += new_cols.len();
        self.first_choice
            .get_or_insert_with(|| (cand.label(), win.delta_bic));
        self.terms.push(Term {
            cand,
            theta: win.theta,
            cols: new_cols,
            delta_bic: win.delta_bic,
            p_value: acc.p_value,
            gain_rss: acc.plain_gain,
            rms_after_um: (acc.rss1 / self.r.len() as f64).sqrt(),
            heldout_rms_before_um: self.cv_before,
            heldout_rms_after_um: acc.cv_after,
            within_cells: win.cells,
            ambiguous_with: acc.ambiguous_with,
        });
        self.cv_before = acc.cv_after;
        self.guard_before = self.in_sample(&set_of(&self.terms));
    }
}

/// Whether a first-order lag (τ = `tau_s`) of column `sensor` departs from the reading itself by
/// less than the reading's resolution (RMS over the record below its smallest step, e.g. 0.1 °C):
/// such a lag cannot be told from the reading by this sensor.
fn within_resolution(ctx: &Context, sensor: &str, tau_s: f64) -> bool {
    let (Some(u), Some(q)) = (ctx.temp(sensor), ctx.resolution(sensor)) else {
        return false;
    };
    let ss: f64 = lowpass(&ctx.t_s, u, tau_s)
        .iter()
        .zip(u)
        .map(|(y, v)| (y - v).powi(2))
        .sum();
    (ss / u.len() as f64).sqrt() < q
}
