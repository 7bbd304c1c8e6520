//! Mean shift segmentation (Comaniciu & Meer, PAMI 2002; the paper's
//! III.A.1) in the joint spatial-range domain.
//!
//! **Filtering** (eq. 3–4): each pixel's point `(x, y, c)` (colour `c` in
//! L\*u\*v\* or RGB) moves to the mean of the pixels inside its window (a
//! `(2h_s+1)²` square in space and, with the uniform kernel, a ball of radius
//! `h_r` in colour; the Gaussian kernel weights the colour distance instead)
//! until the shift is below `threshold` or `max_iterations` is reached.
//! **Clustering**: neighbouring pixels whose modes are closer than `h_r / 2`
//! in colour join one region (their basins of attraction merged); regions
//! smaller than `min_region` pixels are merged into the adjacent region of
//! the most similar colour (mostly: see [`MeanShiftSpec::min_region`]), and beyond
//! [`crate::MAX_LABELS`] regions the smallest merge into their most similar
//! neighbours. Each region is shown in its mean original colour.
//!
//! The window sums run on the colours as three planes, eight pixels per
//! step in lanes (lanes past a row's end weigh 0): with AVX2 intrinsics for
//! the uniform kernel where the CPU has them, otherwise portable code doing
//! the same operations in the same order, so both give the same bits.
//!
//! The paper's setting is [`MeanShiftSpec::paper`] (`h_s = 40`, `h_r = 3`,
//! threshold 3). The default (`h_s = 8`, `h_r = 8` in L\*u\*v\*) keeps the
//! filtering affordable on the sender's CPU and gives far fewer regions.

use rayon::prelude::*;
use serde::Serialize;
use stereolink_image::{color, Plane, RgbImage};

use crate::regions::{cap_regions, find, merge_small_regions, region_sums};
use crate::{compact, SegmentError, Segmentation, MAX_LABELS};

/// Colour space of the range domain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ColourSpace {
    /// CIE L\*u\*v\* (perceptually uniform; Comaniciu & Meer's choice).
    Luv,
    /// Plain RGB.
    Rgb,
}

/// Range kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Kernel {
    /// Flat: every pixel within `h_r` counts equally.
    Uniform,
    /// Gaussian weights `exp(−||Δc||² / (2 h_r²))` over a `3 h_r` ball.
    Gaussian,
}

/// Mean shift parameters.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MeanShiftSpec {
    /// Spatial bandwidth h_s (pixels).
    pub spatial: usize,
    /// Range bandwidth h_r (colour units).
    pub range: f32,
    /// Stop when a shift is below this.
    pub threshold: f32,
    /// Most iterations per pixel.
    pub max_iterations: usize,
    /// Range domain.
    pub colour_space: ColourSpace,
    /// Range kernel.
    pub kernel: Kernel,
    /// Regions smaller than this are merged into a neighbour, in a few
    /// rounds that leave equal regions picking each other alone (the
    /// one-pixel regions of pixel noise).
    pub min_region: usize,
    /// Coarse-to-fine levels, as OpenCV's `pyrMeanShiftFiltering`
    /// `maxLevel` (0 = filter every pixel, the exact procedure): see
    /// [`modes`]. At most [`MAX_PYRAMID`]. The default 1 barely changes the
    /// segmentation and saves time (docs/tuning.md, “Mean shift pyramid”).
    pub pyramid: usize,
}

/// Most coarse-to-fine levels ([`MeanShiftSpec::pyramid`]).
pub const MAX_PYRAMID: usize = 8;

impl Default for MeanShiftSpec {
    fn default() -> Self {
        MeanShiftSpec {
            spatial: 8,
            range: 8.0,
            threshold: 0.5,
            max_iterations: 8,
            colour_space: ColourSpace::Luv,
            kernel: Kernel::Uniform,
            min_region: 50,
            pyramid: 1,
        }
    }
}

