//! Candidate chessboard corners: saddle points of the smoothed image that a
//! ring test confirms as X-junctions.
//!
//! At an X-junction the smoothed intensity is locally `c·x·y` in the edges'
//! frame, so the Hessian determinant is negative; `Ixy² − Ixx·Iyy` peaks
//! there (Chen & Zhang 2005, "Sub-pixel detection of X-corners"). Blobs and
//! straight edges give a response near zero or negative, but texture and
//! noise give saddles too, so each local maximum must also show, on a ring of
//! [`ChessboardOptions::ring_radius`], four alternating light and dark
//! sectors whose boundaries are pairwise opposite (two straight edges through
//! the point).

use nalgebra::Point2;
use stereolink_image::GrayImage;

use super::ChessboardOptions;

/// Samples on the ring of the X-junction test (11.25° apart).
const RING_SAMPLES: usize = 32;

/// A gray image smoothed to `f32`, with bilinear sampling.
pub(super) struct Smooth {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl Smooth {
    /// `(width, height)`.
    pub(super) fn dims(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The pixel at `(x, y)`, coordinates clamped to the image (replicated
    /// borders); the image must not be empty.
    #[inline]
    pub(super) fn pixel(&self, x: isize, y: isize) -> f64 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.data[y * self.width + x] as f64
    }

    /// Bilinear sample at `(x, y)` with replicated borders.
    pub(super) fn sample(&self, x: f64, y: f64) -> f64 {
        let limit = (self.width + self.height) as f64;
        let (x, y) = (x.clamp(-1.0, limit), y.clamp(-1.0, limit));
        let (fx, fy) = (x.floor(), y.floor());
        let (ax, ay) = (x - fx, y - fy);
        let (ix, iy) = (fx as isize, fy as isize);
        let top = self.pixel(ix, iy) * (1.0 - ax) + self.pixel(ix + 1, iy) * ax;
        let bottom = self.pixel(ix, iy + 1) * (1.0 - ax) + self.pixel(ix + 1, iy + 1) * ax;
        top * (1.0 - ay) + bottom * ay
    }
}

/// Pixels at the border where no candidate can be (ring plus the Hessian's
/// stencil).
pub(super) fn margin(options: &ChessboardOptions) -> usize {
    options.ring_radius.max(1.0).ceil() as usize + 2
}

/// Separable Gaussian smoothing of standard deviation `sigma` (replicated
/// borders); `sigma <= 0` only converts to `f32`.
pub(super) fn smooth(image: &GrayImage, sigma: f64) -> Smooth {
    let (width, height) = image.dims();
    if sigma <= 0.0 || width == 0 || height == 0 {
        return Smooth {
            width,
            height,
            data: image.as_slice().iter().map(|&v| v as f32).collect(),
        };
    }
    // Beyond the image size a wider kernel only repeats border pixels.
    let radius = ((3.0 * sigma).ceil() as usize).min(width.max(height));
    let kernel: Vec<f32> = {
        let raw: Vec<f64> = (0..=2 * radius)
            .map(|i| {
                let d = i as f64 - radius as f64;
                (-d * d / (2.0 * sigma * sigma)).exp()
            })
            .collect();
        let sum: f64 = raw.iter().sum();
        raw.iter().map(|k| (k / sum) as f32).collect()
    };
    // Rows: each tap adds a shifted copy of the (border-padded) row, a loop
    // the compiler vectorises.
    let mut horizontal = vec![0f32; width * height];
    let mut padded = vec![0f32; width + 2 * radius];
    for (y, row) in image.rows().enumerate() {
        padded[..radius].fill(row[0] as f32);
        for (p, &v) in padded[radius..radius + width].iter_mut().zip(row) {
            *p = v as f32;
        }
        padded[radius + width..].fill(row[width - 1] as f32);
        let out = &mut horizontal[y * width..(y + 1) * width];
        for (i, k) in kernel.iter().enumerate() {
            for (o, v) in out.iter_mut().zip(&padded[i..i + width]) {
                *o += k * v;
            }
        }
    }
    // Columns: the same, a shifted row at a time.
    let mut data = vec![0f32; width * height];
    for y in 0..height {
        let out = &mut data[y * width..(y + 1) * width];
        for (i, k) in kernel.iter().enumerate() {
            let sy = (y + i).saturating_sub(radius).min(height - 1);
            for (o, v) in out
                .iter_mut()
                .zip(&horizontal[sy * width..(sy + 1) * width])
            {
                *o += k * v;
            }
        }
    }
    Smooth {
        width,
        height,
        data,
    }
}

/// The saddle response `Ixy² − Ixx·Iyy` (central differences), zero within
/// `margin` of the border.
fn response(smooth: &Smooth, margin: usize) -> Vec<f32> {
    let (w, h) = smooth.dims();
    let mut out = vec![0f32; w * h];
    let d = &smooth.data;
    for y in margin..h.saturating_sub(margin) {
        for x in margin..w.saturating_sub(margin) {
            let i = y * w + x;
            let ixx = d[i + 1] - 2.0 * d[i] + d[i - 1];
            let iyy = d[i + w] - 2.0 * d[i] + d[i - w];
            let ixy = 0.25 * (d[i + w + 1] - d[i + w - 1] - d[i - w + 1] + d[i - w - 1]);
            out[i] = ixy * ixy - ixx * iyy;
        }
    }
    out
}

/// Candidate corner positions (to about 0.3 px), strongest response first,
/// at most [`ChessboardOptions::max_candidates`].
pub(super) fn candidates(smooth: &Smooth, options: &ChessboardOptions) -> Vec<Point2<f64>> {
    let (w, h) = smooth.dims();
    let margin = margin(options);
    if w <= 2 * margin || h <= 2 * margin {
        return Vec::new();
    }
    let resp = response(smooth, margin);
    let peak = resp.iter().copied().fold(0f32, f32::max);
    if peak <= 0.0 {
        return Vec::new();
    }
    let threshold = (peak as f64 * options.min_response_ratio).max(f64::MIN_POSITIVE) as f32;
    let r = options.nms_radius.max(1);
    let mut maxima = Vec::new();
    for y in margin..h - margin {
        for x in margin..w - margin {
            let i = y * w + x;
            let v = resp[i];
            if v < threshold
                || v < resp[i - 1]
                || v < resp[i + 1]
                || v < resp[i - w]
                || v < resp[i + w]
            {
                continue;
            }
            if is_local_max(&resp, w, h, x, y, r) {
                maxima.push((x, y, v));
            }
        }
    }
    maxima.sort_by(|a, b| b.2.total_cmp(&a.2));
    // Ring samples at whole-pixel offsets: the test reads signs of a smooth
    // image, where half a pixel of position moves a transition by < 0.1 rad.
    let step = std::f64::consts::TAU / RING_SAMPLES as f64;
    let ring: [isize; RING_SAMPLES] = std::array::from_fn(|i| {
        let (sin, cos) = (i as f64 * step).sin_cos();
        let dx = (options.ring_radius * cos).round() as isize;
        let dy = (options.ring_radius * sin).round() as isize;
        dy * w as isize + dx
    });
    let mut out = Vec::new();
    for &(x, y, _) in &maxima {
        if out.len() >= options.max_candidates {
            break;
        }
        if is_x_junction(&smooth.data, y * w + x, &ring, options) {
            out.push(peak_position(&resp, w, x, y));
        }
    }
    out
}

/// True if `(x, y)` is the maximum of its `(2r+1)²` window (ties go to the
/// first in raster order).
fn is_local_max(resp: &[f32], w: usize, h: usize, x: usize, y: usize, r: usize) -> bool {
    let v = resp[y * w + x];
    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
            let u = resp[yy * w + xx];
            let before = (yy, xx) < (y, x);
            if u > v || (u == v && before) {
                return false;
            }
        }
    }
    true
}

