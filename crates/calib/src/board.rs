//! The calibration target's geometry: a chessboard's inner corners as 3-D
//! points on its plane (`Z = 0`), row by row, in the units of its square
//! size (which are then the units of every translation and the baseline).

use nalgebra::Point3;

/// A chessboard's size in **inner** corners: a board of 10x7 squares is
/// `BoardSize { cols: 9, rows: 6 }`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BoardSize {
    /// Inner corners per row.
    pub cols: usize,
    /// Rows of inner corners.
    pub rows: usize,
}

impl BoardSize {
    /// `cols`x`rows` inner corners.
    pub const fn new(cols: usize, rows: usize) -> Self {
        BoardSize { cols, rows }
    }

    /// Number of inner corners.
    pub fn count(&self) -> usize {
        self.cols * self.rows
    }

    /// The inner corners as board points, row by row: corner `k` is at
    /// `(k % cols, k / cols) · square`.
    pub fn points(&self, square: f64) -> Vec<Point3<f64>> {
        let cols = self.cols;
        (0..self.rows)
            .flat_map(|r| {
                (0..cols).map(move |c| Point3::new(c as f64 * square, r as f64 * square, 0.0))
            })
            .collect()
    }

    /// The same board with rows and columns exchanged.
    pub fn transposed(&self) -> Self {
        BoardSize::new(self.rows, self.cols)
    }
}

impl std::fmt::Display for BoardSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.cols, self.rows)
    }
}

impl std::str::FromStr for BoardSize {
    type Err = String;

    /// Parses `COLSxROWS`, e.g. `9x6`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || format!("board size {s:?} is not COLSxROWS (inner corners, e.g. 9x6)");
        let (c, r) = s.split_once(['x', 'X']).ok_or_else(bad)?;
        let cols = c.trim().parse().map_err(|_| bad())?;
        let rows = r.trim().parse().map_err(|_| bad())?;
        Ok(BoardSize::new(cols, rows))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use nalgebra::{Rotation3, Vector3};

    use super::*;
    use crate::Pose;

    /// `n` poses of a 9x6 board about 0.5 m (20 squares of 0.025) in front
    /// of a camera, tilted up to about 35° about varied axes.
    pub(crate) fn spread_poses(square: f64, n: usize) -> Vec<Pose> {
        let centre = Vector3::new(4.0 * square, 2.5 * square, 0.0);
        (0..n)
            .map(|i| {
                let a = i as f64 * 2.399_963; // the golden angle spreads the axes
                let tilt = 0.45 + 0.35 * ((i % 3) as f64 / 2.0);
                let axis = Vector3::new(a.cos(), a.sin(), 0.0);
                let roll = 0.2 * ((i % 5) as f64 - 2.0);
                let r = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), tilt)
                    * Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
                let at = Vector3::new(
                    0.06 * (a * 1.7).sin(),
                    0.04 * (a * 2.3).cos(),
                    11.0 * square * (1.0 + 0.3 * ((i % 4) as f64 / 3.0)),
                );
                let t = at - r * centre;
                Pose {
                    rotation: r.scaled_axis(),
                    translation: t,
                }
            })
            .collect()
    }

    #[test]
    fn corners_run_row_by_row() {
        let p = BoardSize::new(9, 6).points(0.5);
        assert_eq!(p.len(), 54);
        assert_eq!(p[1], Point3::new(0.5, 0.0, 0.0));
        assert_eq!(p[9], Point3::new(0.0, 0.5, 0.0));
        assert_eq!(p[53], Point3::new(4.0, 2.5, 0.0));
    }
}
