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

    #[inline]
    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear sample at `(x, y)`, coordinates clamped to the image.
    pub(super) fn sample(&self, x: f64, y: f64) -> f64 {
        let x = x.clamp(0.0, (self.width - 1) as f64);
        let y = y.clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let top = self.at(x0, y0) as f64 * (1.0 - fx) + self.at(x1, y0) as f64 * fx;
        let bottom = self.at(x0, y1) as f64 * (1.0 - fx) + self.at(x1, y1) as f64 * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// A candidate corner: position (to about 0.3 px) and saddle response.
#[derive(Clone, Copy, Debug)]
pub(super) struct Candidate {
    pub(super) pos: Point2<f64>,
    pub(super) response: f32,
}

/// Pixels at the border where no candidate can be (ring plus the Hessian's
/// stencil).
pub(super) fn margin(options: &ChessboardOptions) -> usize {
    options.ring_radius.max(1.0).ceil() as usize + 2
}

/// Separable Gaussian smoothing of standard deviation `sigma` (clamped
/// borders); `sigma <= 0` only converts.
pub(super) fn smooth(image: &GrayImage, sigma: f64) -> Smooth {
    let (width, height) = image.dims();
    let src: Vec<f32> = image.as_slice().iter().map(|&v| v as f32).collect();
    let radius = if sigma > 0.0 {
        (3.0 * sigma).ceil() as usize
    } else {
        0
    };
    let kernel: Vec<f32> = {
        let raw: Vec<f64> = (0..=2 * radius)
            .map(|i| {
                let d = i as f64 - radius as f64;
                (-d * d / (2.0 * sigma * sigma).max(f64::MIN_POSITIVE)).exp()
            })
            .collect();
        let sum: f64 = raw.iter().sum();
        raw.iter().map(|k| (k / sum) as f32).collect()
    };
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let mut horizontal = vec![0f32; width * height];
    for y in 0..height {
        let row = &src[y * width..(y + 1) * width];
        let out = &mut horizontal[y * width..(y + 1) * width];
        for (x, o) in out.iter_mut().enumerate() {
            let interior = x >= radius && x + radius < width;
            *o = if interior {
                row[x - radius..=x + radius]
                    .iter()
                    .zip(&kernel)
                    .map(|(v, k)| v * k)
                    .sum()
            } else {
                kernel
                    .iter()
                    .enumerate()
                    .map(|(i, k)| row[clamp(x as isize + i as isize - radius as isize, width)] * k)
                    .sum()
            };
        }
    }
    let mut data = vec![0f32; width * height];
    for (i, k) in kernel.iter().enumerate() {
        for y in 0..height {
            let sy = clamp(y as isize + i as isize - radius as isize, height);
            let (src_row, out) = (
                &horizontal[sy * width..(sy + 1) * width],
                &mut data[y * width..(y + 1) * width],
            );
            for (o, v) in out.iter_mut().zip(src_row) {
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

/// Candidates, strongest first, at most
/// [`ChessboardOptions::max_candidates`].
pub(super) fn candidates(smooth: &Smooth, options: &ChessboardOptions) -> Vec<Candidate> {
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
            let v = resp[y * w + x];
            if v >= threshold && is_local_max(&resp, w, h, x, y, r) {
                maxima.push((x, y, v));
            }
        }
    }
    maxima.sort_by(|a, b| b.2.total_cmp(&a.2));
    let mut out = Vec::new();
    for &(x, y, v) in &maxima {
        if out.len() >= options.max_candidates {
            break;
        }
        let pos = peak_position(&resp, w, x, y);
        if is_x_junction(smooth, pos, options) {
            out.push(Candidate { pos, response: v });
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

/// The ring test: four light/dark sectors of at least two samples each, with
/// opposite boundaries π apart within [`ChessboardOptions::edge_tolerance`].
fn is_x_junction(smooth: &Smooth, pos: Point2<f64>, options: &ChessboardOptions) -> bool {
    let mut ring = [0f64; RING_SAMPLES];
    let step = std::f64::consts::TAU / RING_SAMPLES as f64;
    for (i, v) in ring.iter_mut().enumerate() {
        let a = i as f64 * step;
        *v = smooth.sample(
            pos.x + options.ring_radius * a.cos(),
            pos.y + options.ring_radius * a.sin(),
        );
    }
    let (lo, hi) = ring
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if hi - lo < options.min_contrast {
        return false;
    }
    let mid = 0.5 * (lo + hi);
    let mut changes = [0usize; 4];
    let mut count = 0;
    for i in 0..RING_SAMPLES {
        let prev = ring[(i + RING_SAMPLES - 1) % RING_SAMPLES] > mid;
        if (ring[i] > mid) != prev {
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
    let tolerance = options.edge_tolerance / step;
    let opposite = |a: usize, b: usize| ((b - a) as f64 - half).abs() <= tolerance;
    sectors_long && opposite(changes[0], changes[2]) && opposite(changes[1], changes[3])
}