impl MeanShiftSpec {
    /// The paper's preset: h_s = 40, h_r = 3, threshold 3, every pixel
    /// filtered (no pyramid).
    pub fn paper() -> Self {
        MeanShiftSpec {
            spatial: 40,
            range: 3.0,
            threshold: 3.0,
            pyramid: 0,
            ..Self::default()
        }
    }

    fn validate(&self) -> Result<(), SegmentError> {
        if self.spatial == 0
            || self.spatial > 200
            || self.range.is_nan()
            || self.range <= 0.0
            || self.threshold.is_nan()
            || self.threshold < 0.0
        {
            return Err(SegmentError::Parameter(format!(
                "mean shift needs h_s in 1..=200, h_r > 0 and a threshold >= 0 \
                 (got h_s {}, h_r {}, threshold {})",
                self.spatial, self.range, self.threshold
            )));
        }
        if self.pyramid > MAX_PYRAMID {
            return Err(SegmentError::Parameter(format!(
                "mean shift pyramid levels must be at most {MAX_PYRAMID} (got {})",
                self.pyramid
            )));
        }
        Ok(())
    }
}

/// Window pixels summed together, one per lane.
const LANES: usize = 8;

/// Lane-wise window sums: `Σ w·x, Σ w·y, Σ w·f₀, Σ w·f₁, Σ w·f₂, Σ w`.
type Sums = [[f32; LANES]; 6];

/// What filtering a pixel needs.
struct Filter<'a> {
    /// Range features (L\*u\*v\* or RGB) as three planes, padded by a block.
    planes: &'a [Vec<f32>; 3],
    w: usize,
    h: usize,
    spec: &'a MeanShiftSpec,
    /// Sum uniform-kernel windows with AVX2.
    avx2: bool,
}

impl Filter<'_> {
    /// Moves pixel `i`'s point to the mean of its window until the shift
    /// is below the threshold (eq. 3–4); returns the mode's colour and the
    /// iterations run.
    fn shift(&self, i: usize) -> ([f32; 3], usize) {
        let (w, h, spec) = (self.w, self.h, self.spec);
        let hs = spec.spatial as isize;
        let (mut px, mut py) = ((i % w) as f32, (i / w) as f32);
        let mut c = [0, 1, 2].map(|k| self.planes[k][i]);
        let mut it = 0;
        while it < spec.max_iterations {
            it += 1;
            let (cx, cy) = (px.round() as isize, py.round() as isize);
            let x0 = (cx - hs).max(0) as usize;
            let len = (cx + hs).min(w as isize - 1) as usize + 1 - x0;
            let (y0, y1) = (
                (cy - hs).max(0) as usize,
                (cy + hs).min(h as isize - 1) as usize,
            );
            let window = Window {
                first: y0 * w + x0,
                stride: w,
                len,
                rows: y1 + 1 - y0,
                x0: x0 as f32,
                y0: y0 as f32,
            };
            let acc = self.sums(&window, c);
            // Lanes in order, as both window-sum versions leave them.
            let [sx, sy, s0, s1, s2, sw] = acc.map(|a| a.iter().sum::<f32>());
            if sw <= 0.0 {
                break;
            }
            let (nx, ny, nc) = (sx / sw, sy / sw, [s0, s1, s2].map(|v| v / sw));
            let shift2 = (nx - px).powi(2)
                + (ny - py).powi(2)
                + (0..3).map(|k| (nc[k] - c[k]).powi(2)).sum::<f32>();
            (px, py, c) = (nx, ny, nc);
            if shift2 < spec.threshold * spec.threshold {
                break;
            }
        }
        (c, it)
    }

    fn sums(&self, window: &Window, c: [f32; 3]) -> Sums {
        let hr2 = self.spec.range * self.spec.range;
        let mut acc: Sums = [[0.0; LANES]; 6];
        match self.spec.kernel {
            Kernel::Uniform if self.avx2 => {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `avx2` is only set where the CPU has AVX2.
                unsafe {
                    window_avx2(&mut acc, self.planes, window, c, hr2)
                }
            }
            Kernel::Uniform => window.rows().for_each(|row| {
                add_row(&mut acc, self.planes, &row, c, |d2| {
                    if d2 <= hr2 {
                        1.0
                    } else {
                        0.0
                    }
                })
            }),
            Kernel::Gaussian => window.rows().for_each(|row| {
                add_row(&mut acc, self.planes, &row, c, |d2| {
                    if d2 <= 9.0 * hr2 {
                        (-d2 / (2.0 * hr2)).exp()
                    } else {
                        0.0
                    }
                })
            }),
        }
        acc
    }
}

