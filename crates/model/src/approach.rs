//! Direction of approach of one axis: the ONE definition used by the gateway's direction latch
//! (`gateway::direction`, which adds the ramped forward/reverse blend on top), diagnose's motion
//! features (`diagnose::features`) and the demo fit's bidirectional tables (`demo::fitted`).
//!
//! Sign convention: +1 = forward = the axis reached its position moving towards +position; −1 =
//! reverse; 0 = not known yet (the axis has not moved by more than the deadband since the latch
//! started). Positions in mm, commanded (nominal) positions wherever the caller has them.
//!
//! Rule (hysteresis): the latch only reverses once the axis has moved `deadband_mm` back from the
//! extreme it reached in the current direction, so noise or creep around a standstill never flips
//! it and a dwell keeps the direction of its approach (ISO 230-2 step-and-dwell readings). The first
//! direction is latched once the axis has moved `deadband_mm` from the first position seen.

use serde::{Deserialize, Serialize};

/// Direction of approach of an axis (ISO 230-2 ↑ / ↓): the one type for the gateway's latch and
/// status, the toolkit's bidirectional tables (`analysis::table`), diagnose and the demo fit.
/// "Not known yet" is `Option::None`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Approach {
    /// Approach in the positive direction (`+`, ↑, "forward").
    Forward,
    /// Approach in the negative direction (`-`, ↓, "reverse").
    Reverse,
}

impl Approach {
    /// `+` / `-` as in the ISO 230-2 CSV.
    pub fn symbol(self) -> char {
        match self {
            Approach::Forward => '+',
            Approach::Reverse => '-',
        }
    }

    /// +1 forward, −1 reverse.
    pub fn sign(self) -> i8 {
        match self {
            Approach::Forward => 1,
            Approach::Reverse => -1,
        }
    }

    /// Forward for a positive sign, reverse for a negative one, None for 0.
    pub fn from_sign(sign: i8) -> Option<Approach> {
        match sign.signum() {
            1 => Some(Approach::Forward),
            -1 => Some(Approach::Reverse),
            _ => None,
        }
    }
}

/// A latched approach as the gateway's status, metrics and OPC UA spell it: `unknown`, `forward`,
/// `reverse`.
pub fn latched_name(a: Option<Approach>) -> &'static str {
    match a {
        None => "unknown",
        Some(Approach::Forward) => "forward",
        Some(Approach::Reverse) => "reverse",
    }
}

/// `#[serde(serialize_with)]` for a latched approach: [`latched_name`].
pub fn serialize_latched<S: serde::Serializer>(
    a: &Option<Approach>,
    s: S,
) -> Result<S::Ok, S::Error> {
    s.serialize_str(latched_name(*a))
}

/// Deadband for recorded commanded positions (diagnose, offline fits): 0.1 µm, below the resolution
/// of any recorded target, so every commanded step counts and rounding noise does not.
pub const RECORDED_DEADBAND_MM: f64 = 1e-4;

/// Latched direction of approach of one axis (see the module comment).
#[derive(Clone, Debug)]
pub struct ApproachLatch {
    deadband_mm: f64,
    dir: i8,
    /// Extreme position reached in the current direction (or the first position seen).
    extreme_mm: Option<f64>,
}

impl ApproachLatch {
    /// A latch that reverses after `deadband_mm` of travel back from the extreme (negative = 0).
    pub fn new(deadband_mm: f64) -> Self {
        Self {
            deadband_mm: deadband_mm.max(0.0),
            dir: 0,
            extreme_mm: None,
        }
    }

    /// +1 forward, −1 reverse, 0 before the first latch.
    pub fn dir(&self) -> i8 {
        self.dir
    }

    /// The latched approach (None before the first latch).
    pub fn approach(&self) -> Option<Approach> {
        Approach::from_sign(self.dir)
    }

    /// Feed the next position; returns `Some(extreme_mm)` when the direction changes (including the
    /// first latch), with the extreme the axis turned at (the first position for the first latch).
    /// Non-finite positions are ignored.
    pub fn update(&mut self, pos_mm: f64) -> Option<f64> {
        if !pos_mm.is_finite() {
            return None;
        }
        let db = self.deadband_mm;
        let ext = *self.extreme_mm.get_or_insert(pos_mm);
        let new_dir = match self.dir {
            1 if pos_mm < ext - db => -1,
            -1 if pos_mm > ext + db => 1,
            0 if pos_mm > ext + db => 1,
            0 if pos_mm < ext - db => -1,
            _ => {
                self.extreme_mm = Some(match self.dir {
                    1 => ext.max(pos_mm),
                    -1 => ext.min(pos_mm),
                    _ => ext,
                });
                return None;
            }
        };
        self.dir = new_dir;
        self.extreme_mm = Some(pos_mm);
        Some(ext)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reverses_only_after_the_deadband_back_from_the_extreme() {
        let mut l = ApproachLatch::new(0.01);
        assert_eq!(l.update(0.0), None);
        assert_eq!(l.dir(), 0);
        assert_eq!(l.update(0.005), None, "inside the deadband: not latched");
        assert_eq!(l.approach(), None);
        assert_eq!(l.update(1.0), Some(0.0));
        assert_eq!(l.dir(), 1);
        assert_eq!(l.approach(), Some(Approach::Forward));
        // Creep back by less than the deadband from the extreme (1.2) never flips.
        for p in [1.2, 1.195, 1.199, 1.191] {
            assert_eq!(l.update(p), None);
            assert_eq!(l.dir(), 1, "flipped at {p}");
        }
        assert_eq!(l.update(1.18), Some(1.2));
        assert_eq!(l.dir(), -1);
        assert_eq!(l.approach(), Some(Approach::Reverse));
        assert_eq!(latched_name(l.approach()), "reverse");
        assert_eq!(l.update(f64::NAN), None);
        assert_eq!(l.dir(), -1);
    }
}
