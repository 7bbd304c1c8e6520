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
//! the most similar colour. Each region is shown in its mean original colour.
//!
//! The paper's setting is [`MeanShiftSpec::paper`] (`h_s = 40`, `h_r = 3`,
//! threshold 3). The default (`h_s = 8`, `h_r = 8` in L\*u\*v\*) keeps the
//! filtering affordable on the sender's CPU and gives far fewer regions.

use rayon::prelude::*;
use serde::Serialize;
use stereolink_image::{color, Plane, RgbImage};

use crate::{compact, SegmentError, Segmentation};

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
    /// Regions smaller than this are merged into a neighbour.
    pub min_region: usize,
}

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
        }
    }
}

impl MeanShiftSpec {
    /// The paper's preset: h_s = 40, h_r = 3, threshold 3.
    pub fn paper() -> Self {
        MeanShiftSpec {
            spatial: 40,
            range: 3.0,
            threshold: 3.0,
            ..Self::default()
        }
    }

    fn validate(&self) -> Result<(), SegmentError> {
        if self.spatial == 0
            || self.spatial > 200
            || self.range.is_nan()
            || self.range <= 0.0
            || self.threshold < 0.0
        {
            return Err(SegmentError::Parameter(format!(
                "mean shift needs bandwidths h_s in 1..=200 and h_r > 0 (got {} and {})",
                self.spatial, self.range
            )));
        }
        Ok(())
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
    let hs = spec.spatial as isize;
    let (hr2, reach2) = match spec.kernel {
        Kernel::Uniform => (spec.range * spec.range, spec.range * spec.range),
        Kernel::Gaussian => (spec.range * spec.range, 9.0 * spec.range * spec.range),
    };
    let mut iterations_used = 0usize;
    let modes: Vec<([f32; 3], usize)> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (mut px, mut py) = ((i % w) as f32, (i / w) as f32);
            let mut c = feat.as_slice()[i];
            let mut it = 0;
            while it < spec.max_iterations {
                it += 1;
                let (cx, cy) = (px.round() as isize, py.round() as isize);
                let (mut sx, mut sy, mut sc, mut sw) = (0.0f32, 0.0f32, [0.0f32; 3], 0.0f32);
                for y in (cy - hs).max(0)..=(cy + hs).min(h as isize - 1) {
                    let row = feat.row(y as usize);
                    for x in (cx - hs).max(0)..=(cx + hs).min(w as isize - 1) {
                        let q = row[x as usize];
                        let d2 =
                            (q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2) + (q[2] - c[2]).powi(2);
                        if d2 > reach2 {
                            continue;
                        }
                        let wgt = match spec.kernel {
                            Kernel::Uniform => 1.0,
                            Kernel::Gaussian => (-d2 / (2.0 * hr2)).exp(),
                        };
                        sx += wgt * x as f32;
                        sy += wgt * y as f32;
                        for k in 0..3 {
                            sc[k] += wgt * q[k];
                        }
                        sw += wgt;
                    }
                }
                if sw <= 0.0 {
                    break;
                }
                let (nx, ny, nc) = (sx / sw, sy / sw, sc.map(|v| v / sw));
                let shift2 = (nx - px).powi(2)
                    + (ny - py).powi(2)
                    + (0..3).map(|k| (nc[k] - c[k]).powi(2)).sum::<f32>();
                (px, py, c) = (nx, ny, nc);
                if shift2 < spec.threshold * spec.threshold {
                    break;
                }
            }
            (c, it)
        })
        .collect();
    for &(_, it) in &modes {
        iterations_used = iterations_used.max(it);
    }
    // Cluster: union neighbours with close modes.
    let mut parent: Vec<u32> = (0..(w * h) as u32).collect();
    fn find(p: &mut [u32], mut i: u32) -> u32 {
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i
    }
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
                if close(modes[i].0, modes[j].0) {
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

/// Per root label: summed colour and pixel count.
fn region_sums(labels: &Plane<u32>, image: &RgbImage) -> Vec<([u64; 3], u64)> {
    let mut sums = vec![([0u64; 3], 0u64); labels.len()];
    for (&l, p) in labels.as_slice().iter().zip(image.as_slice()) {
        let e = &mut sums[l as usize];
        for k in 0..3 {
            e.0[k] += p[k] as u64;
        }
        e.1 += 1;
    }
    sums
}

/// Merges every region smaller than `min_region` into the adjacent region of
/// the closest mean colour, smallest regions first, until none is left.
fn merge_small_regions(labels: &mut Plane<u32>, image: &RgbImage, min_region: usize) {
    let (w, h) = labels.dims();
    for _ in 0..8 {
        let sums = region_sums(labels, image);
        let mean = |l: u32| {
            let (s, n) = sums[l as usize];
            s.map(|v| v as f64 / n.max(1) as f64)
        };
        let mut target: Vec<Option<(f64, u32)>> = vec![None; labels.len()];
        for y in 0..h {
            for x in 0..w {
                let a = labels.get(x, y);
                if sums[a as usize].1 as usize >= min_region {
                    continue;
                }
                for (nx, ny) in [
                    (x + 1, y),
                    (x, y + 1),
                    (x.wrapping_sub(1), y),
                    (x, y.wrapping_sub(1)),
                ] {
                    if nx >= w || ny >= h {
                        continue;
                    }
                    let b = labels.get(nx, ny);
                    if b == a {
                        continue;
                    }
                    let d: f64 = (0..3).map(|k| (mean(a)[k] - mean(b)[k]).powi(2)).sum();
                    if target[a as usize].is_none_or(|(bd, _)| d < bd) {
                        target[a as usize] = Some((d, b));
                    }
                }
            }
        }
        if target.iter().all(Option::is_none) {
            return;
        }
        for l in labels.as_mut_slice() {
            if let Some((_, b)) = target[*l as usize] {
                // Merge only into a region that is not itself moving this round.
                if target[b as usize].is_none() || sums[b as usize].1 > sums[*l as usize].1 {
                    *l = b;
                }
            }
        }
    }
}
