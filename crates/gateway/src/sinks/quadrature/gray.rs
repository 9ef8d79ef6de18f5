//! A/B Gray code: position phase ↔ pin levels, and a quadrature decoder (the receiver's view, used
//! to read native edges and to check the merged output stream).

/// One count up or down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Step {
    Up,
    Down,
}

impl Step {
    pub fn sign(self) -> i64 {
        match self {
            Step::Up => 1,
            Step::Down => -1,
        }
    }

    pub fn of_sign(n: i64) -> Option<Step> {
        match n.signum() {
            1 => Some(Step::Up),
            -1 => Some(Step::Down),
            _ => None,
        }
    }
}

/// Levels (A, B) for a position: phase 0:(0,0) 1:(1,0) 2:(1,1) 3:(0,1). Exactly one level changes per count.
pub fn levels_of_phase(position: i64) -> (bool, bool) {
    match position.rem_euclid(4) {
        0 => (false, false),
        1 => (true, false),
        2 => (true, true),
        _ => (false, true),
    }
}

fn phase_of_levels(a: bool, b: bool) -> i64 {
    match (a, b) {
        (false, false) => 0,
        (true, false) => 1,
        (true, true) => 2,
        (false, true) => 3,
    }
}

#[derive(Clone, Copy, Debug, thiserror::Error, PartialEq, Eq)]
pub enum DecodeError {
    /// Both lines changed at once: a count was lost (edges too close for the receiver, or noise).
    #[error(
        "illegal quadrature transition {from:?} -> {to:?}: both A and B changed, a count was lost"
    )]
    IllegalTransition {
        from: (bool, bool),
        to: (bool, bool),
    },
}

/// Counts A/B level changes like a controller's ×4 quadrature receiver.
#[derive(Clone, Debug)]
pub struct QuadDecoder {
    levels: (bool, bool),
    count: i64,
}

impl QuadDecoder {
    /// Start at the given line levels with count 0.
    pub fn new(a: bool, b: bool) -> Self {
        Self {
            levels: (a, b),
            count: 0,
        }
    }

    /// Feed the current levels; returns the step seen (None when nothing changed).
    pub fn update(&mut self, a: bool, b: bool) -> Result<Option<Step>, DecodeError> {
        let from = phase_of_levels(self.levels.0, self.levels.1);
        let to = phase_of_levels(a, b);
        let step = match (to - from).rem_euclid(4) {
            0 => None,
            1 => Some(Step::Up),
            3 => Some(Step::Down),
            _ => {
                return Err(DecodeError::IllegalTransition {
                    from: self.levels,
                    to: (a, b),
                });
            }
        };
        self.levels = (a, b);
        if let Some(s) = step {
            self.count += s.sign();
        }
        Ok(step)
    }

    pub fn count(&self) -> i64 {
        self.count
    }

    pub fn levels(&self) -> (bool, bool) {
        self.levels
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gray_code_changes_one_line_per_count() {
        for p in -8..8 {
            let (a0, b0) = levels_of_phase(p);
            let (a1, b1) = levels_of_phase(p + 1);
            assert_eq!(u8::from(a0 != a1) + u8::from(b0 != b1), 1, "phase {p}");
        }
    }

    #[test]
    fn decoder_counts_both_ways_and_rejects_double_change() {
        let mut d = QuadDecoder::new(false, false);
        for p in 1..=10 {
            let (a, b) = levels_of_phase(p);
            assert_eq!(d.update(a, b).unwrap(), Some(Step::Up));
        }
        for p in (7..10).rev() {
            let (a, b) = levels_of_phase(p);
            assert_eq!(d.update(a, b).unwrap(), Some(Step::Down));
        }
        assert_eq!(d.count(), 7);
        let (a, b) = levels_of_phase(7 + 2);
        assert!(d.update(a, b).is_err());
        assert_eq!(d.count(), 7);
    }
}
