//! Rectification maps, computed once and applied to every frame: the
//! fixed-point bilinear remap of `cv::initUndistortRectifyMap` with
//! `CV_16SC2` maps followed by `cv::remap(INTER_LINEAR, BORDER_CONSTANT)`.
//!
//! For each rectified pixel `(u, v)` the map holds where it comes from in
//! the raw image: `[x y w]ᵀ = Rᵀ·P[:, :3]⁻¹·[u v 1]ᵀ`, distorted and
//! projected by the camera. As in OpenCV the source position is kept to
//! 1/32 pixel ([`FRACTION_BITS`] = OpenCV's `INTER_BITS`), so that the four
//! bilinear weights come from a small table and sum to 1024 exactly.
//!
//! Applying a map is then one pass of integer arithmetic: each output pixel
//! reads its precomputed source offset and weight index, with one bounds
//! check per pixel. Pixels whose four neighbours are all inside the source
//! take this path; those mapped wholly outside get zero weights (black, the
//! constant border); the few along the source's edge, with some neighbours
//! outside, are finished in a second, exact pass over a short list. RGB
//! images take an AVX2 copy of the first pass where the CPU has it
//! (`avx2`, detected by [`stereolink_image::cpu::avx2`]), with
//! the same results bit for bit.

use nalgebra::{Matrix3, Matrix3x4, Point2, Vector3};
use stereolink_image::{Plane, Rgb};

use crate::{Camera, Error, Result, StereoCalibration};

#[cfg(target_arch = "x86_64")]
mod avx2;

/// Bits of the source position's fraction (OpenCV's `INTER_BITS`).
pub const FRACTION_BITS: u32 = 5;
/// Sub-pixel steps per pixel.
const STEPS: i32 = 1 << FRACTION_BITS;
/// Bits of the weights, which sum to `1 << WEIGHT_BITS`.
const WEIGHT_BITS: u32 = 2 * FRACTION_BITS;
/// Weight-table entries: one per fraction pair, then zero weights.
const TABLE: usize = 2 << WEIGHT_BITS;
/// The weight index of a pixel outside the source.
const OUTSIDE: u16 = 1 << WEIGHT_BITS;

/// A pixel the maps can interpolate: 8-bit channels.
pub trait Pixel: Copy + Default + Send + Sync + 'static {
    /// Channels per pixel.
    const CHANNELS: usize;
    /// Channel `c` (below [`Pixel::CHANNELS`]).
    fn channel(self, c: usize) -> u8;
    /// A pixel whose channel `c` is `f(c)`.
    fn from_fn(f: impl FnMut(usize) -> u8) -> Self;
    /// The bilinear blend of the four neighbours `p` (top-left, top-right,
    /// bottom-left, bottom-right) with weights `w` summing to 1024, rounded.
    fn blend(p: [Self; 4], w: &[u16; 4]) -> Self;
    /// `src` and `out` as RGB pixels if these are RGB (`None` otherwise):
    /// lets a [`RectifyMap`] run its RGB kernel on them.
    fn as_rgb<'a>(_src: &'a [Self], _out: &'a mut [Self]) -> Option<(&'a [Rgb], &'a mut [Rgb])> {
        None
    }
}

/// Half of the weights' sum: rounds a blend to nearest.
const HALF: u32 = 1 << (WEIGHT_BITS - 1);

impl Pixel for u8 {
    const CHANNELS: usize = 1;
    #[inline(always)]
    fn channel(self, _: usize) -> u8 {
        self
    }
    #[inline(always)]
    fn from_fn(mut f: impl FnMut(usize) -> u8) -> Self {
        f(0)
    }
    #[inline(always)]
    fn blend(p: [u8; 4], w: &[u16; 4]) -> u8 {
        let sum: u32 = p
            .iter()
            .zip(w)
            .map(|(&p, &w)| u32::from(p) * u32::from(w))
            .sum();
        ((sum + HALF) >> WEIGHT_BITS) as u8
    }
}

/// Bit position of each channel's lane in [`Pixel::blend`] for RGB: 21
/// bits hold a channel times a weight sum (255·1024 < 2²¹).
const LANE: u32 = 21;

/// An RGB pixel's channels in three lanes of a `u64`.
#[inline(always)]
fn lanes(p: Rgb) -> u64 {
    u64::from(p[0]) | u64::from(p[1]) << LANE | u64::from(p[2]) << (2 * LANE)
}

