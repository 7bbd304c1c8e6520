//! Synthetic rectified stereo scenes with exact ground truth.
//!
//! A scene is a slanted background plane, `d(x, y) = d0 + gx·x/W + gy·y/H`,
//! in front of which stand several fronto-parallel objects (rectangles and
//! ellipses) at constant integer disparities. Every surface carries a procedural
//! texture (two octaves of value noise over a base colour) defined on the
//! continuous left-view coordinates, so the right view samples the *same*
//! texture at `x_L = x_R + d` and both views agree exactly, fractional
//! disparities included. Visibility is resolved analytically: the nearest
//! surface (largest disparity) wins in each view, which also gives the
//! occlusion mask without rounding.
//!
//! Everything follows from the seed through a stateless hash, so a scene is
//! identical whatever the thread count.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::scene::discontinuity_mask;
use crate::{Calibration, DisparityMap, Error, Masks, Plane, Result, Rgb, RgbImage, Scene};

/// What to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SynthSpec {
    /// Image width in pixels (at least 16).
    pub width: usize,
    /// Image height in pixels (at least 16).
    pub height: usize,
    /// Disparity search range: ground truth lies in `[0.1·max_disp, 0.95·max_disp]`,
    /// and the scene's `ndisp` is `max_disp`. At least 4 and below `width / 2`.
    pub max_disp: usize,
    /// Seed of every random choice.
    pub seed: u64,
}

