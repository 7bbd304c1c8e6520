//! Synthetic truth for tests and benches: a rig built around a chosen
//! rectification (so its `R1, R2, P1, P2, Q` are exact without running
//! `stereoRectify`), and raw camera views rendered from rectified ones, the
//! inverse of the rectification maps; and chessboard views through a known
//! camera and pose, the truth the calibration tests recover. They extend the
//! synthetic scenes of `stereolink_image::synth` with lens distortion and
//! poses, which need this crate's camera model (so they live here).
//!
//! A chessboard pixel is the mean of `samples × samples` rays through it:
//! a ray is undistorted, intersected with the board's plane, and takes the
//! square's colour there (a white margin of one square around the board, a
//! mid-gray background beyond), which antialiases the edges as a lens does.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Point2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stereolink_image::{GrayImage, Plane};

use crate::remap::{sample_bilinear, Pixel};
use crate::{BoardSize, Camera, Pose, Rectification, StereoCalibration, StereoRig};

/// The rectified pair's geometry: both rectified cameras have focal length
/// `focal` and principal row `cy`; the left's principal column is `cx`, the
/// right's `cx + doffs`; the right sits `baseline` along the left's x axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RectifiedGeometry {
    /// Focal length of the rectified cameras, pixels.
    pub focal: f64,
    /// Left principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Right principal point x minus the left's (Middlebury's `doffs`).
    pub doffs: f64,
    /// Baseline, in the units the rig's `T` is to be in.
    pub baseline: f64,
    /// Rectified image size (width, height).
    pub size: (usize, usize),
}

/// The calibration of two cameras whose frames the rectifying rotations
/// `r1`, `r2` turn into a rectified pair of `geometry`: `R = R2ᵀ·R1`, `T =
/// R2ᵀ·(−b, 0, 0)`, and `P1, P2, Q` as `cv::stereoRectify` forms them.
pub fn rig_around(
    left: Camera,
    right: Camera,
    r1: Matrix3<f64>,
    r2: Matrix3<f64>,
    geometry: &RectifiedGeometry,
) -> StereoCalibration {
    let g = geometry;
    let tx = -g.baseline;
    let projection = |cx: f64, fx_tx: f64| {
        Matrix3x4::new(
            g.focal, 0.0, cx, fx_tx, 0.0, g.focal, g.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        )
    };
    let cx2 = g.cx + g.doffs;
    #[rustfmt::skip]
    let q = Matrix4::new(
        1.0, 0.0, 0.0, -g.cx,
        0.0, 1.0, 0.0, -g.cy,
        0.0, 0.0, 0.0, g.focal,
        0.0, 0.0, -1.0 / tx, (g.cx - cx2) / tx,
    );
    StereoCalibration {
        rig: StereoRig {
            left,
            right,
            rotation: r2.transpose() * r1,
            translation: r2.transpose() * Vector3::new(tx, 0.0, 0.0),
        },
        rectification: Rectification {
            r1,
            r2,
            p1: projection(g.cx, 0.0),
            p2: projection(cx2, g.focal * tx),
            q,
            size: g.size,
        },
    }
}

/// The raw view `camera` would have seen of the rectified view
/// `rectified` (rectifying rotation `r`, projection `p`): each raw pixel is
/// undistorted, rotated into the rectified frame, projected and sampled
/// (floating-point bilinear, black outside).
pub fn unrectify<P: Pixel>(
    rectified: &Plane<P>,
    camera: &Camera,
    r: &Matrix3<f64>,
    p: &Matrix3x4<f64>,
) -> Plane<P> {
    let k = p.fixed_view::<3, 3>(0, 0) * r;
    Plane::from_fn(camera.width, camera.height, |x, y| {
        let n = camera.normalised(Point2::new(x as f64, y as f64));
        let q = k * Vector3::new(n.x, n.y, 1.0);
        if q.z <= 0.0 {
            return P::default();
        }
        let (u, v) = (q.x / q.z, q.y / q.z);
        P::from_fn(|c| sample_bilinear(rectified, u, v, c).round() as u8)
    })
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::tests::calibration;

    #[test]
    fn the_rig_and_its_rectification_agree() {
        let c = calibration();
        let (rig, rect) = (c.rig, c.rectification);
        // A 3-D point seen by both rectified cameras lands on one row, at
        // the disparity Q turns back into it.
        let x_l = Vector3::new(0.21, -0.13, 1.7);
        let x_r = rig.rotation * x_l + rig.translation;
        // P1 and P2 project points of the left rectified frame; the right
        // camera's own point, rotated by R2, lands on the same pixel.
        let pl = rect.p1 * (rect.r1 * x_l).push(1.0);
        let pr = rect.p2 * (rect.r1 * x_l).push(1.0);
        let (pl, pr) = (pl / pl.z, pr / pr.z);
        let own = rect.p2.fixed_view::<3, 3>(0, 0) * (rect.r2 * x_r);
        assert!((own / own.z - pr).norm() < 1e-9);
        assert!((pl.y - pr.y).abs() < 1e-9);
        let d = pl.x - pr.x;
        let back = rect.q * nalgebra::Vector4::new(pl.x, pl.y, d, 1.0);
        let back = back.xyz() / back.w;
        assert!((back - rect.r1 * x_l).norm() < 1e-9, "{back}");
        let (f, b, doffs) = rect.depth_geometry();
        assert!((b * f / (d + doffs) - (rect.r1 * x_l).z).abs() < 1e-9);
        assert!((rig.baseline() - b).abs() < 1e-12);
    }

    #[test]
    fn unrectify_then_rectify_restores_the_view() {
        let c = calibration();
        let (cam, rect) = (c.rig.left, c.rectification);
        let view = Plane::from_fn(640, 480, |x, y| {
            (128.0 + 50.0 * (x as f64 / 11.0).sin() * (y as f64 / 13.0).cos()) as u8
        });
        let raw = unrectify(&view, &cam, &rect.r1, &rect.p1);
        let map = crate::RectifyMap::new(&cam, &rect.r1, &rect.p1, rect.size).unwrap();
        let back = map.apply(&raw).unwrap();
        let (mut sum, mut n) = (0.0, 0);
        for y in 40..440 {
            for x in 40..600 {
                sum += (f64::from(back.get(x, y)) - f64::from(view.get(x, y))).abs();
                n += 1;
            }
        }
        assert!(sum / (n as f64) < 1.0, "mean error {}", sum / n as f64);
    }
}
