//! The generator's physics, deliberately richer than diagnose's candidate forms: a two-node thermal
//! network driven by spindle speed and ambient drift (nodes have their own time constants; sensors
//! read a node through their own lag, with noise and 0.1 °C quantisation), a cutting force with
//! process noise read by a noisy load cell and by a strain gauge with its own temperature
//! sensitivity, and measurement noise that is white + AR(1) + quantised + 0.5 % outliers.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use retrocomp_analysis::diagnose::features::lowpass;
use retrocomp_model::lag;

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller: deterministic for a seeded ChaCha8Rng.
    let u1: f64 = rng.random_range(1e-12..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

pub(crate) fn quantize(v: f64, lsb: f64) -> f64 {
    (v / lsb).round() * lsb
}

/// True node temperatures (°C). The machine starts cold (every node at ambient). `spindle` is heated
/// by spindle speed (`k_c_per_krpm`, time constant `tau_node_s`); `structure` by a share of the
/// spindle heat AND by axis-motion friction (`motion_speed_mm_s`, 0.05 °C per mm/s), with its own
/// time constant `tau_struct_s` — so it is not a pure lag of the spindle node; ambient drifts slowly.
#[derive(Debug)]
pub(crate) struct Thermal {
    pub spindle_c: Vec<f64>,
    pub structure_c: Vec<f64>,
    pub ambient_c: Vec<f64>,
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn thermal(
    t_s: &[f64],
    rpm: &[f64],
    motion_speed_mm_s: &[f64],
    k_c_per_krpm: f64,
    tau_node_s: f64,
    tau_struct_s: f64,
    amb_amp_c: f64,
    amb_period_s: f64,
) -> Thermal {
    thermal_with_ambient(
        t_s,
        standard_ambient(t_s, amb_amp_c, amb_period_s),
        rpm,
        motion_speed_mm_s,
        k_c_per_krpm,
        tau_node_s,
        tau_struct_s,
        0.4,
    )
}

/// The standard ambient: 20 °C plus a slow sine of `amp_c` and period `period_s`, starting at 20.
pub(crate) fn standard_ambient(t_s: &[f64], amp_c: f64, period_s: f64) -> Vec<f64> {
    t_s.iter()
        .map(|t| 20.0 + amp_c * (std::f64::consts::TAU * t / period_s).sin())
        .collect()
}

/// [`thermal`] with a given ambient and the share of the spindle node's rise that heats the
/// structure (`spindle_share`, 0.4 in the standard cases; 0 leaves the structure unheated by it).
#[allow(clippy::too_many_arguments)]
pub(crate) fn thermal_with_ambient(
    t_s: &[f64],
    ambient_c: Vec<f64>,
    rpm: &[f64],
    motion_speed_mm_s: &[f64],
    k_c_per_krpm: f64,
    tau_node_s: f64,
    tau_struct_s: f64,
    spindle_share: f64,
) -> Thermal {
    let drive: Vec<f64> = rpm
        .iter()
        .zip(&ambient_c)
        .map(|(r, a)| a + k_c_per_krpm * r / 1000.0)
        .collect();
    let spindle_c = lag::plant_series(t_s, &drive, tau_node_s, ambient_c[0]);
    let motion = lag::plant_series(t_s, motion_speed_mm_s, 120.0, 0.0);
    let sdrive: Vec<f64> = (0..t_s.len())
        .map(|i| ambient_c[i] + spindle_share * (spindle_c[i] - ambient_c[i]) + 0.05 * motion[i])
        .collect();
    let structure_c = lag::plant_series(t_s, &sdrive, tau_struct_s, ambient_c[0]);
    Thermal {
        spindle_c,
        structure_c,
        ambient_c,
    }
}

/// A temperature sensor on a node: its own lag, white noise, 0.1 °C quantisation.
pub(crate) fn temp_sensor(
    rng: &mut ChaCha8Rng,
    t_s: &[f64],
    node_c: &[f64],
    lag_s: f64,
    noise_c: f64,
) -> Vec<f64> {
    lowpass(t_s, node_c, lag_s)
        .into_iter()
        .map(|v| quantize(v + noise_c * gauss(rng), 0.1))
        .collect()
}

/// A random-walk "sensor" measuring nothing (decoy).
pub(crate) fn random_walk(rng: &mut ChaCha8Rng, n: usize, start: f64, step: f64) -> Vec<f64> {
    let mut v = start;
    (0..n)
        .map(|_| {
            v += step * gauss(rng);
            quantize(v, 0.01)
        })
        .collect()
}

/// Cutting force (N): `mean_n` with 8 % process noise while in cut, 0 in air.
pub(crate) fn cutting_force(rng: &mut ChaCha8Rng, cut: &[bool], mean_n: f64) -> Vec<f64> {
    cut.iter()
        .map(|&c| {
            if c {
                mean_n * (1.0 + 0.08 * gauss(rng))
            } else {
                0.0
            }
        })
        .collect()
}

/// Load cell reading: force + 1 % of mean white noise, 0.1 N resolution.
pub(crate) fn load_cell(rng: &mut ChaCha8Rng, f: &[f64], noise_n: f64) -> Vec<f64> {
    f.iter()
        .map(|v| quantize(v + noise_n * gauss(rng), 0.1))
        .collect()
}

/// Strain gauge (µε): compliance of the column, apparent strain from its own temperature, noise.
pub(crate) fn strain_gauge(
    rng: &mut ChaCha8Rng,
    f: &[f64],
    temp_c: &[f64],
    ue_per_n: f64,
    ue_per_k: f64,
) -> Vec<f64> {
    let t0 = temp_c.first().copied().unwrap_or(20.0);
    f.iter()
        .zip(temp_c)
        .map(|(v, t)| quantize(v * ue_per_n + ue_per_k * (t - t0) + 0.3 * gauss(rng), 0.01))
        .collect()
}

/// Measurement noise of total standard deviation ≈ `sigma_um`: 60 % white, 80 % AR(1) with ρ = 0.9
/// (in variance: 0.36 + 0.64 = 1), 0.5 % outliers of ±6σ, then 0.05 µm quantisation (laser resolution).
pub(crate) fn error_noise(rng: &mut ChaCha8Rng, n: usize, sigma_um: f64) -> Vec<f64> {
    let rho: f64 = 0.9;
    let innov = (1.0 - rho * rho).sqrt();
    let mut ar = 0.0;
    (0..n)
        .map(|_| {
            ar = rho * ar + innov * gauss(rng);
            let mut e = sigma_um * (0.6 * gauss(rng) + 0.8 * ar);
            if rng.random_range(0.0..1.0) < 0.005 {
                e += 6.0 * sigma_um * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            }
            e
        })
        .collect()
}

/// AR(1) noise with coefficient `rho` and stationary standard deviation `sigma_um` (started in its
/// stationary distribution, so the whole recording has that σ).
pub(crate) fn ar1_noise(rng: &mut ChaCha8Rng, n: usize, sigma_um: f64, rho: f64) -> Vec<f64> {
    let innov = (1.0 - rho * rho).sqrt();
    let mut a = gauss(rng);
    (0..n)
        .map(|i| {
            if i > 0 {
                a = rho * a + innov * gauss(rng);
            }
            sigma_um * a
        })
        .collect()
}

fn centred_rms(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

/// A Gaussian random walk (i.i.d. increments) scaled so its centred RMS over the recording is
/// `sigma_um`: non-stationary noise with no σ of its own.
pub(crate) fn walk_noise(rng: &mut ChaCha8Rng, n: usize, sigma_um: f64) -> Vec<f64> {
    let mut w = 0.0;
    let v: Vec<f64> = (0..n)
        .map(|_| {
            w += gauss(rng);
            w
        })
        .collect();
    let k = sigma_um / centred_rms(&v).max(1e-12);
    v.into_iter().map(|x| x * k).collect()
}

/// Sample correlation of two equally long series.
pub(crate) fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt().max(1e-300)
}

/// A spurious-regression decoy: `tries` random walks ([`random_walk`], own independent increments),
/// the one whose sample correlation with `noise` is largest in magnitude is returned with that
/// correlation. It tracks the noise over the recording by selection, not by cause: it holds no
/// information about the noise's future.
pub(crate) fn correlated_walk_decoy(
    rng: &mut ChaCha8Rng,
    noise: &[f64],
    start: f64,
    step: f64,
    tries: usize,
) -> (Vec<f64>, f64) {
    (0..tries)
        .map(|_| {
            let w = random_walk(rng, noise.len(), start, step);
            let c = correlation(&w, noise);
            (w, c)
        })
        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
        .expect("tries > 0")
}