impl Pixel for Rgb {
    const CHANNELS: usize = 3;
    #[inline(always)]
    fn channel(self, c: usize) -> u8 {
        self[c]
    }
    #[inline(always)]
    fn from_fn(f: impl FnMut(usize) -> u8) -> Self {
        std::array::from_fn(f)
    }
    /// The three channels at once (one multiply per neighbour, not three):
    /// no lane overflows into the next, and each rounded lane is below 256.
    #[inline(always)]
    fn blend(p: [Rgb; 4], w: &[u16; 4]) -> Rgb {
        let half = u64::from(HALF);
        let round = half | half << LANE | half << (2 * LANE);
        let sum = p
            .iter()
            .zip(w)
            .fold(round, |acc, (&p, &w)| acc + lanes(p) * u64::from(w));
        let shift = |lane: u32| (sum >> (WEIGHT_BITS + lane * LANE)) as u8;
        [shift(0), shift(1), shift(2)]
    }
    fn as_rgb<'a>(src: &'a [Rgb], out: &'a mut [Rgb]) -> Option<(&'a [Rgb], &'a mut [Rgb])> {
        Some((src, out))
    }
}

/// The weights of every fraction pair `(fx, fy)` at index `fy·32 + fx`,
/// then zero weights for [`OUTSIDE`].
fn weight_table() -> Box<[[u16; 4]; TABLE]> {
    let mut table = Box::new([[0u16; 4]; TABLE]);
    for fy in 0..STEPS {
        for fx in 0..STEPS {
            let (gx, gy) = (STEPS - fx, STEPS - fy);
            table[(fy * STEPS + fx) as usize] =
                [gx * gy, fx * gy, gx * fy, fx * fy].map(|w| w as u16);
        }
    }
    table
}

/// Floating-point bilinear interpolation of channel `channel` at `(x, y)`,
/// with pixels outside the image black: the reference the fixed-point maps
/// approximate.
pub fn sample_bilinear<P: Pixel>(image: &Plane<P>, x: f64, y: f64, channel: usize) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let at = |dx: f64, dy: f64| {
        let (px, py) = (x0 + dx, y0 + dy);
        let inside =
            px >= 0.0 && py >= 0.0 && px < image.width() as f64 && py < image.height() as f64;
        if inside {
            f64::from(image.get(px as usize, py as usize).channel(channel))
        } else {
            0.0
        }
    };
    (1.0 - fy) * ((1.0 - fx) * at(0.0, 0.0) + fx * at(1.0, 0.0))
        + fy * ((1.0 - fx) * at(0.0, 1.0) + fx * at(1.0, 1.0))
}

/// A source pixel with some of its four neighbours outside the image.
#[derive(Clone, Copy, Debug)]
struct EdgePixel {
    /// Output index.
    at: u32,
    /// Top-left neighbour.
    x: i32,
    y: i32,
    /// Weight index.
    weight: u16,
}

/// One camera's rectification map: for each rectified pixel, where to read
/// the raw image.
#[derive(Clone, Debug)]
pub struct RectifyMap {
    size: (usize, usize),
    source: (usize, usize),
    /// Per output pixel: the source index of the top-left neighbour.
    offset: Vec<u32>,
    /// Per output pixel: the index of its weights in `table`.
    weight: Vec<u16>,
    /// Pixels along the source's edge, blended in a second pass.
    edge: Vec<EdgePixel>,
    table: Box<[[u16; 4]; TABLE]>,
    /// The weights as the AVX2 kernel takes them, if it runs here.
    #[cfg(target_arch = "x86_64")]
    separable: Option<Box<[u64; TABLE]>>,
}

