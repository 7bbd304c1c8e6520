//! Synthetic chessboard views through a known camera: the truth that the
//! calibration tests recover. It extends the synthetic scenes of
//! `stereolink_image::synth` with lens distortion and board poses, which
//! need this crate's camera model (so it lives here, not in `image`).
//!
//! Each pixel is the mean of `samples × samples` rays through it: a ray is
//! undistorted, intersected with the board's plane, and takes the square's
//! colour there (a white margin of one square around the board, a mid-gray
//! background beyond), which antialiases the edges as a real lens does.

use nalgebra::{Point2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stereolink_image::GrayImage;

use crate::chessboard::BoardSize;
use crate::{Camera, Pose};

/// How a view is rendered.
#[derive(Clone, Copy, Debug)]
pub struct RenderSpec {
    /// The board's inner corners.
    pub board: BoardSize,
    /// Square side, in the pose's units.
    pub square: f64,
    /// Rays per pixel along each axis.
    pub samples: usize,
    /// Gaussian noise added to each pixel, gray levels.
    pub noise: f64,
    /// The noise's seed.
    pub seed: u64,
}

/// Gray levels of the board's dark squares, light squares and the scene
/// behind the board.
const DARK: f64 = 30.0;
const LIGHT: f64 = 220.0;
const BACKGROUND: f64 = 120.0;

/// The view of the board at `pose` through `camera`.
pub fn render_board(camera: &Camera, pose: &Pose, spec: &RenderSpec) -> GrayImage {
    let r = pose.matrix();
    let t = pose.translation;
    // The board plane in camera coordinates: points t + r·(X, Y, 0).
    let normal = r.column(2).into_owned();
    let (ex, ey) = (r.column(0).into_owned(), r.column(1).into_owned());
    let (cols, rows) = (spec.board.cols as f64, spec.board.rows as f64);
    let n = spec.samples.max(1);
    // Undistorted rays at the pixels' corners; rays inside a pixel are
    // interpolated between them (the distortion is smooth at that scale).
    let (w, h) = (camera.width, camera.height);
    let corners: Vec<Point2<f64>> = (0..=h)
        .flat_map(|y| (0..=w).map(move |x| (x, y)))
        .map(|(x, y)| camera.normalised(Point2::new(x as f64 - 0.5, y as f64 - 0.5)))
        .collect();
    let ray_at = |x: usize, y: usize, fx: f64, fy: f64| {
        let c = |i: usize, j: usize| corners[j * (w + 1) + i].coords;
        let top = c(x, y) * (1.0 - fx) + c(x + 1, y) * fx;
        let bottom = c(x, y + 1) * (1.0 - fx) + c(x + 1, y + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    };
    let shade = |ray: nalgebra::Vector2<f64>| -> f64 {
        let d = Vector3::new(ray.x, ray.y, 1.0);
        let denom = normal.dot(&d);
        if denom.abs() < 1e-12 {
            return BACKGROUND;
        }
        let s = normal.dot(&t) / denom;
        if s <= 0.0 {
            return BACKGROUND;
        }
        let q = d * s - t;
        let (bx, by) = (ex.dot(&q) / spec.square, ey.dot(&q) / spec.square);
        // Squares span −1..cols+1 and −1..rows+1 (inner corners at 0..cols−1);
        // one more square of white margin around them.
        if bx < -2.0 || by < -2.0 || bx > cols + 1.0 || by > rows + 1.0 {
            return BACKGROUND;
        }
        if bx < -1.0 || by < -1.0 || bx > cols || by > rows {
            return LIGHT;
        }
        // The square outside corner 0 (x, y < 0) is dark.
        if (bx.floor() as i64 + by.floor() as i64).rem_euclid(2) == 0 {
            DARK
        } else {
            LIGHT
        }
    };
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    GrayImage::from_fn(w, h, |x, y| {
        let mut sum = 0.0;
        for j in 0..n {
            for i in 0..n {
                let (fx, fy) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                sum += shade(ray_at(x, y, fx, fy));
            }
        }
        let noise = if spec.noise > 0.0 {
            let (a, b): (f64, f64) = (rng.gen_range(1e-12..1.0), rng.gen());
            spec.noise * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        } else {
            0.0
        };
        (sum / (n * n) as f64 + noise).round().clamp(0.0, 255.0) as u8
    })
}
