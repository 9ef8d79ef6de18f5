//! Thermal terms (a)–(e) and the per-sensor first-order lag state (d).
//!
//! Temperatures are °C; ΔT_i = T_i(lagged) − reference_C_i. A term's value is in its target's unit
//! (µm or µrad); positions are mm. The lag is the exact discretisation of τ·dT'/dt = T − T':
//! T' += (1 − e^(−Δt/τ)) · (T − T'), so the result does not depend on the step size for a constant
//! input, and a reading held for Δt ≫ τ is reached.

use super::spec::{SensorSpec, ThermalKind};

/// Lag states, one per sensor.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ThermalState {
    /// Lagged temperature per sensor, °C; meaningful once `started[i]` (see [`Self::lagged_c`]).
    /// Plain floats plus flags rather than `Option<f64>` so the usual step is one straight loop
    /// over contiguous floats.
    lagged: Vec<f64>,
    started: Vec<bool>,
    /// Every sensor has had a valid reading (then no per-sensor start check is needed).
    all_started: bool,
    /// ΔT per sensor used by the last evaluation (0 while a sensor has never been read).
    pub delta_c: Vec<f64>,
    pub last_t_s: Option<f64>,
    /// (Δt, 1 − e^(−Δt/τ)) of the last step per sensor: avoids an `exp` per sample at a fixed rate.
    alpha_cache: Vec<(f64, f64)>,
    /// The plan's cache for its usual step (all sensors read, all started; `step_planned`): the Δt₀
    /// shared by every sensor (NaN = none yet) and e^(−Δt₀/τ) per sensor (0 for a sensor without
    /// lag: the share of the old state that survives one step).
    shared_dt0: f64,
    shared_keep0: Vec<f64>,
}

/// What stepping found wrong with the inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct StepIssues {
    pub missing_temperature: bool,
    pub time_backwards: bool,
}

impl ThermalState {
    pub(crate) fn new(n: usize) -> Self {
        ThermalState {
            lagged: vec![0.0; n],
            started: vec![false; n],
            all_started: n == 0,
            delta_c: vec![0.0; n],
            last_t_s: None,
            alpha_cache: vec![(f64::NAN, 0.0); n],
            shared_dt0: f64::NAN,
            shared_keep0: vec![0.0; n],
        }
    }

    /// Number of sensors.
    pub fn len(&self) -> usize {
        self.lagged.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lagged.is_empty()
    }

    /// Lagged temperature of sensor `i`, °C (`None` until its first valid reading or for an
    /// index past the end).
    pub fn lagged_c(&self, i: usize) -> Option<f64> {
        self.started
            .get(i)
            .copied()
            .unwrap_or(false)
            .then(|| self.lagged[i])
    }

    /// [`lagged_c`](Self::lagged_c)`(i)`, or `default_c` without one; once every sensor has started
    /// (the usual case) one flag answers instead of sensor i's own.
    #[inline]
    pub(crate) fn lagged_or_c(&self, i: usize, default_c: f64) -> f64 {
        if self.all_started
            && let Some(&l) = self.lagged.get(i)
        {
            return l;
        }
        self.lagged_c(i).unwrap_or(default_c)
    }

    fn set_lagged(&mut self, i: usize, v: f64) {
        self.lagged[i] = v;
        if !self.started[i] {
            self.started[i] = true;
            self.all_started = self.started.iter().all(|&s| s);
        }
    }

    /// Start sensor `i`'s lag from `lagged` (its input unit) as of recording time `t_s`: the next
    /// step advances it from there with Δt = t − `t_s`, the step's reading held over that span.
    /// Sets the time of the last step for every sensor; sensors not resumed start at their first
    /// reading as usual.
    pub(crate) fn resume(&mut self, i: usize, lagged: f64, t_s: f64) {
        self.set_lagged(i, lagged);
        self.last_t_s = Some(t_s);
    }

    /// (Δt since the last step or `None`, issues); records `t_s` unless time went backwards.
    fn advance_time(&mut self, t_s: f64) -> (Option<f64>, StepIssues) {
        let mut issues = StepIssues::default();
        let dt = match self.last_t_s {
            Some(last) if t_s < last => {
                issues.time_backwards = true;
                None
            }
            Some(last) => Some(t_s - last),
            None => None,
        };
        if !issues.time_backwards {
            self.last_t_s = Some(t_s);
        }
        (dt, issues)
    }