impl RectifyMap {
    /// The map that rectifies `camera`'s images with rectifying rotation
    /// `r` and rectified projection `p` (OpenCV's `R1`, `P1` or `R2`, `P2`)
    /// into images of `size` (width, height).
    ///
    /// Fails if `P[:, :3]` is singular or a size is 0 or above
    /// [`crate::files::opencv::MAX_SIDE`].
    pub fn new(
        camera: &Camera,
        r: &Matrix3<f64>,
        p: &Matrix3x4<f64>,
        size: (usize, usize),
    ) -> Result<Self> {
        let max = crate::files::opencv::MAX_SIDE;
        let source = (camera.width, camera.height);
        for (what, (w, h)) in [("rectified", size), ("camera", source)] {
            if w == 0 || h == 0 || w > max || h > max {
                return Err(Error::Invalid(format!(
                    "{what} image size {w}x{h}: each side must be from 1 to {max}"
                )));
            }
        }
        let back = p.fixed_view::<3, 3>(0, 0).try_inverse().ok_or_else(|| {
            Error::Invalid("the rectified projection P[:, :3] is singular".into())
        })?;
        let ray = r.transpose() * back;
        let (sw, sh) = (source.0 as i64, source.1 as i64);
        let n = size.0 * size.1;
        let mut map = RectifyMap {
            size,
            source,
            offset: Vec::with_capacity(n),
            weight: Vec::with_capacity(n),
            edge: Vec::new(),
            table: weight_table(),
            #[cfg(target_arch = "x86_64")]
            separable: stereolink_image::cpu::avx2().then(avx2::separable_weights),
        };
        for v in 0..size.1 {
            for u in 0..size.0 {
                let d = ray * Vector3::new(u as f64, v as f64, 1.0);
                let src = if d.z > 0.0 {
                    Some(camera.pixel(Point2::new(d.x / d.z, d.y / d.z)))
                } else {
                    None
                };
                // The position in 1/32 pixels, rounded as OpenCV rounds it;
                // far-off points saturate to "outside".
                let fixed = src.filter(|s| s.x.abs() < 1e6 && s.y.abs() < 1e6).map(|s| {
                    let q = |c: f64| (c * f64::from(STEPS)).round() as i64;
                    (q(s.x), q(s.y))
                });
                let (mut offset, mut weight) = (0, OUTSIDE);
                if let Some((qx, qy)) = fixed {
                    let (x, y) = (qx >> FRACTION_BITS, qy >> FRACTION_BITS);
                    let w = ((qy & i64::from(STEPS - 1)) * i64::from(STEPS)
                        + (qx & i64::from(STEPS - 1))) as u16;
                    if x >= 0 && y >= 0 && x + 1 < sw && y + 1 < sh {
                        (offset, weight) = ((y * sw + x) as u32, w);
                    } else if x >= -1 && y >= -1 && x < sw && y < sh {
                        map.edge.push(EdgePixel {
                            at: (v * size.0 + u) as u32,
                            x: x as i32,
                            y: y as i32,
                            weight: w,
                        });
                    }
                }
                map.offset.push(offset);
                map.weight.push(weight);
            }
        }
        Ok(map)
    }

    /// The rectified image's size (width, height).
    pub fn size(&self) -> (usize, usize) {
        self.size
    }

    /// The raw image's size (width, height) the map reads.
    pub fn source_size(&self) -> (usize, usize) {
        self.source
    }

    /// Rectifies `src` into a new image.
    pub fn apply<P: Pixel>(&self, src: &Plane<P>) -> Result<Plane<P>> {
        let mut out = Plane::default();
        self.apply_into(src, &mut out)?;
        Ok(out)
    }

    /// Rectifies `src` into `out`, which takes the rectified size and
    /// reuses its storage (no allocation once it is large enough).
    pub fn apply_into<P: Pixel>(&self, src: &Plane<P>, out: &mut Plane<P>) -> Result<()> {
        if src.dims() != self.source {
            return Err(Error::SizeMismatch(format!(
                "the image is {}x{}, the calibration is for {}x{}",
                src.width(),
                src.height(),
                self.source.0,
                self.source.1
            )));
        }
        if out.dims() != self.size {
            out.reset(self.size.0, self.size.1, P::default());
        }
        let s = src.as_slice();
        let table = &*self.table;
        // Every offset leaves room for the pixel below-right (new() made
        // sure; an outside pixel has offset 0 and zero weights), and the
        // source has at least 2 rows and 2 columns when any offset is used.
        if s.len() >= self.source.0 + 2 {
            self.blend_inside(s, out.as_mut_slice());
        } else {
            out.as_mut_slice().fill(P::default());
        }
        let (sw, sh) = (self.source.0 as i32, self.source.1 as i32);
        let at = |x: i32, y: i32| {
            if x >= 0 && y >= 0 && x < sw && y < sh {
                s[(y * sw + x) as usize]
            } else {
                P::default()
            }
        };
        let o = out.as_mut_slice();
        for e in &self.edge {
            let n = [
                at(e.x, e.y),
                at(e.x + 1, e.y),
                at(e.x, e.y + 1),
                at(e.x + 1, e.y + 1),
            ];
            o[e.at as usize] = P::blend(n, &table[usize::from(e.weight)]);
        }
        Ok(())
    }
}