/// A pixel's window: `rows` rows of `len` pixels, the first from plane
/// index `first` at column `x0` and row `y0`.
struct Window {
    first: usize,
    stride: usize,
    len: usize,
    rows: usize,
    x0: f32,
    y0: f32,
}

impl Window {
    /// Its rows, top to bottom.
    fn rows(&self) -> impl Iterator<Item = Row> + '_ {
        (0..self.rows).map(|r| Row {
            start: self.first + r * self.stride,
            len: self.len,
            x0: self.x0,
            y: self.y0 + r as f32,
        })
    }
}

/// One window row: `len` pixels from plane index `start`, at column `x0`
/// and row `y`.
struct Row {
    start: usize,
    len: usize,
    x0: f32,
    y: f32,
}

/// Adds one window row to the lane sums, in blocks of [`LANES`] pixels;
/// lanes past the row's end weigh 0. Per lane: `d² = (Δ₀² + Δ₁²) + Δ₂²`,
/// `w = weight(d²)`, then each sum `+= w·value`, in the order of [`Sums`].
#[inline(always)]
fn add_row(
    acc: &mut Sums,
    planes: &[Vec<f32>; 3],
    row: &Row,
    c: [f32; 3],
    weight: impl Fn(f32) -> f32,
) {
    for start in (0..row.len).step_by(LANES) {
        for l in 0..LANES {
            let i = row.start + start + l;
            let f = [planes[0][i], planes[1][i], planes[2][i]];
            let d = [f[0] - c[0], f[1] - c[1], f[2] - c[2]];
            let d2 = (d[0] * d[0] + d[1] * d[1]) + d[2] * d[2];
            let m = if start + l < row.len { weight(d2) } else { 0.0 };
            acc[0][l] += m * (row.x0 + (start + l) as f32);
            acc[1][l] += m * row.y;
            for k in 0..3 {
                acc[2 + k][l] += m * f[k];
            }
            acc[5][l] += m;
        }
    }
}

