//! Colour-weighted median refinement (a joint bilateral median, as in
//! Ma et al., "Constant time weighted median filtering for stereo
//! matching and beyond", ICCV 2013), in integer arithmetic: a vectorised
//! pass settles most pixels, a search over the bins in lanes the rest
//! (see [`WeightedMedianGuide::filter`]); both give the definition's
//! result exactly.
//!
//! Each pixel takes the weighted median of the valid disparities of a
//! window, a neighbour `q` of the centre `p` weighing
//! `⌊max(0, K − Σ_k |I_k(p) − I_k(q)|)² / 2^s⌋` by their summed colour
//! difference in the left (reference) view ([`weight`]): `K` is
//! [`WeightedMedian::color_reach`], and `s` the smallest shift that keeps a
//! window's sum in 16 bits. Ma et al. weigh by a Gaussian of the colour
//! difference; this truncated quadratic falls off alike, about as
//! accurate (docs/tuning.md, “The weighted median's weights, reach, window
//! and step”), reaches zero within the `u8` range, and is a few lane
//! operations with no table and no weights kept in memory. Neighbours
//! of another colour, likely on another surface, barely count, so
//! disparity edges follow colour edges: this undoes much of the edge
//! fattening of window matching and cleans the streaks of the hole fill.
//! It runs after any matcher.
//!
//! Disparities are binned to whole pixels; a pixel whose own disparity
//! lies in the median bin keeps it (and so its subpixel part), any other
//! takes the bin's whole value. The median bin is the first, in ascending
//! order, where the running sum of weights reaches half the total. The
//! window is sampled every `step` pixels in both directions, which keeps
//! its reach at a fraction of the cost.

use rayon::prelude::*;
use stereolink_image::{DisparityMap, RgbImage};

use crate::StereoError;

#[cfg(target_arch = "x86_64")]
use row::filter_row_avx2;
use row::{filter_row, RowScratch};

mod row;
mod search;
#[cfg(test)]
mod tests;

/// Parameters of [`weighted_median`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct WeightedMedian {
    /// Window radius: the window spans `2·radius + 1` pixels each way (1..=15).
    pub radius: usize,
    /// Colour reach `K` of the weights: the summed RGB difference at which
    /// a neighbour's weight falls to zero (≥ 1).
    pub color_reach: u8,
    /// Sampling step inside the window (1 = every pixel, at most `radius`).
    pub step: usize,
}

impl WeightedMedian {
    /// The default after WTA: a 13×13 window sampled every third pixel
    /// (25 samples), `K` = 150; before a fill, [`Self::before_fill`].
    /// Sparse samples keep a wide reach at a fraction of the cost of every
    /// pixel; the window, step and reach are explained in docs/tuning.md,
    /// “The weighted median's weights, reach, window and step”.
    pub const DEFAULT: WeightedMedian = WeightedMedian {
        radius: 6,
        color_reach: 150,
        step: 3,
    };

    /// The default after the plane matcher, whose map is dense and subpixel
    /// already: a 5×5 window, every pixel, `K` = 250, once. Most of the
    /// planes' remaining errors are a pixel or two of foreground along
    /// depth edges, and the median snaps those to the colour edge
    /// (docs/tuning.md, “The weighted median after the planes”).
    pub const AFTER_PLANES: WeightedMedian = WeightedMedian {
        radius: 2,
        color_reach: 250,
        step: 1,
    };

    /// The pass before a hole fill, on the valid pixels next to a hole
    /// ([`WeightedMedianGuide::filter_borders`]): the centre, corners and
    /// edge midpoints (9 samples) of a window half again as wide (radius
    /// `⌊3·radius / 2⌋`, at most 15), with the same reach. Those pixels
    /// lie along holes, where a wide reach finds their surface's colour;
    /// 9 samples cost about a third of 25 (docs/tuning.md, “The colour-weighted
    /// median as the default refinement”).
    pub fn before_fill(&self) -> WeightedMedian {
        let radius = (3 * self.radius / 2).clamp(1, 15);
        WeightedMedian {
            radius,
            step: radius,
            ..*self
        }
    }

    /// Checks the documented ranges.
    pub fn validate(&self) -> Result<(), StereoError> {
        let bad = |what: String| Err(StereoError::Parameter(what));
        if !(1..=15).contains(&self.radius) {
            return bad(format!(
                "weighted median radius {} must be 1..=15",
                self.radius
            ));
        }
        if self.color_reach == 0 {
            return bad("weighted median colour reach must be at least 1".into());
        }
        if self.step == 0 || self.step > self.radius {
            return bad(format!(
                "weighted median step {} must be 1..=radius ({})",
                self.step, self.radius
            ));
        }
        Ok(())
    }
}

