//! Subpixel corner refinement by gradient orthogonality (Förstner & Gülch
//! 1987), the method of OpenCV's `cornerSubPix`.
//!
//! At the true corner `q`, every image gradient `g(p)` in a window is
//! orthogonal to `p − q` (zero on flat areas, across the edge on edges), so
//! `q` solves the weighted least squares `Σ w·g·gᵀ · q = Σ w·g·gᵀ · p`. The
//! window is resampled bilinearly around the current estimate, the system
//! solved, and the step repeated until it moves less than
//! [`SubpixOptions::epsilon`]. Weights, gradients (central differences, not
//! halved) and stopping rules follow OpenCV so the corners agree with its
//! tool chain.

use nalgebra::Point2;
use stereolink_image::GrayImage;

use super::saddle::smooth;

/// Largest accepted [`SubpixOptions::half_window`].
pub const MAX_HALF_WINDOW: usize = 64;

/// Tuning of [`refine_corners`]; the defaults are the usual OpenCV
/// calibration call, `cornerSubPix(winSize (11,11) i.e. 23x23, zeroZone
/// (-1,-1), EPS + MAX_ITER 30, 0.001)`, with light smoothing added (the call of OpenCV's calibration
/// tutorial and of the shared set's MANIFEST). [`find_chessboard_with`]
/// shrinks the window on boards whose squares are too small for it.
///
/// [`find_chessboard_with`]: super::find_chessboard_with
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SubpixOptions {
    /// Half the window side: the window is `(2·half_window + 1)²` pixels
    /// (`half_window` is clamped to 1..=[`MAX_HALF_WINDOW`]). It should cover
    /// the corner but not the next one (at most half a square side).
    pub half_window: usize,
    /// Most iterations.
    pub max_iterations: usize,
    /// Stop when an iteration moves the corner by at most this (px).
    pub epsilon: f64,
    /// Standard deviation (px) of a Gaussian applied before the gradients;
    /// 0 is OpenCV's behaviour. The default 0.8 removes the aliasing bias of
    /// sharp, nearly axis-aligned edges (see the crate's tests), and on the
    /// shared real set it lowers the reprojection errors and the rectified
    /// row offset (docs/tuning.md, “Gradient smoothing: 0.8 px”).
    pub sigma: f64,
}

impl Default for SubpixOptions {
    fn default() -> Self {
        SubpixOptions {
            half_window: 11,
            max_iterations: 30,
            epsilon: 0.001,
            sigma: 0.8,
        }
    }
}

/// Refines `corners` in place on `image`. A corner whose iteration leaves
/// the image or wanders further than the half window keeps its start value,
/// as in OpenCV.
pub fn refine_corners(image: &GrayImage, corners: &mut [Point2<f64>], options: &SubpixOptions) {
    if image.is_empty() {
        return;
    }
    let half = options.half_window.clamp(1, MAX_HALF_WINDOW);
    let side = 2 * half + 1;
    let weights: Vec<f64> = (0..side * side)
        .map(|k| {
            let y = (k / side) as f64 / half as f64 - 1.0;
            let x = (k % side) as f64 / half as f64 - 1.0;
            (-x * x - y * y).exp()
        })
        .collect();
    let mut patch = vec![0f64; (side + 2) * (side + 2)];
    // Smoothing of sigma 0 only converts to f32: OpenCV's raw gradients.
    let plane = smooth(image, options.sigma);
    let pixel = |x, y| plane.pixel(x, y);
    for corner in corners {
        *corner = refine(
            pixel,
            image.dims(),
            *corner,
            half,
            &weights,
            &mut patch,
            options,
        );
    }
}

/// One corner; `pixel(x, y)` reads the image with replicated borders.
fn refine(
    pixel: impl Fn(isize, isize) -> f64 + Copy,
    (w, h): (usize, usize),
    start: Point2<f64>,
    half: usize,
    weights: &[f64],
    patch: &mut [f64],
    options: &SubpixOptions,
) -> Point2<f64> {
    let side = 2 * half + 1;
    let stride = side + 2;
    let (w, h) = (w as f64, h as f64);
    let tolerance = options.epsilon * options.epsilon;
    let mut q = start;
    for _ in 0..options.max_iterations.max(1) {
        sample_patch(pixel, q, stride, patch);
        let (mut a, mut b, mut c, mut bb1, mut bb2) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..side {
            let py = i as f64 - half as f64;
            for j in 0..side {
                let px = j as f64 - half as f64;
                let m = weights[i * side + j];
                let gx = patch[(i + 1) * stride + j + 2] - patch[(i + 1) * stride + j];
                let gy = patch[(i + 2) * stride + j + 1] - patch[i * stride + j + 1];
                let (gxx, gxy, gyy) = (gx * gx * m, gx * gy * m, gy * gy * m);
                a += gxx;
                b += gxy;
                c += gyy;
                bb1 += gxx * px + gxy * py;
                bb2 += gxy * px + gyy * py;
            }
        }
        let det = a * c - b * b;
        if det.abs() <= f64::EPSILON * f64::EPSILON {
            break;
        }
        let next = Point2::new(
            q.x + (c * bb1 - b * bb2) / det,
            q.y + (a * bb2 - b * bb1) / det,
        );
        let moved = (next - q).norm_squared();
        q = next;
        if !(q.x >= 0.0 && q.x < w && q.y >= 0.0 && q.y < h) || moved <= tolerance {
            break;
        }
    }
    let far = (q.x - start.x).abs() > half as f64 || (q.y - start.y).abs() > half as f64;
    if far || !(q.x.is_finite() && q.y.is_finite()) {
        start
    } else {
        q
    }
}

/// The `stride`² window centred on `centre`, bilinear, borders replicated
/// (OpenCV's `getRectSubPix`).
fn sample_patch(
    pixel: impl Fn(isize, isize) -> f64,
    centre: Point2<f64>,
    stride: usize,
    patch: &mut [f64],
) {
    let origin_x = centre.x - (stride - 1) as f64 / 2.0;
    let origin_y = centre.y - (stride - 1) as f64 / 2.0;
    let (fx, fy) = (origin_x.floor(), origin_y.floor());
    let (ax, ay) = (origin_x - fx, origin_y - fy);
    // Far outside, every sample is a border pixel anyway.
    let limit = 1e9;
    let (ix, iy) = (
        fx.clamp(-limit, limit) as isize,
        fy.clamp(-limit, limit) as isize,
    );
    for i in 0..stride {
        let y = iy + i as isize;
        for j in 0..stride {
            let x = ix + j as isize;
            let top = pixel(x, y) * (1.0 - ax) + pixel(x + 1, y) * ax;
            let bottom = pixel(x, y + 1) * (1.0 - ax) + pixel(x + 1, y + 1) * ax;
            patch[i * stride + j] = top * (1.0 - ay) + bottom * ay;
        }
    }
}