/// [`add_row`] over a whole window for the uniform kernel with AVX2, to the
/// same bits: the colour sums take the same operations in the same order
/// in each lane; the weights are 0 or 1, so the sums of `w`, `w·x` and
/// `w·y` are integers, exact in `f32` in any order while they stay below
/// 2²⁴ (a 41×41 window anywhere in a 10 000 px image; far larger windows
/// and images can round, and then differ from the portable sums in the last
/// bits). That lets the `y` sum be taken once per row and the row-end mask
/// only on the last block.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn window_avx2(
    acc: &mut Sums,
    planes: &[Vec<f32>; 3],
    window: &Window,
    c: [f32; 3],
    hr2: f32,
) {
    use std::arch::x86_64::*;
    let mut v: [__m256; 6] = std::array::from_fn(|k| _mm256_loadu_ps(acc[k].as_ptr()));
    let iota = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    let iota_i = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let (cv, limit) = (c.map(|x| _mm256_set1_ps(x)), _mm256_set1_ps(hr2));
    let one = _mm256_set1_ps(1.0);
    let full = window.len / LANES * LANES;
    let row_end = _mm256_cmpgt_epi32(_mm256_set1_epi32((window.len - full) as i32), iota_i);
    for row in window.rows() {
        let mut count = _mm256_setzero_ps();
        let mut xs = _mm256_add_ps(_mm256_set1_ps(row.x0), iota);
        // One block: `keep` masks the lanes inside the row.
        let mut block = |start: usize, keep: __m256| {
            let at = row.start + start;
            let f: [__m256; 3] =
                std::array::from_fn(|k| _mm256_loadu_ps(planes[k][at..at + LANES].as_ptr()));
            let d: [__m256; 3] = std::array::from_fn(|k| _mm256_sub_ps(f[k], cv[k]));
            let d2 = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(d[0], d[0]), _mm256_mul_ps(d[1], d[1])),
                _mm256_mul_ps(d[2], d[2]),
            );
            let near = _mm256_and_ps(_mm256_cmp_ps(d2, limit, _CMP_LE_OQ), keep);
            let m = _mm256_and_ps(near, one);
            v[0] = _mm256_add_ps(v[0], _mm256_mul_ps(m, xs));
            for k in 0..3 {
                v[2 + k] = _mm256_add_ps(v[2 + k], _mm256_mul_ps(m, f[k]));
            }
            count = _mm256_add_ps(count, m);
            xs = _mm256_add_ps(xs, _mm256_set1_ps(LANES as f32));
        };
        let all = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        for start in (0..full).step_by(LANES) {
            block(start, all);
        }
        if full < window.len {
            block(full, _mm256_castsi256_ps(row_end));
        }
        v[1] = _mm256_add_ps(v[1], _mm256_mul_ps(count, _mm256_set1_ps(row.y)));
        v[5] = _mm256_add_ps(v[5], count);
    }
    for (a, r) in acc.iter_mut().zip(v) {
        _mm256_storeu_ps(a.as_mut_ptr(), r);
    }
}

/// Filters and clusters `image`.
pub fn mean_shift(image: &RgbImage, spec: &MeanShiftSpec) -> Result<Segmentation, SegmentError> {
    spec.validate()?;
    let (w, h) = image.dims();
    let feat: Plane<[f32; 3]> = match spec.colour_space {
        ColourSpace::Luv => color::rgb_image_to_luv(image),
        ColourSpace::Rgb => image.map(|p| p.map(f32::from)),
    };
    let avx2 = spec.kernel == Kernel::Uniform && stereolink_image::cpu::avx2();
    let (modes, iterations_used) = modes(&feat, spec, spec.pyramid, avx2);
    // Cluster: union neighbours with close modes.
    let mut parent: Vec<u32> = (0..(w * h) as u32).collect();
    let join = (spec.range / 2.0).powi(2);
    let close =
        |a: [f32; 3], b: [f32; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>() <= join;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            for j in [(x + 1 < w).then(|| i + 1), (y + 1 < h).then(|| i + w)]
                .into_iter()
                .flatten()
            {
                if close(modes[i], modes[j]) {
                    let (a, b) = (find(&mut parent, i as u32), find(&mut parent, j as u32));
                    if a != b {
                        parent[a.max(b) as usize] = a.min(b);
                    }
                }
            }
        }
    }
    let mut labels: Plane<u32> = Plane::from_fn(w, h, |x, y| find(&mut parent, (y * w + x) as u32));
    merge_small_regions(&mut labels, image, spec.min_region);
    cap_regions(&mut labels, image, MAX_LABELS);
    let sums = region_sums(&labels, image);
    let image = compact(labels, |l| {
        let (s, n) = sums[l as usize];
        s.map(|v| ((v + n / 2) / n.max(1)) as u8)
    })?;
    Ok(Segmentation {
        image,
        channels: None,
        iterations: iterations_used,
    })
}

/// The features as three planes, padded by a block so that a block
/// starting anywhere in the image can be read whole.
fn feature_planes(feat: &Plane<[f32; 3]>) -> [Vec<f32>; 3] {
    std::array::from_fn(|k| {
        let mut p: Vec<f32> = feat.as_slice().iter().map(|c| c[k]).collect();
        p.resize(feat.len() + LANES, 0.0);
        p
    })
}