impl RectifyMap {
    /// The first pass of [`Self::apply_into`]: every output pixel blended
    /// from its four neighbours at its offset in `s` (at least two rows
    /// and columns), in AVX2 for RGB where the CPU has it.
    fn blend_inside<P: Pixel>(&self, s: &[P], out: &mut [P]) {
        #[cfg(target_arch = "x86_64")]
        if let (Some(separable), Some((src, out))) = (&self.separable, P::as_rgb(s, out)) {
            let (offset, weight) = (&self.offset, &self.weight);
            let rest = |k: usize, px: &mut Rgb| *px = self.blend_at(src, offset[k], weight[k]);
            // SAFETY: `separable` is only built where the CPU has AVX2.
            return unsafe {
                avx2::blend_inside(src, self.source.0, offset, weight, separable, out, rest)
            };
        }
        for ((o, &i), &w) in out.iter_mut().zip(&self.offset).zip(&self.weight) {
            *o = self.blend_at(s, i, w);
        }
    }

    /// The blend of the four neighbours of `s` from offset `i` on with
    /// the weights of index `w` (zero for [`OUTSIDE`]).
    #[inline(always)]
    fn blend_at<P: Pixel>(&self, s: &[P], i: u32, w: u16) -> P {
        let stride = self.source.0;
        let n = &s[i as usize..i as usize + stride + 2];
        let w = &self.table[usize::from(w) & (TABLE - 1)];
        P::blend([n[0], n[1], n[stride], n[stride + 1]], w)
    }
}

/// Both cameras' maps: rectifies a raw pair.
#[derive(Clone, Debug)]
pub struct StereoRectifier {
    /// The left camera's map (`R1`, `P1`).
    pub left: RectifyMap,
    /// The right camera's map (`R2`, `P2`).
    pub right: RectifyMap,
}

impl StereoRectifier {
    /// The maps of a calibration, to its rectified size.
    pub fn new(calib: &StereoCalibration) -> Result<Self> {
        let (rig, rect) = (&calib.rig, &calib.rectification);
        Ok(StereoRectifier {
            left: RectifyMap::new(&rig.left, &rect.r1, &rect.p1, rect.size)?,
            right: RectifyMap::new(&rig.right, &rect.r2, &rect.p2, rect.size)?,
        })
    }

    /// Rectifies a raw pair into a new pair.
    pub fn rectify<P: Pixel>(
        &self,
        left: &Plane<P>,
        right: &Plane<P>,
    ) -> Result<(Plane<P>, Plane<P>)> {
        let mut out = (Plane::default(), Plane::default());
        self.rectify_into(left, right, &mut out.0, &mut out.1)?;
        Ok(out)
    }

    /// Rectifies a raw pair into reused buffers, the two views in parallel
    /// when the rayon pool has more than one thread.
    pub fn rectify_into<P: Pixel>(
        &self,
        left: &Plane<P>,
        right: &Plane<P>,
        out_left: &mut Plane<P>,
        out_right: &mut Plane<P>,
    ) -> Result<()> {
        let (a, b) = rayon::join(
            || self.left.apply_into(left, out_left),
            || self.right.apply_into(right, out_right),
        );
        a.and(b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::tests::calibration;
    use crate::Distortion;
    use stereolink_image::GrayImage;

    fn noise(w: usize, h: usize, seed: u32) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| {
            let mut v =
                (x as u32).wrapping_mul(0x9E37_79B9) ^ (y as u32).wrapping_mul(0x85EB_CA6B) ^ seed;
            v ^= v >> 15;
            v = v.wrapping_mul(0x2C1B_3C6D);
            (v >> 24) as u8
        })
    }

