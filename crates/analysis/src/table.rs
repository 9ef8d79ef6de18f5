//! Bidirectional one-axis error table: the error (actual − nominal, µm) of an axis at a list of
//! nominal positions (mm), separately for forward (+) and reverse (−) approach, as laser software,
//! Graves' Error File and Asad Ullah's F/R tables give it.
//!
//! Between points the error is interpolated linearly (Spaan Ch6: a zero-order hold made steps that
//! caused limit cycles); outside the table the end value is held (no extrapolation, so a table never
//! produces a value it was not measured to produce).

use serde::{Deserialize, Serialize};

/// Direction of approach: the crate's one definition ([`retrocomp_model::approach::Approach`]), under the
/// name this module's callers use.
pub use retrocomp_model::approach::Approach as Direction;

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct BidirectionalTable {
    /// Strictly increasing nominal positions.
    pub positions_mm: Vec<f64>,
    /// Error at each position when approached forward, actual − nominal.
    pub forward_um: Vec<f64>,
    /// Error at each position when approached in reverse, actual − nominal.
    pub reverse_um: Vec<f64>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TableError {
    #[error("table is empty")]
    Empty,
    #[error(
        "columns have different lengths: {positions} positions, {forward} forward, {reverse} reverse"
    )]
    Lengths {
        positions: usize,
        forward: usize,
        reverse: usize,
    },
    #[error(
        "positions must be strictly increasing: {prev_mm} mm is followed by {next_mm} mm (index {index})"
    )]
    NotIncreasing {
        index: usize,
        prev_mm: f64,
        next_mm: f64,
    },
    #[error("non-finite value at index {index}")]
    NonFinite { index: usize },
}

impl BidirectionalTable {
    /// Builds a checked table.
    pub fn new(
        positions_mm: Vec<f64>,
        forward_um: Vec<f64>,
        reverse_um: Vec<f64>,
    ) -> Result<Self, TableError> {
        let t = Self {
            positions_mm,
            forward_um,
            reverse_um,
        };
        t.validate()?;
        Ok(t)
    }

    /// A unidirectional table (forward = reverse).
    pub fn unidirectional(positions_mm: Vec<f64>, error_um: Vec<f64>) -> Result<Self, TableError> {
        Self::new(positions_mm, error_um.clone(), error_um)
    }

    pub fn validate(&self) -> Result<(), TableError> {
        let n = self.positions_mm.len();
        if n == 0 {
            return Err(TableError::Empty);
        }
        if self.forward_um.len() != n || self.reverse_um.len() != n {
            return Err(TableError::Lengths {
                positions: n,
                forward: self.forward_um.len(),
                reverse: self.reverse_um.len(),
            });
        }
        for i in 0..n {
            if !(self.positions_mm[i].is_finite()
                && self.forward_um[i].is_finite()
                && self.reverse_um[i].is_finite())
            {
                return Err(TableError::NonFinite { index: i });
            }
            if i > 0 && self.positions_mm[i] <= self.positions_mm[i - 1] {
                return Err(TableError::NotIncreasing {
                    index: i,
                    prev_mm: self.positions_mm[i - 1],
                    next_mm: self.positions_mm[i],
                });
            }
        }
        Ok(())
    }

    pub fn len(&self) -> usize {
        self.positions_mm.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions_mm.is_empty()
    }

    /// Values of one direction.
    pub fn values_um(&self, dir: Direction) -> &[f64] {
        match dir {
            Direction::Forward => &self.forward_um,
            Direction::Reverse => &self.reverse_um,
        }
    }

    /// Mean of forward and reverse at each point.
    pub fn mean_um(&self) -> Vec<f64> {
        self.forward_um
            .iter()
            .zip(&self.reverse_um)
            .map(|(f, r)| 0.5 * (f + r))
            .collect()
    }

    /// Error at `pos_mm` approached in `dir`, linearly interpolated, end values held outside.
    pub fn error_um(&self, pos_mm: f64, dir: Direction) -> f64 {
        interpolate(&self.positions_mm, self.values_um(dir), pos_mm)
    }
}

/// Piecewise-linear interpolation on strictly increasing `xs`, holding the end values outside.
pub fn interpolate(xs: &[f64], ys: &[f64], x: f64) -> f64 {
    let n = xs.len();
    if n == 1 || x <= xs[0] {
        return ys[0];
    }
    if x >= xs[n - 1] {
        return ys[n - 1];
    }
    // First index with xs[i] > x; x lies in [xs[i-1], xs[i]).
    let i = xs.partition_point(|&p| p <= x);
    let (x0, x1, y0, y1) = (xs[i - 1], xs[i], ys[i - 1], ys[i]);
    y0 + (y1 - y0) * (x - x0) / (x1 - x0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_is_linear_inside_and_held_outside() {
        let t = BidirectionalTable::new(
            vec![0.0, 10.0, 20.0],
            vec![0.0, 2.0, -2.0],
            vec![1.0, 1.0, 1.0],
        )
        .unwrap();
        assert_eq!(t.error_um(5.0, Direction::Forward), 1.0);
        assert_eq!(t.error_um(15.0, Direction::Forward), 0.0);
        assert_eq!(t.error_um(-3.0, Direction::Forward), 0.0);
        assert_eq!(t.error_um(25.0, Direction::Forward), -2.0);
        assert_eq!(t.error_um(10.0, Direction::Forward), 2.0);
        assert_eq!(t.error_um(12.0, Direction::Reverse), 1.0);
    }

    #[test]
    fn rejects_unsorted_and_ragged_tables() {
        assert!(matches!(
            BidirectionalTable::new(vec![0.0, 0.0], vec![0.0; 2], vec![0.0; 2]),
            Err(TableError::NotIncreasing { index: 1, .. })
        ));
        assert!(matches!(
            BidirectionalTable::new(vec![0.0], vec![0.0; 2], vec![0.0]),
            Err(TableError::Lengths { .. })
        ));
        assert!(matches!(
            BidirectionalTable::new(vec![0.0], vec![f64::NAN], vec![0.0]),
            Err(TableError::NonFinite { index: 0 })
        ));
    }
}