    /// Advance every lag to `t_s` with readings `temps_c` (by sensor index). A missing or non-finite
    /// reading holds that sensor's state; time going backwards holds all states and is reported.
    pub(crate) fn step(&mut self, sensors: &[SensorSpec], temps_c: &[f64], t_s: f64) -> StepIssues {
        if self.len() != sensors.len() {
            *self = ThermalState::new(sensors.len());
        }
        let (dt, mut issues) = self.advance_time(t_s);
        for (i, s) in sensors.iter().enumerate() {
            let reading = temps_c
                .get(i)
                .copied()
                .filter(|t| t.is_finite())
                .map(|t| s.input(t));
            let Some(t) = reading else {
                issues.missing_temperature = true;
                self.delta_c[i] = self.lagged_c(i).map_or(0.0, |l| l - s.reference_c);
                continue;
            };
            let new = match (self.lagged_c(i), s.tau_s, dt) {
                (None, _, _) | (_, None, _) => t,
                (Some(prev), Some(tau), Some(dt)) => {
                    let alpha = lag_alpha(&mut self.alpha_cache[i], dt, tau);
                    prev + alpha * (t - prev)
                }
                (Some(prev), Some(_), None) => prev,
            };
            self.set_lagged(i, new);
            self.delta_c[i] = new - s.reference_c;
        }
        issues
    }
}

/// Per-sensor lag constants in the layout [`ThermalState::step_planned`] reads: the reference
/// temperature, and τ with 1/τ (`None` = the sensor is used as read).
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct LagPlan {
    reference_c: Vec<f64>,
    lag: Vec<Option<(f64, f64)>>,
    /// 1/τ, 0 for a sensor without lag (its kept share e^(−Δt/τ) is then exactly 0).
    inv_tau_or_0: Vec<f64>,
    /// Per sensor the power of its reading the lag follows (`None` = the reading).
    exponent: Vec<Option<f64>>,
    /// Some sensor has an exponent: the step takes the per-sensor path (the vector path reads the
    /// readings as they are).
    any_exponent: bool,
}

impl LagPlan {
    pub(crate) fn new(sensors: &[SensorSpec]) -> Self {
        LagPlan {
            reference_c: sensors.iter().map(|s| s.reference_c).collect(),
            lag: sensors
                .iter()
                .map(|s| s.tau_s.map(|tau| (tau, 1.0 / tau)))
                .collect(),
            inv_tau_or_0: sensors
                .iter()
                .map(|s| s.tau_s.map_or(0.0, |tau| 1.0 / tau))
                .collect(),
            exponent: sensors.iter().map(|s| s.exponent).collect(),
            any_exponent: sensors.iter().any(|s| s.exponent.is_some()),
        }
    }
}

impl ThermalState {
    /// [`step`](Self::step) for the evaluation plan: the same rules and results (to the rounding of
    /// one multiplication by 1/τ instead of a division per sensor), from flat per-sensor constants.
    pub(crate) fn step_planned(&mut self, p: &LagPlan, temps_c: &[f64], t_s: f64) -> StepIssues {
        let n = p.reference_c.len();
        if self.len() != n {
            *self = ThermalState::new(n);
        }
        let (dt, mut issues) = self.advance_time(t_s);
        // The usual step: forward in time, every reading present and finite, every lag started.
        // One Δt₀ serves all sensors (they all see the same Δt), so the loop below has no branch.
        if let Some(dt) = dt
            && !p.any_exponent
            && self.all_started
            && let Some(temps) = temps_c.get(..n)
            && temps.iter().fold(true, |ok, t| ok & t.is_finite())
        {
            let mut d = dt - self.shared_dt0;
            if d.is_nan() || d.abs() > 1e-6 * self.shared_dt0 {
                for (k0, lag) in self.shared_keep0.iter_mut().zip(&p.lag) {
                    *k0 = lag.map_or(0.0, |(tau, _)| (-dt / tau).exp());
                }
                self.shared_dt0 = dt;
                d = 0.0;
            }
            lag_step_all(
                &mut self.lagged,
                &mut self.delta_c,
                &self.shared_keep0,
                &p.inv_tau_or_0,
                &p.reference_c,
                temps,
                d,
            );
            return issues;
        }
        for (i, (&reference_c, lag)) in p.reference_c.iter().zip(&p.lag).enumerate() {
            let Some(t) = temps_c
                .get(i)
                .copied()
                .filter(|t| t.is_finite())
                .map(|t| super::spec::power_input(p.exponent[i], t))
            else {
                issues.missing_temperature = true;
                self.delta_c[i] = self.lagged_c(i).map_or(0.0, |l| l - reference_c);
                continue;
            };
            let new = match (self.lagged_c(i), lag, dt) {
                (None, _, _) | (_, None, _) => t,
                (Some(prev), Some((tau, inv_tau)), Some(dt)) => {
                    prev + lag_alpha_inv(&mut self.alpha_cache[i], dt, *tau, *inv_tau) * (t - prev)
                }
                (Some(prev), Some(_), None) => prev,
            };
            self.set_lagged(i, new);
            self.delta_c[i] = new - reference_c;
        }
        issues
    }
}