    /// Sinusoids: at most 16 gray levels per pixel.
    fn smooth(w: usize, h: usize) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| {
            let (x, y) = (x as f64, y as f64);
            (127.5 + 60.0 * (x / 7.0).sin() + 60.0 * (y / 9.0 + x / 23.0).cos()).round() as u8
        })
    }

    /// Where the map's definition says output pixel `(u, v)` reads.
    fn source_of(
        cam: &Camera,
        r: &Matrix3<f64>,
        p: &Matrix3x4<f64>,
        u: usize,
        v: usize,
    ) -> Point2<f64> {
        let d = r.transpose()
            * p.fixed_view::<3, 3>(0, 0).try_inverse().unwrap()
            * Vector3::new(u as f64, v as f64, 1.0);
        cam.pixel(Point2::new(d.x / d.z, d.y / d.z))
    }

    #[test]
    fn identity_rig_without_distortion_maps_every_pixel_to_itself() {
        let mut c = calibration();
        for cam in [&mut c.rig.left, &mut c.rig.right] {
            cam.distortion = Distortion::default();
        }
        let cam = c.rig.left;
        let p = Matrix3x4::new(
            cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0,
        );
        let map = RectifyMap::new(&cam, &Matrix3::identity(), &p, (640, 480)).unwrap();
        let img = noise(640, 480, 7);
        assert_eq!(map.apply(&img).unwrap(), img);
        let rgb = img.map(|g| [g, g.wrapping_mul(3), 255 - g]);
        assert_eq!(map.apply(&rgb).unwrap(), rgb);
    }

    #[test]
    fn matches_floating_point_bilinear_within_one_level() {
        let c = calibration();
        let (cam, rect) = (c.rig.left, c.rectification);
        let map = RectifyMap::new(&cam, &rect.r1, &rect.p1, rect.size).unwrap();
        let img = smooth(640, 480);
        let out = map.apply(&img).unwrap();
        let mut worst = 0.0f64;
        let mut inside = 0;
        for v in 0..480 {
            for u in 0..640 {
                // Inside the image: across its edge the black border is a
                // jump no 1/32-pixel position can follow within a level.
                let s = source_of(&cam, &rect.r1, &rect.p1, u, v);
                if s.x >= 0.0 && s.y >= 0.0 && s.x <= 639.0 && s.y <= 479.0 {
                    let reference = sample_bilinear(&img, s.x, s.y, 0);
                    worst = worst.max((f64::from(out.get(u, v)) - reference).abs());
                    inside += 1;
                }
            }
        }
        assert!(worst <= 1.0, "worst difference {worst}");
        // The test means something: most pixels read the image, some do not.
        assert!(
            inside > 640 * 480 * 8 / 10 && inside < 640 * 480,
            "{inside}"
        );
    }

    #[test]
    fn fixed_point_is_exact_at_the_quantised_positions() {
        // On noise, against the reference at the 1/32-pixel positions the
        // map keeps (where only the final rounding differs), RGB included.
        let c = calibration();
        let (cam, mut p) = (c.rig.right, c.rectification.p2);
        let r = c.rectification.r2;
        // A wider rectified view, which sees past the raw image's edges.
        for i in [(0, 0), (1, 1), (0, 3)] {
            p[i] *= 0.6;
        }
        let map = RectifyMap::new(&cam, &r, &p, (640, 480)).unwrap();
        let gray = noise(640, 480, 3);
        let rgb = gray.map(|g| [g, 255 - g, g / 2]);
        let out = map.apply(&rgb).unwrap();
        let mut edge_pixels = 0;
        for v in (0..480).step_by(3) {
            for u in 0..640 {
                let s = source_of(&cam, &r, &p, u, v);
                let q = |c: f64| (c * 32.0).round() / 32.0;
                let (x, y) = (q(s.x), q(s.y));
                edge_pixels += usize::from((-1.0..0.0).contains(&x) || (639.0..640.0).contains(&x));
                for ch in 0..3 {
                    let reference = sample_bilinear(&rgb, x, y, ch);
                    let got = f64::from(out.get(u, v)[ch]);
                    assert!(
                        (got - reference).abs() <= 0.5 + 1e-9,
                        "({u}, {v}) ch {ch}: {got} vs {reference}"
                    );
                }
            }
        }
        assert!(edge_pixels > 0, "the edge pass was exercised");
        assert!(map.weight.contains(&OUTSIDE), "and the outside");
    }

    #[test]
    fn outputs_are_reused_and_sizes_checked() {
        let c = calibration();
        let r = StereoRectifier::new(&c).unwrap();
        let img = smooth(640, 480);
        let (l, rr) = r.rectify(&img, &img).unwrap();
        let (mut a, mut b) = (GrayImage::new(640, 480, 9), GrayImage::default());
        r.rectify_into(&img, &img, &mut a, &mut b).unwrap();
        assert_eq!((&a, &b), (&l, &rr));
        let ptr = a.as_slice().as_ptr();
        r.rectify_into(&img, &img, &mut a, &mut b).unwrap();
        assert_eq!(a.as_slice().as_ptr(), ptr);
        let small = smooth(320, 240);
        assert!(matches!(
            r.rectify(&small, &small),
            Err(Error::SizeMismatch(_))
        ));
        let mut bad = c;
        bad.rectification.p1 = Matrix3x4::zeros();
        assert!(StereoRectifier::new(&bad).is_err());
    }
}
