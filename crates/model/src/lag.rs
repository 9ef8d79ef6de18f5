//! The one first-order lag kernel of the workspace: a temperature (or any slow signal) seen through a
//! first-order lag with time constant τ, discretised exactly for an input held between samples:
//! y ← y + α·(u − y) with α = 1 − e^(−Δt/τ). Used by the model's thermal terms
//! ([`crate::ThermalState`]), the fit's lagged regressors (`analysis::fit`), diagnose's features and
//! hil-sim's physics.
//!
//! Which reading is held: the one that arrives at the end of the interval (`u[i]` over
//! `t[i−1]…t[i]`), as the gateway's `ThermalState::step` applies a reading the moment it comes in.
//! [`series`] follows the same rule so that a lag fitted offline is, to rounding, the lag the box
//! runs (holding u[i−1] instead would make a written model differ from its fit by one sample's step
//! after every jump of the input, and carry a reading across a gap in the rows).
//! `thermal::tests::the_gateway_lag_is_the_offline_lag_series` locks the two together on both of the
//! gateway's step paths. [`plant_series`] is the other rule, for a simulated plant.
//!
//! Units: Δt, τ and the sample times in seconds; the signal in its own unit. τ ≤ 0 means "no lag"
//! (α = 1: [`series`] takes the reading itself, [`plant_series`] the previous set point). A
//! negative Δt (times out of order) counts as 0.

/// α = 1 − e^(−Δt/τ), the weight of the new input for a step of `dt_s`; 1 when τ ≤ 0.
#[inline]
pub fn alpha(dt_s: f64, tau_s: f64) -> f64 {
    if tau_s > 0.0 {
        1.0 - (-dt_s.max(0.0) / tau_s).exp()
    } else {
        1.0
    }
}

/// The lagged series of `u` sampled at `t_s`, started at `y0`: `y[0] = y0` and
/// `y[i] = y[i−1] + α(t[i] − t[i−1])·(u[i] − y[i−1])` (each reading held over the interval it ends,
/// as `ThermalState::step` does). For readings: the fit's and diagnose's
/// regressors, and the evaluation of a model over a recording.
pub fn series(t_s: &[f64], u: &[f64], tau_s: f64, y0: f64) -> Vec<f64> {
    run(t_s, u, tau_s, y0, 0)
}

/// A plant's response to an input *schedule*: the value set at `t[i−1]` acts until `t[i]`
/// (`y[i] = y[i−1] + α·(u[i−1] − y[i−1])`), the exact solution for a commanded speed or an ambient
/// held between its set points. hil-sim's physics drives its simulated machine with it; a model
/// reading sensors uses [`series`], so the two differ by one sample the way a real machine and its
/// sampled model do.
pub fn plant_series(t_s: &[f64], u: &[f64], tau_s: f64, y0: f64) -> Vec<f64> {
    run(t_s, u, tau_s, y0, 1)
}

/// [`series`] at every time constant of `taus_s`, each minus `offset` (`y[i] − offset`; an
/// `offset` of 0 leaves the series' bits), in one pass over the rows per [`LANES`] time
/// constants: a lag is a chain of dependent steps, so one series at a time waits on each step's
/// latency, while interleaved series fill the pipeline. Each series is the same bits as
/// [`series`] at its τ (the same steps in the same order).
pub fn series_each(t_s: &[f64], u: &[f64], taus_s: &[f64], y0: f64, offset: f64) -> Vec<Vec<f64>> {
    taus_s
        .chunks(LANES)
        .flat_map(|taus| run_lanes(t_s, u, taus, y0, 0, offset))
        .collect()
}

/// Time constants one pass of [`series_each`] carries.
pub const LANES: usize = 4;

/// `y[i] = y[i−1] + α·(u[i − back] − y[i−1])` for i ≥ 1.
fn run(t_s: &[f64], u: &[f64], tau_s: f64, y0: f64, back: usize) -> Vec<f64> {
    let mut out = run_lanes(t_s, u, &[tau_s], y0, back, 0.0);
    out.pop().expect("one lane per time constant")
}

/// [`run`] for up to [`LANES`] time constants `taus_s` at once, each series minus `offset`.
fn run_lanes(
    t_s: &[f64],
    u: &[f64],
    taus_s: &[f64],
    y0: f64,
    back: usize,
    offset: f64,
) -> Vec<Vec<f64>> {
    let lanes = taus_s.len();
    assert!(lanes <= LANES, "{lanes} time constants, at most {LANES}");
    let mut out: Vec<Vec<f64>> = (0..lanes).map(|_| Vec::with_capacity(u.len())).collect();
    let mut y = [y0; LANES];
    let mut alphas = AlphaCache::new(taus_s);
    for i in 0..u.len() {
        if i > 0 {
            let a = alphas.get(t_s[i] - t_s[i - 1]);
            let ui = u[i - back];
            for l in 0..lanes {
                y[l] += a[l] * (ui - y[l]);
            }
        }
        for (o, y) in out.iter_mut().zip(y) {
            o.push(y - offset);
        }
    }
    out
}

