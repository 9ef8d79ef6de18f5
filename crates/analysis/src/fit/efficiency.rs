//! Spaan's efficiency on held-out data: δ = 1 − Σ|Δm − Δs| / Σ|Δm| (Δm measured, Δs modelled),
//! reported with the maximum residual. δ = 1 is perfect, 0 is no better than no compensation, and
//! it can be negative (the model makes things worse).

use serde::Serialize;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Efficiency {
    pub delta: f64,
    pub max_residual_um: f64,
    pub n: usize,
}

/// `None` for empty input or when every measured value is zero (δ undefined).
pub fn efficiency(measured_um: &[f64], modelled_um: &[f64]) -> Option<Efficiency> {
    if measured_um.is_empty() || measured_um.len() != modelled_um.len() {
        return None;
    }
    let den: f64 = measured_um.iter().map(|m| m.abs()).sum();
    if den == 0.0 {
        return None;
    }
    let res: Vec<f64> = measured_um
        .iter()
        .zip(modelled_um)
        .map(|(m, s)| m - s)
        .collect();
    Some(Efficiency {
        delta: 1.0 - res.iter().map(|r| r.abs()).sum::<f64>() / den,
        max_residual_um: res.iter().fold(0.0, |a, r| a.max(r.abs())),
        n: res.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn efficiency_values() {
        let e = efficiency(&[10.0, -10.0], &[8.0, -9.0]).unwrap();
        assert!((e.delta - (1.0 - 3.0 / 20.0)).abs() < 1e-12);
        assert_eq!(e.max_residual_um, 2.0);
        assert!(efficiency(&[1.0], &[3.0]).unwrap().delta < 0.0);
        assert_eq!(efficiency(&[0.0], &[1.0]), None);
    }
}
