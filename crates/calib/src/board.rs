//! The calibration target's geometry: a chessboard's inner corners as 3-D
//! points on its plane (`Z = 0`), row by row, in the units of its square
//! size (which are then the units of every translation and the baseline).

use nalgebra::Point3;

/// The inner corners of a board with `cols` corners per row and `rows`
/// rows: corner `k` is at `(k % cols, k / cols) · square`.
pub fn board_points(cols: usize, rows: usize, square: f64) -> Vec<Point3<f64>> {
    (0..rows)
        .flat_map(|r| {
            (0..cols).map(move |c| Point3::new(c as f64 * square, r as f64 * square, 0.0))
        })
        .collect()
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
        let p = board_points(9, 6, 0.5);
        assert_eq!(p.len(), 54);
        assert_eq!(p[1], Point3::new(0.5, 0.0, 0.0));
        assert_eq!(p[9], Point3::new(0.0, 0.5, 0.0));
        assert_eq!(p[53], Point3::new(4.0, 2.5, 0.0));
    }
}