/// The response peak to subpixel precision: a parabola through the three
/// values on each axis, the offset clamped to half a pixel.
fn peak_position(resp: &[f32], w: usize, x: usize, y: usize) -> Point2<f64> {
    let i = y * w + x;
    let offset = |minus: f32, centre: f32, plus: f32| {
        let curvature = (minus - 2.0 * centre + plus) as f64;
        if curvature < 0.0 {
            (0.5 * (minus - plus) as f64 / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    Point2::new(
        x as f64 + offset(resp[i - 1], resp[i], resp[i + 1]),
        y as f64 + offset(resp[i - w], resp[i], resp[i + w]),
    )
}

/// The ring test at pixel `centre` (an index into `data`, with every
/// `ring` offset inside): four light/dark sectors of at least two samples
/// each, with opposite boundaries π apart within
/// [`ChessboardOptions::edge_tolerance`].
fn is_x_junction(
    data: &[f32],
    centre: usize,
    ring: &[isize; RING_SAMPLES],
    options: &ChessboardOptions,
) -> bool {
    let values: [f32; RING_SAMPLES] =
        std::array::from_fn(|i| data[centre.wrapping_add_signed(ring[i])]);
    let (lo, hi) = values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if ((hi - lo) as f64) < options.min_contrast {
        return false;
    }
    let mid = 0.5 * (lo + hi);
    let mut changes = [0usize; 4];
    let mut count = 0;
    for i in 0..RING_SAMPLES {
        let prev = values[(i + RING_SAMPLES - 1) % RING_SAMPLES] > mid;
        if (values[i] > mid) != prev {
            if count == 4 {
                return false;
            }
            changes[count] = i;
            count += 1;
        }
    }
    if count != 4 {
        return false;
    }
    let sectors_long = (0..4).all(|k| {
        let next = if k == 3 {
            changes[0] + RING_SAMPLES
        } else {
            changes[k + 1]
        };
        next - changes[k] >= 2
    });
    let half = RING_SAMPLES as f64 / 2.0;
    let tolerance = options.edge_tolerance * RING_SAMPLES as f64 / std::f64::consts::TAU;
    let opposite = |a: usize, b: usize| ((b - a) as f64 - half).abs() <= tolerance;
    sectors_long && opposite(changes[0], changes[2]) && opposite(changes[1], changes[3])
}