/// `2²³`: a whole `x` in `0..2²³` is the low mantissa bits of `x + MAGIC`.
const MAGIC: f32 = 8_388_608.0;

/// The weight of a neighbour of colour `q` for a centre of colour `c`:
/// `⌊max(0, reach − Σ_k |c_k − q_k|)² / 2^shift⌋`. The difference adds up
/// in `u8` lanes, saturating at 255 (where any weight is zero already).
#[inline(always)]
fn weight(c: [u8; 3], q: [u8; 3], reach: u8, shift: u32) -> u16 {
    let diff = c[0]
        .abs_diff(q[0])
        .saturating_add(c[1].abs_diff(q[1]))
        .saturating_add(c[2].abs_diff(q[2]));
    let t = u16::from(reach.saturating_sub(diff));
    (t * t) >> shift
}

/// The smallest shift `s` with `n · ⌊reach² / 2^s⌋ ≤ 65535`: a window's
/// sum of `n` weights fits a `u16` (and the largest weight is at least 1,
/// as `n` ≤ 961).
fn weight_shift(reach: u8, n: usize) -> u32 {
    let peak = u32::from(reach).pow(2);
    (0..16)
        .find(|&s| n as u32 * (peak >> s) <= 65535)
        .unwrap_or(16)
}

/// The weighted median of `map` guided by `guide` (same size; checked by
/// the caller). Invalid pixels take a value when some valid neighbour has
/// weight; pixels without any stay invalid. A map whose values span 32767
/// px or more is returned unchanged. Rows run in parallel; see
/// [`WeightedMedianGuide::filter`] for how the work is kept small.
///
/// # Panics
/// If the sizes differ.
pub fn weighted_median(map: &DisparityMap, guide: &RgbImage, p: &WeightedMedian) -> DisparityMap {
    let mut out = DisparityMap::default();
    WeightedMedianGuide::new(guide, p).filter(map, &mut out);
    out
}

/// What [`weighted_median`] takes from the guide and the parameters alone,
/// built once for any number of maps of the guide's size (the refinement
/// filters twice with one guide), and rebuilt in its own buffers for the
/// next frame ([`Self::rebuild`]): frames of an unchanged size allocate
/// nothing after the first.
pub struct WeightedMedianGuide {
    p: WeightedMedian,
    dims: (usize, usize),
    /// The border of the padded grid: the radius the guide was built for,
    /// at least the window's ([`Self::set_window`]).
    pad: usize,
    /// The colour planes apart and border-replicated by `pad` on every
    /// side, so that a sample's colours along a row are a slice.
    planes: [Vec<u8>; 3],
    /// The window's samples in order, as offsets in the padded grid.
    offsets: Vec<isize>,
    /// [`weight_shift`] of the window.
    shift: u32,
    /// Whether the kernels run with AVX2 (same results either way).
    avx2: bool,
    /// The bins of the map being filtered, padded as the colour planes.
    bin_pad: Vec<u16>,
}

impl WeightedMedianGuide {
    /// The guide of `guide` for `p`.
    pub fn new(guide: &RgbImage, p: &WeightedMedian) -> Self {
        Self::with_avx2(guide, p, stereolink_image::cpu::avx2())
    }

    /// [`Self::new`] with the AVX2 kernels (`avx2`, only if the CPU has it)
    /// or the portable ones.
    fn with_avx2(guide: &RgbImage, p: &WeightedMedian, avx2: bool) -> Self {
        let mut g = WeightedMedianGuide {
            p: *p,
            dims: (0, 0),
            pad: 0,
            planes: Default::default(),
            offsets: Vec::new(),
            shift: 0,
            avx2,
            bin_pad: Vec::new(),
        };
        g.rebuild(guide, p);
        g
    }

    /// Makes this the guide of `guide` for `p`, in the buffers it has.
    pub fn rebuild(&mut self, guide: &RgbImage, p: &WeightedMedian) {
        pad_planes_into(&mut self.planes, guide, p.radius);
        (self.dims, self.pad) = (guide.dims(), p.radius);
        self.set_window(p);
    }