/// The usual lag step for every sensor (all read, all started). A function of separate slices so
/// the compiler knows they do not overlap and runs the loop on vector registers.
#[inline(always)]
fn lag_step_all(
    lagged: &mut [f64],
    delta_c: &mut [f64],
    keep0: &[f64],
    inv_tau: &[f64],
    reference_c: &[f64],
    temps: &[f64],
    d: f64,
) {
    let n = lagged.len();
    let (delta_c, keep0, inv_tau) = (&mut delta_c[..n], &keep0[..n], &inv_tau[..n]);
    let (reference_c, temps) = (&reference_c[..n], &temps[..n]);
    for i in 0..n {
        // Kept share e^(−Δt/τ) = e^(−Δt₀/τ)·e^(−x), x = (Δt − Δt₀)/τ, as in `lag_alpha`; written
        // T' = T + keep·(T'₀ − T) so that no lag (keep = 0) gives the reading exactly.
        let x = d * inv_tau[i];
        let keep = keep0[i] * (1.0 - x * (1.0 - x * (0.5 - x * (1.0 / 6.0))));
        let t = temps[i];
        let new = t + keep * (lagged[i] - t);
        lagged[i] = new;
        delta_c[i] = new - reference_c[i];
    }
}

/// [`lag_alpha`] with x = (Δt − Δt₀) · (1/τ) instead of a division.
#[inline]
fn lag_alpha_inv(cache: &mut (f64, f64), dt: f64, tau: f64, inv_tau: f64) -> f64 {
    let (dt0, alpha0) = *cache;
    let d = dt - dt0;
    if d.abs() <= 1e-6 * dt0 {
        let x = d * inv_tau;
        alpha0 + (1.0 - alpha0) * (x * (1.0 - x * (0.5 - x * (1.0 / 6.0))))
    } else {
        let alpha = super::lag::alpha(dt, tau);
        *cache = (dt, alpha);
        alpha
    }
}

/// α = 1 − e^(−Δt/τ) for this step, from the sensor's cache (Δt₀, α₀) of the last `exp`.
///
/// Sample times at a fixed rate differ by float rounding (t = k·1 ms at t ≈ 1000 s jitters Δt by
/// ~1e-10 relative), so an exact-match cache would call `exp` on almost every sample. For
/// |Δt − Δt₀| ≤ 1e-6·Δt₀ the step is corrected instead: with x = (Δt − Δt₀)/τ,
/// α = 1 − (1 − α₀)·e^(−x) = α₀ + (1 − α₀)·(x − x²/2 + x³/6), whose truncation (x⁴/24 ≤ 1e-24·(Δt/τ)⁴)
/// is far below one rounding of α. (The cache starts as NaN, which never counts as near.)
#[inline]
fn lag_alpha(cache: &mut (f64, f64), dt: f64, tau: f64) -> f64 {
    let (dt0, alpha0) = *cache;
    let d = dt - dt0;
    if d.abs() <= 1e-6 * dt0 {
        let x = d / tau;
        alpha0 + (1.0 - alpha0) * (x * (1.0 - x * (0.5 - x * (1.0 / 6.0))))
    } else {
        let alpha = super::lag::alpha(dt, tau);
        *cache = (dt, alpha);
        alpha
    }
}

/// Σ_i Σ_j c_ij x_i x_j over the term's sensor list.
#[inline]
fn quadratic(c: &[Vec<f64>], idx: &[usize], dt: &[f64]) -> f64 {
    let mut acc = 0.0;
    for (i, row) in c.iter().enumerate() {
        let xi = dt[idx[i]];
        for (j, cij) in row.iter().enumerate() {
            acc += cij * xi * dt[idx[j]];
        }
    }
    acc
}