/// Every pixel's mode, and the most iterations a pixel took.
///
/// With `levels` = 0, each pixel is filtered. Otherwise, as OpenCV's
/// `pyrMeanShiftFiltering` does, a half-size copy (each pixel the mean of a
/// 2×2 block) is filtered first with half the spatial bandwidth (itself
/// with `levels − 1`), and then only the pixels near a boundary of its
/// modes are filtered at full size: those whose coarse pixel, or one of its
/// 8 neighbours, has a neighbour whose mode is farther than the clustering
/// distance `h_r / 2` from its own. The others take their coarse pixel's
/// mode. This approximates the exact filtering, at a fraction of its cost.
fn modes(
    feat: &Plane<[f32; 3]>,
    spec: &MeanShiftSpec,
    levels: usize,
    avx2: bool,
) -> (Vec<[f32; 3]>, usize) {
    let (w, h) = feat.dims();
    let planes = feature_planes(feat);
    let filter = Filter {
        planes: &planes,
        w,
        h,
        spec,
        avx2,
    };
    let coarse = (levels > 0 && w > 1 && h > 1).then(|| {
        let half = Plane::from_fn(w.div_ceil(2), h.div_ceil(2), |cx, cy| {
            let block = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .map(|(dx, dy)| feat.get((2 * cx + dx).min(w - 1), (2 * cy + dy).min(h - 1)));
            std::array::from_fn(|k| block.iter().map(|c| c[k]).sum::<f32>() / 4.0)
        });
        let spec = MeanShiftSpec {
            spatial: (spec.spatial / 2).max(1),
            ..spec.clone()
        };
        let (modes, iterations) = modes(&half, &spec, levels - 1, avx2);
        let modes =
            Plane::from_vec(half.width(), half.height(), modes).expect("one mode per pixel");
        (modes, iterations)
    });
    // The coarse modes, and which coarse pixels are near a boundary of them.
    let coarse = coarse.map(|(coarse, iterations)| {
        let (cw, ch) = coarse.dims();
        let join = (spec.range / 2.0).powi(2);
        let neighbours = |x: usize, y: usize| {
            let (x0, y0) = (x.saturating_sub(1), y.saturating_sub(1));
            (y0..(y + 2).min(ch)).flat_map(move |ny| (x0..(x + 2).min(cw)).map(move |nx| (nx, ny)))
        };
        let boundary = Plane::from_fn(cw, ch, |x, y| {
            let m = coarse.get(x, y);
            neighbours(x, y).any(|(nx, ny)| {
                let n = coarse.get(nx, ny);
                (0..3).map(|k| (m[k] - n[k]).powi(2)).sum::<f32>() > join
            })
        });
        let near = Plane::from_fn(cw, ch, |x, y| {
            neighbours(x, y).any(|(nx, ny)| boundary.get(nx, ny))
        });
        (coarse, near, iterations)
    });
    let pixels: Vec<([f32; 3], usize)> = (0..w * h)
        .into_par_iter()
        .map(|i| match &coarse {
            Some((modes, near, _)) => {
                let (cx, cy) = (i % w / 2, i / w / 2);
                if near.get(cx, cy) {
                    filter.shift(i)
                } else {
                    (modes.get(cx, cy), 0)
                }
            }
            None => filter.shift(i),
        })
        .collect();
    let coarse_iterations = coarse.map_or(0, |c| c.2);
    let iterations = pixels
        .iter()
        .map(|m| m.1)
        .fold(coarse_iterations, usize::max);
    (pixels.into_iter().map(|m| m.0).collect(), iterations)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 window sums give the portable ones bit for bit.
    #[test]
    fn avx2_and_portable_windows_agree() {
        if !stereolink_image::cpu::avx2() {
            return;
        }
        let (w, h) = (37, 23);
        let mut s = 7u32;
        let image = RgbImage::from_fn(w, h, |x, y| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let noise = (s >> 28) as u8;
            [
                (x * 6) as u8 + noise,
                (y * 9) as u8,
                if x > 20 { 200 } else { 40 } + noise,
            ]
        });
        let spec = MeanShiftSpec {
            spatial: 5,
            range: 12.0,
            ..MeanShiftSpec::default()
        };
        let planes = feature_planes(&color::rgb_image_to_luv(&image));
        let filter = |avx2| Filter {
            planes: &planes,
            w,
            h,
            spec: &spec,
            avx2,
        };
        let bits = |m: ([f32; 3], usize)| (m.0.map(f32::to_bits), m.1);
        for i in 0..w * h {
            assert_eq!(
                bits(filter(true).shift(i)),
                bits(filter(false).shift(i)),
                "pixel {i}"
            );
        }
    }

    /// Two flat halves with mild noise and a slanted edge.
    fn two_halves(w: usize, h: usize) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let n = ((x * 7 + y * 13) % 4) as u8;
            if 2 * x + y < w + h / 2 {
                [30 + n, 90 + n, 160 + n]
            } else {
                [200 - n, 60 + n, 40 + n]
            }
        })
    }

    /// The pyramid refilters the pixels near boundaries, so on two flat
    /// regions it finds the same segmentation as filtering every pixel.
    #[test]
    fn pyramid_matches_exact_filtering_on_flat_regions() {
        let image = two_halves(61, 37);
        let exact = MeanShiftSpec {
            pyramid: 0,
            ..MeanShiftSpec::default()
        };
        let reference = mean_shift(&image, &exact).unwrap();
        assert_eq!(reference.image.palette().len(), 2);
        for pyramid in 1..=3 {
            let spec = MeanShiftSpec {
                pyramid,
                ..exact.clone()
            };
            assert_eq!(
                mean_shift(&image, &spec).unwrap(),
                reference,
                "{pyramid} levels"
            );
        }
    }

    #[test]
    fn pyramid_levels_are_bounded_and_tiny_images_work() {
        let spec = MeanShiftSpec {
            pyramid: MAX_PYRAMID + 1,
            ..MeanShiftSpec::default()
        };
        assert!(mean_shift(&two_halves(8, 8), &spec).is_err());
        let spec = MeanShiftSpec {
            pyramid: MAX_PYRAMID,
            ..MeanShiftSpec::default()
        };
        for (w, h) in [(1, 1), (1, 9), (9, 1), (2, 3)] {
            let seg = mean_shift(&two_halves(w, h), &spec).unwrap();
            assert_eq!(seg.image.labels().dims(), (w, h));
        }
    }

    /// Uniform noise, a fixed sequence.
    fn noise(w: usize, h: usize) -> RgbImage {
        let mut s = 3u32;
        RgbImage::from_fn(w, h, |_, _| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            [(s >> 24) as u8, (s >> 16) as u8, (s >> 8) as u8]
        })
    }

    /// A 400x300 noise image stopped this with "more than 65536 segments":
    /// its modes differ everywhere, and its one-pixel regions, equal, do
    /// not merge for the minimum size. Now the smallest regions merge down
    /// to the label cap.
    #[test]
    fn noise_images_segment_within_the_label_cap() {
        let image = noise(400, 300);
        for (min_region, pyramid) in [(50, 1), (30, 0), (1, 1), (0, 1)] {
            let spec = MeanShiftSpec {
                min_region,
                pyramid,
                ..MeanShiftSpec::default()
            };
            let seg = mean_shift(&image, &spec).unwrap();
            let labels = seg.image.labels();
            assert_eq!(labels.dims(), (400, 300));
            let n = seg.image.palette().len();
            assert_eq!(n, crate::MAX_LABELS, "min_region {min_region}");
        }
    }
}
