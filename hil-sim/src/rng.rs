//! Seeded random streams. Every consumer (each sensor, each fault, the error instrument) draws from its
//! own ChaCha8 stream `(seed, stream id)`, so switching one effect on or off never shifts another's noise.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[derive(Clone, Debug)]
pub struct Noise {
    rng: ChaCha8Rng,
    spare: Option<f64>,
}

/// Stream ids are derived from a consumer's name so they are stable when the config is reordered.
pub fn stream_id(name: &str) -> u64 {
    // FNV-1a: stable across runs and platforms (std's hasher is randomly keyed).
    name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

impl Noise {
    pub fn new(seed: u64, name: &str) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream_id(name));
        Self { rng, spare: None }
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.rng.random::<f64>()
    }

    /// Normal(0, sigma) by Box–Muller; sigma = 0 draws nothing (so noise-off runs are exact).
    pub fn gauss(&mut self, sigma: f64) -> f64 {
        if sigma == 0.0 {
            return 0.0;
        }
        if let Some(z) = self.spare.take() {
            return z * sigma;
        }
        let u1 = 1.0 - self.uniform(); // (0, 1]: ln is finite
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (std::f64::consts::TAU * u2).sin_cos();
        self.spare = Some(r * s);
        r * c * sigma
    }

    /// Exponential waiting time with the given mean.
    pub fn exp_wait(&mut self, mean: f64) -> f64 {
        -mean * (1.0 - self.uniform()).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_is_identical_and_streams_differ() {
        let a: Vec<f64> = (0..5)
            .map({
                let mut n = Noise::new(7, "T_spindle_C");
                move |_| n.gauss(1.0)
            })
            .collect();
        let b: Vec<f64> = (0..5)
            .map({
                let mut n = Noise::new(7, "T_spindle_C");
                move |_| n.gauss(1.0)
            })
            .collect();
        let c: Vec<f64> = (0..5)
            .map({
                let mut n = Noise::new(7, "T_column_C");
                move |_| n.gauss(1.0)
            })
            .collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn gauss_has_unit_variance() {
        let mut n = Noise::new(1, "x");
        let v: Vec<f64> = (0..20000).map(|_| n.gauss(2.0)).collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (v.len() - 1) as f64;
        assert!(mean.abs() < 0.05, "mean {mean}");
        assert!((var.sqrt() - 2.0).abs() < 0.05, "sd {}", var.sqrt());
    }
}
