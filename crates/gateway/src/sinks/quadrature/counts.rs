//! Correction in µm → whole encoder counts to inject, with the fractional residual carried so that
//! no sub-count part is ever lost or counted twice (the sum of emitted counts always equals the
//! rounded total target).
//!
//! Sign convention (see the module above): `inject_counts = −correction_um / resolution_um × count_sign`.

/// Converts an absolute correction target (µm) into a count delta to inject since the last call.
#[derive(Clone, Debug)]
pub struct CountQuantizer {
    resolution_um: f64,
    count_sign: f64,
    /// Counts handed out so far (integer, exact).
    emitted_counts: i64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CountError {
    #[error("encoder resolution must be finite and > 0 µm, got {0}")]
    BadResolution(f64),
    #[error("correction must be finite, got {0} µm")]
    NotFinite(f64),
    #[error("correction of {0} µm is more than 2^53 counts")]
    TooLarge(f64),
}

impl CountQuantizer {
    /// `resolution_um`: slide travel per count (per A/B edge). `count_sign`: +1 when the encoder counts
    /// up as the axis moves +, −1 otherwise.
    pub fn new(resolution_um: f64, count_sign: i8) -> Result<Self, CountError> {
        if !(resolution_um.is_finite() && resolution_um > 0.0) {
            return Err(CountError::BadResolution(resolution_um));
        }
        Ok(Self {
            resolution_um,
            count_sign: if count_sign < 0 { -1.0 } else { 1.0 },
            emitted_counts: 0,
        })
    }

    /// A quantizer that continues from `held_counts` already emitted (what the controller holds,
    /// persisted by `super::held`): the next delta is taken against them, not against 0.
    pub fn continuing_from(
        resolution_um: f64,
        count_sign: i8,
        held_counts: i64,
    ) -> Result<Self, CountError> {
        let mut q = Self::new(resolution_um, count_sign)?;
        q.emitted_counts = held_counts;
        Ok(q)
    }

    /// The correction (µm) that `counts` injected counts realise (the inverse of the rounding).
    pub fn correction_um_of(&self, counts: i64) -> f64 {
        -(counts as f64) * self.resolution_um * self.count_sign
    }

    /// Total injected counts that realise `correction_um` (rounded half away from zero).
    pub fn target_counts(&self, correction_um: f64) -> Result<i64, CountError> {
        if !correction_um.is_finite() {
            return Err(CountError::NotFinite(correction_um));
        }
        let counts = (-correction_um / self.resolution_um * self.count_sign).round();
        // ±2⁵³ counts is far beyond any clamp (the guard caps the correction first); refuse rather
        // than let `as` saturate.
        if counts.abs() > 9.007_199_254_740_992e15 {
            return Err(CountError::TooLarge(correction_um));
        }
        #[allow(
            clippy::cast_possible_truncation,
            reason = "|counts| ≤ 2⁵³, an integer: exact in i64"
        )]
        let counts = counts as i64;
        Ok(counts)
    }

    /// Counts to inject now so that the running total matches the new target; the remainder below
    /// half a count stays as residual (it is not emitted until the target crosses the next half count).
    pub fn delta_counts(&mut self, correction_um: f64) -> Result<i64, CountError> {
        let target = self.target_counts(correction_um)?;
        let delta = target - self.emitted_counts;
        self.emitted_counts = target;
        Ok(delta)
    }

    /// Counts emitted so far.
    pub fn emitted_counts(&self) -> i64 {
        self.emitted_counts
    }

    /// Residual in µm of slide motion not yet realised: requested correction minus what the emitted
    /// counts move the slide by.
    pub fn residual_um(&self, correction_um: f64) -> f64 {
        let realised_um = -(self.emitted_counts as f64) * self.resolution_um * self.count_sign;
        correction_um - realised_um
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sign_positive_correction_injects_negative_counts() {
        let mut q = CountQuantizer::new(1.0, 1).unwrap();
        assert_eq!(q.delta_counts(5.0).unwrap(), -5);
        let mut q = CountQuantizer::new(1.0, -1).unwrap();
        assert_eq!(q.delta_counts(5.0).unwrap(), 5);
    }

    #[test]
    fn residual_is_carried_not_lost() {
        // 0.1 µm steps at 0.5 µm/count: 20 steps of 0.1 µm must give exactly 2 µm = −4 counts in total.
        let mut q = CountQuantizer::new(0.5, 1).unwrap();
        let mut sum = 0;
        for k in 1..=20 {
            let c = f64::from(k) * 0.1;
            sum += q.delta_counts(c).unwrap();
            assert!(
                q.residual_um(c).abs() <= 0.25 + 1e-9,
                "residual beyond half a count"
            );
        }
        assert_eq!(sum, -4);
    }

    #[test]
    fn rejects_bad_input() {
        assert!(CountQuantizer::new(0.0, 1).is_err());
        assert!(CountQuantizer::new(f64::NAN, 1).is_err());
        let mut q = CountQuantizer::new(1.0, 1).unwrap();
        q.delta_counts(3.0).unwrap();
        assert!(matches!(
            q.delta_counts(f64::NAN),
            Err(CountError::NotFinite(_))
        ));
        assert_eq!(
            q.emitted_counts(),
            -3,
            "a rejected input must not change the state"
        );
    }
}