/// [`alpha`] for up to [`LANES`] time constants, remembered per sample period: a recording's
/// periods are few (a 1 kHz clock read as decimal seconds gives ≈ 20 distinct Δt) but alternate
/// from row to row, so keeping only the last one computed an exponential for every other row.
/// Direct-mapped on Δt's bits; a slot holds the exact α of its exact Δt (NaN marks it empty: no Δt
/// has NaN's bits here, and a NaN Δt never matches), so a series is the same bits as with its α
/// computed at every row.
struct AlphaCache {
    taus_s: [f64; LANES],
    slots: [(u64, [f64; LANES]); ALPHA_SLOTS],
}

const ALPHA_SLOTS: usize = 64;

impl AlphaCache {
    fn new(taus_s: &[f64]) -> Self {
        // Lanes past the given time constants repeat the first: computed, never read.
        let taus_s =
            std::array::from_fn(|l| taus_s.get(l).or(taus_s.first()).copied().unwrap_or(0.0));
        AlphaCache {
            taus_s,
            slots: [(f64::NAN.to_bits(), [1.0; LANES]); ALPHA_SLOTS],
        }
    }

    #[inline]
    fn get(&mut self, dt_s: f64) -> [f64; LANES] {
        let bits = dt_s.to_bits();
        // Fibonacci hashing: the top bits of the product mix every bit of Δt.
        let k = (bits.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as usize;
        let slot = &mut self.slots[k];
        if slot.0 != bits || dt_s.is_nan() {
            *slot = (bits, self.taus_s.map(|tau_s| alpha(dt_s, tau_s)));
        }
        slot.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_rises_by_one_minus_e_per_time_constant() {
        let t: Vec<f64> = (0..=1000).map(|i| f64::from(i) * 0.5).collect();
        let u = vec![1.0; t.len()];
        let y = series(&t, &u, 100.0, 0.0);
        // After τ = 100 s (200 samples) the exact discretisation of a held input gives 1 − 1/e.
        assert!(
            (y[200] - (1.0 - (-1.0f64).exp())).abs() < 1e-12,
            "{}",
            y[200]
        );
        assert!(y.windows(2).all(|w| w[1] >= w[0]) && y[1000] < 1.0);
    }

    #[test]
    fn no_lag_and_out_of_order_times() {
        assert_eq!(alpha(0.1, 0.0), 1.0);
        assert_eq!(alpha(-1.0, 10.0), 0.0);
        assert_eq!(
            series(&[0.0, 1.0, 2.0], &[5.0, 6.0, 7.0], 0.0, 5.0),
            [5.0, 6.0, 7.0]
        );
        assert_eq!(
            plant_series(&[0.0, 1.0, 2.0], &[5.0, 6.0, 7.0], 0.0, 5.0),
            [5.0, 5.0, 6.0]
        );
        assert!(series(&[], &[], 1.0, 0.0).is_empty());
    }

    /// The remembered α per sample period gives the bits of an α computed at every row: periods
    /// that alternate (a 1 kHz clock in decimal seconds), more distinct periods than the cache
    /// has slots (so they collide and are recomputed), a NaN time and out-of-order times.
    #[test]
    fn remembered_alphas_are_the_per_row_alphas_bit_for_bit() {
        let mut t: Vec<f64> = (0..5000).map(|i| f64::from(i) * 0.001).collect();
        t.extend((0..3000).map(|i| 5.0 + f64::from(i * i % 997) * 1e-3 + f64::from(i) * 0.01));
        t[6000] = f64::NAN;
        t[7000] = t[6999] - 0.5;
        let u: Vec<f64> = (0..t.len()).map(|i| (i as f64 * 0.37).sin()).collect();
        let distinct: std::collections::HashSet<u64> =
            t.windows(2).map(|w| (w[1] - w[0]).to_bits()).collect();
        assert!(distinct.len() > 4 * ALPHA_SLOTS, "{}", distinct.len());
        for (tau_s, back) in [(30.0, 0), (0.004, 0), (30.0, 1), (0.0, 0)] {
            let mut y = 0.25;
            let mut reference = vec![y];
            for i in 1..t.len() {
                y += alpha(t[i] - t[i - 1], tau_s) * (u[i - back] - y);
                reference.push(y);
            }
            let got = run(&t, &u, tau_s, 0.25, back);
            assert_eq!(bits(&got), bits(&reference), "τ = {tau_s} s, back = {back}");
        }
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// Series carried side by side (a full group of lanes and a remainder) are each the bits of
    /// the series alone, and the offset is subtracted after the lag, not fed into it.
    #[test]
    fn series_each_is_each_series_bit_for_bit() {
        let t: Vec<f64> = (0..3000)
            .map(|i| f64::from(i) * 0.001 + f64::from(i % 7) * 1e-5)
            .collect();
        let u: Vec<f64> = (0..t.len())
            .map(|i| 20.0 + (i as f64 * 0.01).sin())
            .collect();
        let taus = [30.0, 39.0, 0.05, 0.0, 66.0, 0.2];
        for offset in [0.0, 20.0] {
            let each = series_each(&t, &u, &taus, u[0], offset);
            assert_eq!(each.len(), taus.len());
            for (y, &tau_s) in each.iter().zip(&taus) {
                let alone: Vec<f64> = series(&t, &u, tau_s, u[0])
                    .iter()
                    .map(|v| v - offset)
                    .collect();
                assert_eq!(bits(y), bits(&alone), "τ = {tau_s} s, offset {offset}");
            }
        }
        assert!(series_each(&t, &u, &[], 0.0, 0.0).is_empty());
    }
}