#[inline]
fn linear(b: &[f64], idx: &[usize], dt: &[f64]) -> f64 {
    b.iter().zip(idx).map(|(bi, &i)| bi * dt[i]).sum()
}

/// Value of one thermal term. `idx` maps the term's sensors to model sensor indices; `lagged_abs_c`
/// gives absolute lagged temperatures for the expansion term; `q_target_mm` is the target axis'
/// position, `q_along_mm` the stations axis' position. Returns (value, clamped).
#[inline]
pub(crate) fn thermal_value(
    kind: &ThermalKind,
    idx: &[usize],
    delta_c: &[f64],
    abs_c: f64,
    q_target_mm: f64,
    q_along_mm: f64,
) -> (f64, bool) {
    match kind {
        ThermalKind::PolynomialDt {
            e0,
            b_per_k,
            c_per_k2,
            ..
        } => (
            e0 + linear(b_per_k, idx, delta_c) + quadratic(c_per_k2, idx, delta_c),
            false,
        ),
        ThermalKind::Slope {
            s0_per_mm,
            s_per_mm_k,
            d_per_mm_k2,
            ..
        } => {
            // Coefficients are per metre of travel: q_mm · 1e-3 m/mm.
            let slope =
                s0_per_mm + linear(s_per_mm_k, idx, delta_c) + quadratic(d_per_mm_k2, idx, delta_c);
            (q_target_mm * 1e-3 * slope, false)
        }
        ThermalKind::Expansion {
            alpha_ppm_per_k,
            origin_mm,
            reference_c,
            ..
        } => {
            // ppm/K · mm · K = 1e-6 mm = 1e-3 µm.
            (
                alpha_ppm_per_k * (q_target_mm - origin_mm) * (abs_c - reference_c) * 1e-3,
                false,
            )
        }
        ThermalKind::Stations {
            stations_mm,
            e0,
            b_per_k,
            ..
        } => {
            let n = stations_mm.len();
            let at = |k: usize| e0[k] + linear(&b_per_k[k], idx, delta_c);
            if q_along_mm.is_nan() || q_along_mm < stations_mm[0] {
                return (at(0), true);
            }
            if q_along_mm > stations_mm[n - 1] {
                return (at(n - 1), true);
            }
            let k = stations_mm
                .partition_point(|&s| s <= q_along_mm)
                .saturating_sub(1)
                .min(n - 2);
            let w = (q_along_mm - stations_mm[k]) / (stations_mm[k + 1] - stations_mm[k]);
            ((1.0 - w) * at(k) + w * at(k + 1), false)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sensor(tau: Option<f64>) -> SensorSpec {
        SensorSpec {
            name: "s".into(),
            reference_c: 20.0,
            tau_s: tau,
            column: None,
            exponent: None,
        }
    }

    #[test]
    fn lag_reaches_63_percent_after_one_tau_independent_of_step() {
        for steps in [10usize, 100, 1000] {
            let s = [sensor(Some(100.0))];
            let mut st = ThermalState::new(1);
            st.step(&s, &[20.0], 0.0);
            for k in 1..=steps {
                st.step(&s, &[30.0], 100.0 * k as f64 / steps as f64);
            }
            let expect = 10.0 * (1.0 - (-1.0f64).exp());
            assert!(
                (st.delta_c[0] - expect).abs() < 1e-9,
                "steps {steps}: {}",
                st.delta_c[0]
            );
        }
    }

    #[test]
    fn the_gateway_lag_is_the_offline_lag_series() {
        // A fitted lag (`models::lag::series`, used by `fit`, `diagnose` and their written models'
        // evaluation) must be the lag the box runs, reading by reading: a speed step, a ramp and
        // an irregular sample period, started settled at the first reading as both start.
        let t: Vec<f64> = (0..400)
            .map(|i| f64::from(i) * 15.0 + if i % 7 == 3 { 2.5 } else { 0.0 })
            .collect();
        let u: Vec<f64> = (0..400)
            .map(|i| match i {
                0..=99 => 20.0,
                100..=199 => 26.0,
                _ => 26.0 - 0.02 * f64::from(i - 200),
            })
            .collect();
        let offline = crate::lag::series(&t, &u, 300.0, u[0]);
        let s = [sensor(Some(300.0))];
        // Both paths: `step` (the reference evaluator) and `step_planned` (the compiled plan the
        // gateway's cycle runs, `models::plan`).
        let plan = LagPlan::new(&s);
        let (mut reference, mut planned) = (ThermalState::new(1), ThermalState::new(1));
        for (i, (&ti, &ui)) in t.iter().zip(&u).enumerate() {
            reference.step(&s, &[ui], ti);
            planned.step_planned(&plan, &[ui], ti);
            for (path, st) in [("step", &reference), ("step_planned", &planned)] {
                let online = st.delta_c[0] + s[0].reference_c;
                assert!(
                    (online - offline[i]).abs() < 1e-9,
                    "row {i}: {path} {online} vs offline {}",
                    offline[i]
                );
            }
        }
        // The step is seen on the row it arrives, not one row later.
        assert!(offline[100] > 20.0 + 1e-3, "{}", offline[100]);
    }

    #[test]
    fn cached_lag_step_matches_exp_for_jittered_and_changed_steps() {
        let tau = 180.0;
        let mut cache = (f64::NAN, 0.0);
        // Fixed-rate sample times at t ≈ 1000 s: Δt jitters by float rounding around 1 ms.
        let ts: Vec<f64> = (1_000_000..1_000_200)
            .map(|k| f64::from(k) * 1e-3)
            .collect();
        let mut steps: Vec<f64> = ts.windows(2).map(|w| w[1] - w[0]).collect();
        steps.extend([0.002, 0.002 * (1.0 + 5e-7), 0.0, 0.5, 1e-3]);
        assert!(steps.iter().any(|&d| d != 1e-3), "the fixture must jitter");
        for dt in steps {
            let want = 1.0 - (-dt / tau).exp();
            let got = lag_alpha(&mut cache, dt, tau);
            assert!((got - want).abs() <= 4e-16, "dt {dt}: {got} vs {want}");
        }
    }

    #[test]
    fn missing_reading_holds_and_backwards_time_is_reported() {
        let s = [sensor(None)];
        let mut st = ThermalState::new(1);
        assert_eq!(st.step(&s, &[25.0], 1.0), StepIssues::default());
        let i = st.step(&s, &[f64::NAN], 2.0);
        assert!(i.missing_temperature);
        assert_eq!(st.delta_c[0], 5.0);
        let i = st.step(&s, &[26.0], 1.5);
        assert!(i.time_backwards);
        assert_eq!(st.last_t_s, Some(2.0));
    }

    #[test]
    fn stations_interpolate_and_clamp() {
        let k = ThermalKind::Stations {
            along: super::super::names::Axis::Z,
            sensors: vec!["s".into()],
            stations_mm: vec![0.0, 100.0, 300.0],
            e0: vec![0.0, 10.0, 10.0],
            b_per_k: vec![vec![1.0], vec![2.0], vec![4.0]],
        };
        let dt = [2.0];
        assert_eq!(
            thermal_value(&k, &[0], &dt, 0.0, 0.0, 50.0),
            (0.5 * 2.0 + 0.5 * 14.0, false)
        );
        assert_eq!(
            thermal_value(&k, &[0], &dt, 0.0, 0.0, 200.0),
            (0.5 * 14.0 + 0.5 * 18.0, false)
        );
        assert_eq!(thermal_value(&k, &[0], &dt, 0.0, 0.0, 400.0), (18.0, true));
    }

    #[test]
    fn an_exponent_lags_the_power_of_the_reading_on_both_step_paths() {
        // rpm² heat input: the lag follows |n|², reference and ΔT in rpm².
        let mut s = sensor(Some(600.0));
        s.column = Some("rpm".into());
        s.exponent = Some(2.0);
        s.reference_c = 0.0;
        let specs = [s];
        let plan = LagPlan::new(&specs);
        let (mut a, mut b) = (ThermalState::new(1), ThermalState::new(1));
        let rpm = |t: f64| if t < 3600.0 { 1000.0 } else { -2000.0 };
        for k in 0..=720 {
            let t = 15.0 * f64::from(k);
            a.step(&specs, &[rpm(t)], t);
            b.step_planned(&plan, &[rpm(t)], t);
            assert!((a.delta_c[0] - b.delta_c[0]).abs() <= 1e-9 * a.delta_c[0].abs());
        }
        // Started at 1000² and held there; a reading applies over the interval that ends at it, so
        // (−2000)² drives the state from 3585 s to 10800 s (7215 s).
        let want = 4e6 + (1e6 - 4e6) * (-7215.0f64 / 600.0).exp();
        assert!(
            (a.delta_c[0] - want).abs() < 1e-6 * want,
            "{}",
            a.delta_c[0]
        );
    }
}