impl Default for SynthSpec {
    /// The `demo` scene: 384x288, 32 disparities, seed 1.
    fn default() -> Self {
        SynthSpec {
            width: 384,
            height: 288,
            max_disp: 32,
            seed: 1,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Shape {
    Rect { x0: f32, y0: f32, x1: f32, y1: f32 },
    Ellipse { cx: f32, cy: f32, rx: f32, ry: f32 },
}

impl Shape {
    fn contains(&self, x: f32, y: f32) -> bool {
        match *self {
            Shape::Rect { x0, y0, x1, y1 } => x >= x0 && x < x1 && y >= y0 && y < y1,
            Shape::Ellipse { cx, cy, rx, ry } => {
                ((x - cx) / rx).powi(2) + ((y - cy) / ry).powi(2) <= 1.0
            }
        }
    }
}

struct Object {
    shape: Shape,
    disparity: f32,
}

struct Layout {
    seed: u64,
    width: f32,
    height: f32,
    d0: f32,
    gx: f32,
    gy: f32,
    /// Sorted nearest first (largest disparity first).
    objects: Vec<Object>,
    colours: Vec<[f32; 3]>,
}

/// Surface index: 0 is the background, `i + 1` is `objects[i]`.
type Surface = usize;

impl Layout {
    fn background_disparity(&self, x: f32, y: f32) -> f32 {
        self.d0 + self.gx * x / self.width + self.gy * y / self.height
    }

    /// Visible surface at left coordinates, with its disparity.
    fn left_surface(&self, x: f32, y: f32) -> (Surface, f32) {
        for (i, o) in self.objects.iter().enumerate() {
            if o.shape.contains(x, y) {
                return (i + 1, o.disparity);
            }
        }
        (0, self.background_disparity(x, y))
    }

    /// Visible surface at right coordinates: `(surface, left x it shows, disparity)`.
    fn right_surface(&self, xr: f32, y: f32) -> (Surface, f32, f32) {
        for (i, o) in self.objects.iter().enumerate() {
            let x = xr + o.disparity;
            if o.shape.contains(x, y) {
                return (i + 1, x, o.disparity);
            }
        }
        // Solve x − d(x, y) = xr for the plane.
        let x = (xr + self.d0 + self.gy * y / self.height) / (1.0 - self.gx / self.width);
        (0, x, self.background_disparity(x, y))
    }

    fn texture(&self, surface: Surface, x: f32, y: f32) -> Rgb {
        let base = self.colours[surface];
        let fine = value_noise(self.seed, surface as u64 * 2, x / 2.5, y / 2.5);
        let coarse = value_noise(self.seed, surface as u64 * 2 + 1, x / 11.0, y / 11.0);
        let shade = 0.35 + 0.4 * fine + 0.35 * coarse;
        base.map(|c| (c * shade).clamp(0.0, 255.0).round() as u8)
    }
}

fn hash(seed: u64, a: u64, b: i64, c: i64) -> u64 {
    // splitmix64 finaliser over a mix of the inputs
    let mut z = seed
        ^ a.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9)
        ^ (c as u64).wrapping_mul(0x94D0_49BB_1331_11EB);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Bilinearly interpolated lattice noise in `[0, 1]`.
fn value_noise(seed: u64, layer: u64, x: f32, y: f32) -> f32 {
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (x - fx, y - fy);
    let (ix, iy) = (fx as i64, fy as i64);
    let v =
        |dx: i64, dy: i64| (hash(seed, layer, ix + dx, iy + dy) >> 40) as f32 / (1u64 << 24) as f32;
    let top = v(0, 0) * (1.0 - tx) + v(1, 0) * tx;
    let bottom = v(0, 1) * (1.0 - tx) + v(1, 1) * tx;
    top * (1.0 - ty) + bottom * ty
}

fn layout(spec: &SynthSpec) -> Layout {
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let (w, h, m) = (spec.width as f32, spec.height as f32, spec.max_disp as f32);
    let n_objects = rng.gen_range(3..=4);
    let mut objects: Vec<Object> = (0..n_objects)
        .map(|i| {
            // Spread the object disparities over [0.5, 0.95]·max, one band each.
            let band = 0.45 / n_objects as f32;
            let disparity = (m * (0.5 + band * (i as f32 + rng.gen_range(0.15..0.85)))).round();
            let (sw, sh) = (w * rng.gen_range(0.14..0.28), h * rng.gen_range(0.18..0.36));
            let cx = rng.gen_range(sw * 0.6 + m..w - sw * 0.6);
            let cy = rng.gen_range(sh * 0.6..h - sh * 0.6);
            let shape = if rng.gen_bool(0.5) {
                Shape::Rect {
                    x0: cx - sw / 2.0,
                    y0: cy - sh / 2.0,
                    x1: cx + sw / 2.0,
                    y1: cy + sh / 2.0,
                }
            } else {
                Shape::Ellipse {
                    cx,
                    cy,
                    rx: sw / 2.0,
                    ry: sh / 2.0,
                }
            };
            Object { shape, disparity }
        })
        .collect();
    objects.sort_by(|a, b| b.disparity.total_cmp(&a.disparity));
    let colours = (0..=n_objects)
        .map(|_| {
            let hue = rng.gen_range(0.0..6.0f32);
            let (r, g, b) = match hue as u32 {
                0 => (1.0, hue.fract(), 0.0),
                1 => (1.0 - hue.fract(), 1.0, 0.0),
                2 => (0.0, 1.0, hue.fract()),
                3 => (0.0, 1.0 - hue.fract(), 1.0),
                4 => (hue.fract(), 0.0, 1.0),
                _ => (1.0, 0.0, 1.0 - hue.fract()),
            };
            [r, g, b].map(|c| 90.0 + 200.0 * c)
        })
        .collect();
    Layout {
        seed: spec.seed,
        width: w,
        height: h,
        d0: m * 0.15,
        gx: m * rng.gen_range(-0.05..0.05),
        gy: m * 0.25,
        objects,
        colours,
    }
}

/// Generates a scene: both views, both ground truths, the masks (`nonocc`,
/// `all`, `disc`) and a calibration with focal length `0.8·width` px and a
/// 3 cm baseline (a small robot's stereo head: the scene lies 0.3–3 m away).
pub fn synthesize(spec: &SynthSpec) -> Result<Scene> {
    if spec.width < 16 || spec.height < 16 {
        return Err(Error::InvalidParameter(format!(
            "synthetic scene of {}x{} is too small (at least 16x16)",
            spec.width, spec.height
        )));
    }
    if spec.max_disp < 4 || spec.max_disp * 2 >= spec.width {
        return Err(Error::InvalidParameter(format!(
            "max disparity {} must be at least 4 and below half the width ({})",
            spec.max_disp, spec.width
        )));
    }
    if spec.width.saturating_mul(spec.height) > crate::io::MAX_PIXELS {
        return Err(Error::TooLarge {
            what: "synthetic scene".into(),
            width: spec.width,
            height: spec.height,
            max_pixels: crate::io::MAX_PIXELS,
        });
    }
    let lay = layout(spec);
    let (w, h) = (spec.width, spec.height);
    let left = RgbImage::from_fn(w, h, |x, y| {
        let (s, _) = lay.left_surface(x as f32, y as f32);
        lay.texture(s, x as f32, y as f32)
    });
    let right = RgbImage::from_fn(w, h, |x, y| {
        let (s, xl, _) = lay.right_surface(x as f32, y as f32);
        lay.texture(s, xl, y as f32)
    });
    let gt_left: DisparityMap = Plane::from_fn(w, h, |x, y| lay.left_surface(x as f32, y as f32).1);
    let gt_right: DisparityMap =
        Plane::from_fn(w, h, |x, y| lay.right_surface(x as f32, y as f32).2);
    let nonocc = Plane::from_fn(w, h, |x, y| {
        let (s, d) = lay.left_surface(x as f32, y as f32);
        let xr = x as f32 - d;
        xr >= 0.0 && lay.right_surface(xr, y as f32).0 == s
    });
    let disc = discontinuity_mask(&gt_left, &nonocc, 2.0, 2);
    Ok(Scene {
        name: format!("synthetic-{}", spec.seed),
        left,
        right,
        gt_left: Some(gt_left),
        gt_right: Some(gt_right),
        masks: Masks {
            nonocc: Some(nonocc),
            all: Some(Plane::new(w, h, true)),
            disc: Some(disc),
        },
        calib: Calibration {
            focal_px: Some(0.8 * w as f64),
            baseline_m: Some(0.03),
            doffs: 0.0,
            ndisp: spec.max_disp,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(seed: u64) -> SynthSpec {
        SynthSpec {
            width: 160,
            height: 120,
            max_disp: 24,
            seed,
        }
    }

    #[test]
    fn deterministic_per_seed_and_different_across_seeds() {
        assert_eq!(synthesize(&spec(3)).unwrap(), synthesize(&spec(3)).unwrap());
        assert_ne!(
            synthesize(&spec(3)).unwrap().left,
            synthesize(&spec(4)).unwrap().left
        );
    }

    /// The independent check: warping the right view by the ground truth gives
    /// back the left view at every non-occluded pixel with integer disparity.
    #[test]
    fn right_view_warped_by_ground_truth_equals_left() {
        for seed in 0..5 {
            let s = synthesize(&spec(seed)).unwrap();
            let (gt, nonocc) = (
                s.gt_left.as_ref().unwrap(),
                s.masks.nonocc.as_ref().unwrap(),
            );
            let (mut checked, mut equal) = (0, 0);
            let mut err_sum = 0.0;
            for y in 0..s.left.height() {
                for x in 0..s.left.width() {
                    let d = gt.get(x, y);
                    assert!((0.1 * 24.0 - 1e-3..=0.95 * 24.0 + 1e-3).contains(&d), "{d}");
                    if !nonocc.get(x, y) {
                        continue;
                    }
                    let xr = x as f32 - d;
                    let (x0, t) = (xr.floor() as usize, xr.fract());
                    let x1 = (x0 + 1).min(s.left.width() - 1);
                    let l = s.left.get(x, y);
                    let r = [0, 1, 2].map(|c| {
                        s.right.get(x0, y)[c] as f32 * (1.0 - t) + s.right.get(x1, y)[c] as f32 * t
                    });
                    checked += 1;
                    err_sum += (0..3).map(|c| (l[c] as f32 - r[c]).abs()).sum::<f32>() / 3.0;
                    if t == 0.0 {
                        assert_eq!(s.right.get(x0, y), l, "seed {seed} at ({x}, {y})");
                        equal += 1;
                    }
                }
            }
            let frac_occluded = 1.0 - checked as f64 / s.left.len() as f64;
            assert!(
                frac_occluded > 0.0 && frac_occluded < 0.3,
                "{frac_occluded}"
            );
            assert!(
                equal > checked / 30,
                "seed {seed}: only {equal} of {checked} integer disparities"
            );
            assert!(
                err_sum / (checked as f32) < 6.0,
                "seed {seed}: mean error {}",
                err_sum / checked as f32
            );
        }
    }

    #[test]
    fn bad_specs_are_errors() {
        for s in [
            SynthSpec {
                width: 8,
                ..spec(0)
            },
            SynthSpec {
                max_disp: 2,
                ..spec(0)
            },
            SynthSpec {
                max_disp: 80,
                ..spec(0)
            },
        ] {
            assert!(synthesize(&s).is_err());
        }
    }
}