    /// Makes this the guide of the same image for `p`, whose window fits
    /// the border it was built with, without padding the colour planes
    /// again (the refinement's second pass has a narrower window than its
    /// first).
    ///
    /// # Panics
    /// If `p.radius` is larger than the radius the guide was built for.
    pub fn set_window(&mut self, p: &WeightedMedian) {
        assert!(
            p.radius <= self.pad,
            "the window outgrows the guide's border"
        );
        let (r, step) = (p.radius as isize, p.step);
        let wp = (self.dims.0 + 2 * self.pad) as isize;
        self.offsets.clear();
        self.offsets.extend(
            (-r..=r)
                .step_by(step)
                .flat_map(|dy| (-r..=r).step_by(step).map(move |dx| dy * wp + dx)),
        );
        self.shift = weight_shift(p.color_reach, self.offsets.len());
        self.p = *p;
    }

    /// The weighted median of `map` (see [`weighted_median`]).
    ///
    /// Disparities are binned to whole pixels. Most pixels need no sorting:
    /// one vectorised pass over a row sums, per pixel and in registers, the
    /// weights of its valid samples below, in and at any bin for a
    /// candidate bin `c` (the pixel's own, or for an invalid pixel its left
    /// neighbour's), and in the bins `c − 1` and `c + 1`. Where one of the
    /// three is the median, the sums show it exactly, and the pixel takes it
    /// (keeping its own value if it is its own bin). A window without
    /// weight leaves the pixel as it is. Only the rest (pixels at a
    /// disparity edge, holes unlike their left neighbour) go through a
    /// bisection of the bins, in lanes for the chunk of pixels that holds
    /// them ([`search`](search::search)).
    ///
    /// The result goes into `out` (resized, storage reused).
    ///
    /// # Panics
    /// If `map` is not the guide's size.
    pub fn filter(&mut self, map: &DisparityMap, out: &mut DisparityMap) {
        self.filter_with(map, out, false)
    }

    /// As [`Self::filter`], but only the valid pixels next to a hole (one
    /// of their 8 neighbours invalid) take the median, the others stay as
    /// they are: before a hole fill that takes each hole's nearest valid
    /// pixels along rows, columns and diagonals ([`crate::refine::HoleFill::Directions`]),
    /// which are next to holes, these are the pixels whose values it
    /// spreads. The rest need no work.
    ///
    /// # Panics
    /// If `map` is not the guide's size.
    pub fn filter_borders(&mut self, map: &DisparityMap, out: &mut DisparityMap) {
        self.filter_with(map, out, true)
    }

    /// [`Self::filter`], or [`Self::filter_borders`] if `borders`.
    fn filter_with(&mut self, map: &DisparityMap, out: &mut DisparityMap, borders: bool) {
        assert_eq!(map.dims(), self.dims);
        if out.dims() != map.dims() {
            out.reset(map.width(), map.height(), 0.0);
        }
        let w = self.dims.0;
        // The smallest and largest valid values, by rows in parallel
        // (branch-free selects, so that the loop vectorises).
        let extremes = |(a, b): (f32, f32), (c, d): (f32, f32)| (a.min(c), b.max(d));
        let (lo, hi) = map
            .as_slice()
            .par_chunks(w.max(1))
            .map(|row| {
                row.iter()
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |span, &d| {
                        let f = d.is_finite();
                        let lo = if f { d } else { f32::INFINITY };
                        let hi = if f { d } else { f32::NEG_INFINITY };
                        extremes(span, (lo, hi))
                    })
            })
            .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), extremes);
        if lo > hi {
            // No valid pixel.
            out.as_mut_slice().copy_from_slice(map.as_slice());
            return;
        }
        // Rounding is monotonic: the extremes' bins are the extreme bins.
        let (lo, hi) = (lo.round(), hi.round());
        let bins = (hi - lo) as usize + 1;
        if bins >= i16::MAX as usize {
            // Not a disparity map of any image this crate matches: left as
            // is (bins and their differences are `i16` in the lanes).
            out.as_mut_slice().copy_from_slice(map.as_slice());
            return;
        }
        let r = self.pad;
        // Invalid pixels go to the extra bin `bins`, which never counts.
        let invalid = bins as u16;
        let mut bin_pad = std::mem::take(&mut self.bin_pad);
        pad_into(&mut bin_pad, map.as_slice(), self.dims, r, |row, src| {
            with_avx2(self.avx2, || bin_row(row, src, lo, invalid))
        });
        let job = MapJob {
            guide: self,
            bin_pad: &bin_pad,
            lo,
            invalid,
            borders,
        };
        out.as_mut_slice()
            .par_chunks_mut(w)
            .enumerate()
            .for_each_init(RowScratch::default, |scratch, (y, row)| {
                // Each row copies its own (in parallel, not one copy of
                // the map before).
                row.copy_from_slice(map.row(y));
                #[cfg(target_arch = "x86_64")]
                if self.avx2 {
                    // SAFETY: `avx2` only when the CPU has it.
                    return unsafe { filter_row_avx2(&job, y, row, scratch) };
                }
                filter_row(&job, y, row, scratch)
            });
        self.bin_pad = bin_pad;
    }
}

