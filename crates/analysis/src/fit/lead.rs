//! A ball-screw lead wave: a sinusoid of the screw's lead along one axis, fitted as a sin/cos pair
//! beside a smooth (piecewise-quadratic) part. Shared by the artefact identification
//! (`identify --lead-mm`) and the direct laser fit (`fit axis --lead-mm`), so both report and
//! tabulate it alike.
//!
//! Convention: wave(q) = s·sin(2πq/L) + c·cos(2πq/L) = A·sin(2πq/L + φ), q the axis position in
//! its own coordinate (mm, phase measured from q = 0), L the lead (mm), s, c, A in µm, φ in degrees
//! in (−180, 180]: A = √(s² + c²), φ = atan2(c, s). A piecewise quadratic cannot carry the wave, so
//! a component with one goes into the model as a linear table at steps of at most
//! L / [`TABLE_STEPS_PER_LEAD`] (linear interpolation of a sine at L/16 misses by at most
//! 1 − cos(π/16) = 1.9 % of A; at L/4 it would be 29 %).

use serde::{Deserialize, Serialize};

/// Table nodes per lead when a component with a lead wave is written into the model.
pub const TABLE_STEPS_PER_LEAD: f64 = 16.0;

/// The wave's two columns at q (µm per µm of s and of c).
pub fn columns(lead_mm: f64, q_mm: f64) -> [f64; 2] {
    let (s, c) = (std::f64::consts::TAU * q_mm / lead_mm).sin_cos();
    [s, c]
}

/// Checks a `--lead-mm` value: positive and finite.
pub fn check_lead(lead_mm: f64) -> Result<f64, String> {
    if lead_mm.is_finite() && lead_mm > 0.0 {
        Ok(lead_mm)
    } else {
        Err(format!(
            "--lead-mm {lead_mm}: expected the ball screw's lead, a positive length in mm"
        ))
    }
}

/// One fitted lead wave with its uncertainty.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeadWave {
    /// The component (e.g. `EXX`) or direction it belongs to.
    pub name: String,
    pub lead_mm: f64,
    /// Coefficients of sin and cos, µm.
    pub sin_um: f64,
    pub cos_um: f64,
    pub amplitude_um: f64,
    /// Standard error of the amplitude, µm (first order).
    pub amplitude_se_um: f64,
    pub phase_deg: f64,
    /// Standard error of the phase, degrees (first order; large when the amplitude is not
    /// significant).
    pub phase_se_deg: f64,
    /// Covariance of (sin_um, cos_um), µm².
    pub cov_um2: [[f64; 2]; 2],
}

impl LeadWave {
    /// From the coefficients (s, c) and their 2×2 covariance (µm²).
    pub fn new(name: &str, lead_mm: f64, sin_um: f64, cos_um: f64, cov: [[f64; 2]; 2]) -> Self {
        let a = sin_um.hypot(cos_um);
        // Gradients of A and φ (rad) with respect to (s, c).
        let (ga, gp) = if a > 0.0 {
            (
                [sin_um / a, cos_um / a],
                [-cos_um / (a * a), sin_um / (a * a)],
            )
        } else {
            ([0.0; 2], [0.0; 2])
        };
        let quad = |g: [f64; 2]| {
            (g[0] * g[0] * cov[0][0] + 2.0 * g[0] * g[1] * cov[0][1] + g[1] * g[1] * cov[1][1])
                .max(0.0)
                .sqrt()
        };
        LeadWave {
            name: name.to_string(),
            lead_mm,
            sin_um,
            cos_um,
            amplitude_um: a,
            amplitude_se_um: quad(ga),
            phase_deg: cos_um.atan2(sin_um).to_degrees(),
            phase_se_deg: if a > 0.0 {
                quad(gp).to_degrees()
            } else {
                180.0
            },
            cov_um2: cov,
        }
    }

    /// The wave's value at q, µm.
    pub fn eval(&self, q_mm: f64) -> f64 {
        let [s, c] = columns(self.lead_mm, q_mm);
        self.sin_um * s + self.cos_um * c
    }

    /// `EXX lead 5 mm: 1.48 ± 0.03 µm at φ = 31.2 ± 1.1°`.
    pub fn describe(&self) -> String {
        format!(
            "{} lead {} mm: {:.2} ± {:.2} µm at φ = {:.1} ± {:.1}° (A·sin(2πq/L + φ), q from 0)",
            self.name,
            self.lead_mm,
            self.amplitude_um,
            self.amplitude_se_um,
            self.phase_deg,
            self.phase_se_deg
        )
    }
}

/// Smallest angle between two phases, degrees (0…180).
pub fn phase_difference_deg(a_deg: f64, b_deg: f64) -> f64 {
    let d = (a_deg - b_deg).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// Table positions over [lo, hi] at equal steps of at most `lead_mm` / [`TABLE_STEPS_PER_LEAD`]
/// (both ends included).
pub fn table_positions(lo_mm: f64, hi_mm: f64, lead_mm: f64) -> Vec<f64> {
    let max_step = lead_mm / TABLE_STEPS_PER_LEAD;
    let n = crate::numeric::ceil_usize((hi_mm - lo_mm) / max_step).max(1);
    (0..=n)
        .map(|k| lo_mm + (hi_mm - lo_mm) * k as f64 / n as f64)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn amplitude_and_phase_follow_the_sine_convention() {
        // 1.5 µm at φ = 30°: s = A cos φ, c = A sin φ.
        let (a, ph) = (1.5_f64, 30.0_f64.to_radians());
        let w = LeadWave::new(
            "EXX",
            5.0,
            a * ph.cos(),
            a * ph.sin(),
            [[0.01, 0.0], [0.0, 0.01]],
        );
        assert!((w.amplitude_um - 1.5).abs() < 1e-12);
        assert!((w.phase_deg - 30.0).abs() < 1e-9);
        // Isotropic covariance: se(A) = σ, se(φ) = σ / A.
        assert!((w.amplitude_se_um - 0.1).abs() < 1e-12);
        assert!((w.phase_se_deg - (0.1f64 / 1.5).to_degrees()).abs() < 1e-9);
        for q in [0.0, 1.3, 7.7, 512.4] {
            let want = a * (std::f64::consts::TAU * q / 5.0 + ph).sin();
            assert!((w.eval(q) - want).abs() < 1e-12, "{q}");
        }
        assert_eq!(phase_difference_deg(350.0, 10.0), 20.0);
        assert_eq!(phase_difference_deg(-170.0, 170.0), 20.0);
    }

    #[test]
    fn a_linear_table_at_the_positions_carries_the_wave() {
        let q = table_positions(130.0, 681.3, 5.0);
        let step = q[1] - q[0];
        assert!(
            step <= 5.0 / TABLE_STEPS_PER_LEAD + 1e-12 && (q[q.len() - 1] - 681.3).abs() < 1e-9
        );
        let w = LeadWave::new("EXX", 5.0, 1.2, -0.9, [[0.0; 2]; 2]);
        let v: Vec<f64> = q.iter().map(|x| w.eval(*x)).collect();
        let t = retrocomp_model::Table::new(
            q.clone(),
            v.clone(),
            v,
            retrocomp_model::Interpolation::Linear,
        );
        let worst = (0..5000)
            .map(|k| 130.0 + 551.3 * f64::from(k) / 5000.0)
            .map(|x| (t.eval(x, 0).0 - w.eval(x)).abs())
            .fold(0.0, f64::max);
        assert!(worst <= 0.02 * w.amplitude_um, "{worst}");
        assert!(check_lead(0.0).is_err() && check_lead(f64::NAN).is_err());
    }
}
