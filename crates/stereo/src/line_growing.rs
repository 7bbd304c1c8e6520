//! Line growing, the paper's global method (after Alagoz's region-growing
//! stereo matching), on the averaged squared error energy.
//!
//! **Convention.** The paper writes its energy with `L(x, y + d) − R(x, y)`,
//! indexing (row, column) and anchoring the right view. stereolink anchors the
//! left view with `x_R = x_L − d`; substituting `x_L = y + d` gives the form
//! used here, which is the same quantity:
//!
//! ```text
//! e(x, y, d) = 1/(3·n·m) Σ_{(i,j) ∈ n×m window} Σ_{k=1..3} (L(x+i, y+j, k) − R(x+i−d, y+j, k))²   (eq. 15)
//! ẽ(x, y, d) = 1/(n·m)  Σ_{(i,j) ∈ n×m window} e(x+i, y+j, d)          (eq. 16, applied `passes` times)
//! ```
//!
//! **Step 3**: the disparity of minimum `ẽ`. **Step 4, line growing**, row by
//! row from left to right: a point whose minimum energy is at most the
//! growing threshold becomes a *root* with that disparity, otherwise it is
//! *idle*; from a root the region grows to the next point on the row while
//! that point's energy *at the region's disparity* stays within the
//! threshold; when growth stops, the next point is examined as a new root.
//! **Idle points** are left invalid (`inf`) for the refinement's hole fill
//! (on by default), which gives them the background-side disparity of the
//! row; with fill off they stay invalid so that their share can be measured.
//!
//! The energy volume is stored as `u16` (energies are at most 255² = 65025;
//! rounding to whole units does not change which disparity wins except on
//! near ties), disparity-major so disparities are processed in parallel.

use rayon::prelude::*;
use stereolink_image::{DisparityMap, RgbImage};

use crate::refine::Raw;
use crate::{MatchSpec, StereoError};

/// Parameters of line growing.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LineGrowingParams {
    /// How many times the averaging filter of eq. 16 is applied.
    pub passes: usize,
    /// Growing threshold on `ẽ` (squared intensity units).
    pub threshold: f32,
}

impl Default for LineGrowingParams {
    /// Chosen on the Middlebury v2 scenes with `stereolink eval --algo lg`
    /// (docs/tuning.md, “Line growing”).
    fn default() -> Self {
        LineGrowingParams {
            passes: 1,
            threshold: 150.0,
        }
    }
}

impl LineGrowingParams {
    pub(crate) fn validate(&self) -> Result<(), StereoError> {
        if self.passes > 16 || self.threshold.is_nan() || self.threshold < 0.0 {
            return Err(StereoError::Parameter(format!(
                "line growing needs at most 16 passes and a threshold >= 0 (got {} and {})",
                self.passes, self.threshold
            )));
        }
        Ok(())
    }
}

/// Box mean over a `(2r+1)²` window with border replication, in place.
fn box_mean(plane: &mut [f32], w: usize, h: usize, r: usize, tmp: &mut Vec<f32>) {
    let n = (2 * r + 1) as f32;
    tmp.resize(w * h, 0.0);
    // Horizontal running sum into tmp.
    for y in 0..h {
        let row = &plane[y * w..(y + 1) * w];
        let out = &mut tmp[y * w..(y + 1) * w];
        let at = |x: isize| row[x.clamp(0, w as isize - 1) as usize];
        let mut s: f32 = (-(r as isize)..=r as isize).map(at).sum();
        for (x, o) in out.iter_mut().enumerate() {
            if x > 0 {
                s += at((x + r) as isize) - at(x as isize - r as isize - 1);
            }
            *o = s / n;
        }
    }
    // Vertical running sum back into plane.
    for x in 0..w {
        let at = |y: isize| tmp[y.clamp(0, h as isize - 1) as usize * w + x];
        let mut s: f32 = (-(r as isize)..=r as isize).map(at).sum();
        for y in 0..h {
            if y > 0 {
                s += at((y + r) as isize) - at(y as isize - r as isize - 1);
            }
            plane[y * w + x] = s / n;
        }
    }
}