/// What [`filter_row`] reads for the whole map.
struct MapJob<'a> {
    guide: &'a WeightedMedianGuide,
    bin_pad: &'a [u16],
    /// The disparity of bin 0.
    lo: f32,
    /// The bin of invalid pixels, one past the last valid one.
    invalid: u16,
    /// Whether only valid pixels next to holes take the median
    /// ([`WeightedMedianGuide::filter_borders`]).
    borders: bool,
}

/// Runs `f` compiled for AVX2 if `avx2` (only when the CPU has it), as is
/// otherwise: the same loops, in wider vectors (the kernels here are
/// `#[inline(always)]` into `f`, and LLVM inlines `f`, called once, into
/// the AVX2 function; checked in the disassembly, as a speed matter only:
/// the results are the same either way).
#[inline(always)]
fn with_avx2<R>(avx2: bool, f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        #[target_feature(enable = "avx2")]
        unsafe fn run<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        // SAFETY: the caller saw AVX2 at run time.
        return unsafe { run(f) };
    }
    let _ = avx2;
    f()
}

/// Writes into `out` (resized, storage reused) `src` (`w`×`h`, row-major)
/// border-replicated by `r` on every side, each row mapped by
/// `f(out, src)` (`out` as long as `src`); rows in parallel.
fn pad_into<S: Sync, T: Copy + Default + Send>(
    out: &mut Vec<T>,
    src: &[S],
    (w, h): (usize, usize),
    r: usize,
    f: impl Fn(&mut [T], &[S]) + Sync,
) {
    if w == 0 || h == 0 {
        out.clear();
        return;
    }
    let wp = w + 2 * r;
    // Every element is written below.
    out.resize(wp * (h + 2 * r), T::default());
    out.par_chunks_mut(wp).enumerate().for_each(|(yp, row)| {
        let y = yp.clamp(r, r + h - 1) - r;
        let (left, rest) = row.split_at_mut(r);
        let (middle, right) = rest.split_at_mut(w);
        f(middle, &src[y * w..(y + 1) * w]);
        left.fill(middle[0]);
        right.fill(middle[w - 1]);
    });
}

/// [`pad_into`] for the three colour planes of `guide` at once (one pass
/// over its pixels, not one per plane).
fn pad_planes_into(planes: &mut [Vec<u8>; 3], guide: &RgbImage, r: usize) {
    let (w, h) = guide.dims();
    if w == 0 || h == 0 {
        planes.iter_mut().for_each(Vec::clear);
        return;
    }
    let wp = w + 2 * r;
    // Every element is written below.
    planes
        .iter_mut()
        .for_each(|p| p.resize(wp * (h + 2 * r), 0));
    let [red, green, blue] = planes;
    let rows = red.par_chunks_mut(wp).zip(green.par_chunks_mut(wp));
    rows.zip(blue.par_chunks_mut(wp))
        .enumerate()
        .for_each(|(yp, ((red, green), blue))| {
            let y = yp.clamp(r, r + h - 1) - r;
            let src = guide.row(y);
            let middle = r..r + w;
            let planes = (&mut red[middle.clone()], &mut green[middle.clone()]);
            let rows = planes.0.iter_mut().zip(planes.1.iter_mut());
            for (((o0, o1), o2), c) in rows.zip(&mut blue[middle]).zip(src) {
                (*o0, *o1, *o2) = (c[0], c[1], c[2]);
            }
            for row in [red, green, blue] {
                let (first, last) = (row[r], row[r + w - 1]);
                row[..r].fill(first);
                row[r + w..].fill(last);
            }
        });
}

/// The bins of a row of disparities (`invalid` for an invalid one);
/// branch-free, so that it vectorises.
#[inline(always)]
fn bin_row(out: &mut [u16], src: &[f32], lo: f32, invalid: u16) {
    for (o, &d) in out.iter_mut().zip(src) {
        // A whole number in 0..=65535 as the low mantissa bits of `x + 2²³`
        // (a saturating cast would not vectorise); a non-finite `d` gives
        // some bin and is replaced.
        let bin = ((d.round() - lo).clamp(0.0, 65535.0) + MAGIC).to_bits() as u16;
        *o = if d.is_finite() { bin } else { invalid };
    }
}