/// The averaged energy volume `ẽ`, disparity-major: `vol[k][y][x]`.
fn energy_volume(left: &RgbImage, right: &RgbImage, spec: &MatchSpec) -> Vec<u16> {
    let (w, h) = left.dims();
    let r = spec.block / 2;
    let mut vol = vec![u16::MAX; spec.ndisp() * w * h];
    vol.par_chunks_mut(w * h).enumerate().for_each(|(k, out)| {
        let d = spec.min_disp + k;
        let mut plane: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (l, rr) = (left.get(x, y), right.get(x.saturating_sub(d), y));
                (0..3)
                    .map(|c| (l[c] as f32 - rr[c] as f32).powi(2))
                    .sum::<f32>()
                    / 3.0
            })
            .collect();
        let mut tmp = Vec::new();
        for _ in 0..=spec.line_growing.passes {
            box_mean(&mut plane, w, h, r, &mut tmp);
        }
        for (i, (o, e)) in out.iter_mut().zip(&plane).enumerate() {
            if i % w >= d {
                *o = e.round().min(65534.0) as u16;
            }
        }
    });
    vol
}

/// Runs step 3 and line growing (step 4) on a colour pair.
pub fn line_growing(left: &RgbImage, right: &RgbImage, spec: &MatchSpec) -> Raw {
    let (w, h) = left.dims();
    let nd = spec.ndisp();
    let plane = w * h;
    let vol = energy_volume(left, right, spec);
    let theta = spec.line_growing.threshold;
    let energy = |x: usize, y: usize, k: usize| vol[k * plane + y * w + x];
    let mut out = DisparityMap::new(w, h, f32::INFINITY);
    out.as_mut_slice()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            let argmin = |x: usize| (0..nd).min_by_key(|&k| energy(x, y, k)).expect("ndisp > 0");
            let mut x = spec.min_disp;
            while x < w {
                let k = argmin(x);
                if energy(x, y, k) as f32 > theta {
                    x += 1; // idle point
                    continue;
                }
                // A root: grow the region along the row at its disparity.
                row[x] = (spec.min_disp + k) as f32;
                x += 1;
                while x < w && (energy(x, y, k) as f32) <= theta {
                    row[x] = (spec.min_disp + k) as f32;
                    x += 1;
                }
            }
        });
    Raw {
        disparity: out,
        right: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Algorithm, Refinement};

    #[test]
    fn box_mean_of_constant_is_constant_and_spreads_a_spike() {
        let mut p = vec![2.0f32; 20];
        let mut tmp = Vec::new();
        box_mean(&mut p, 5, 4, 1, &mut tmp);
        assert!(p.iter().all(|&v| (v - 2.0).abs() < 1e-6));
        let mut q = vec![0.0f32; 25];
        q[12] = 9.0;
        box_mean(&mut q, 5, 5, 1, &mut tmp);
        assert!((q[6] - 1.0).abs() < 1e-6 && q[0] == 0.0);
    }

    #[test]
    fn regions_grow_at_the_root_disparity_and_idle_points_stay_invalid() {
        // A textured right row shifted by 3 to make the left; the leftmost
        // columns cannot match (x < d) and a band of noise breaks the match.
        let right = RgbImage::from_fn(60, 9, |x, y| {
            let v = ((x * 37 + y * 11) % 251) as u8;
            [v, v / 2, 255 - v]
        });
        let mut left = RgbImage::from_fn(60, 9, |x, y| right.get(x.saturating_sub(3), y));
        for y in 0..9 {
            for x in 30..34 {
                left.set(x, y, [0, 255, 0]);
            }
        }
        let mut spec = MatchSpec::new(Algorithm::LineGrowing, 0, 8).unwrap();
        spec.block = 3;
        spec.refine = Refinement::NONE;
        let raw = line_growing(&left, &right, &spec);
        let row = raw.disparity.row(4);
        assert!(row[10..28].iter().all(|&d| d == 3.0), "{row:?}");
        assert!(row[31..33].iter().all(|d| d.is_infinite()), "{row:?}");
        assert!(row[38..56].iter().all(|&d| d == 3.0), "{row:?}");
    }
}
