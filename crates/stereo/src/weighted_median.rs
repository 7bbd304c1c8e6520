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
//! difference; this truncated quadratic falls off alike (on the 20
//! Middlebury scenes after WTA, bad > 1 px 26.99 % against 26.93 % with
//! `exp(−diff / 50)`), reaches zero within the `u8` range, and is a few
//! lane operations with no table and no weights kept in memory. Neighbours
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
    /// The measured default after WTA: a 17×17 window sampled every fourth
    /// pixel (25 samples), `K` = 150. Bad > 1 px on the 20 Middlebury
    /// scenes 27.00 % on average, 3.53 / 0.83 / 15.38 / 6.76 % on Tsukuba /
    /// Venus / Teddy / Cones (`K` = 100 / 130 / 170 / 255: 27.02 / 27.00 /
    /// 27.01 / 27.10 %; a triangle `K − diff` in place of its square at
    /// `K` = 80 / 100 / 120: 27.05 / 27.06 / 27.07 %). The Gaussian weights
    /// `exp(−diff / 50)` gave 26.93 % and 3.60 / 0.87 / 15.35 / 6.85 % at
    /// 1.6–2.3x the time of the two passes. Earlier, with those weights:
    /// every second pixel (81 samples, σ = 30) gave 27.02 % at about twice
    /// the time; radius 9 at step 3 27.27 %, radius 10 at step 5 27.88 %,
    /// radius 12 at step 6 28.75 %, radius 7 at step 3 27.87 %; radius 7 at
    /// step 1 (225 samples) is better on the 2014 scenes but misses the
    /// Teddy target (16.53 %).
    pub const DEFAULT: WeightedMedian = WeightedMedian {
        radius: 8,
        color_reach: 150,
        step: 4,
    };

    /// The measured default after the plane matcher, whose map is dense and
    /// subpixel already: a 5×5 window, every pixel, `K` = 250, once. Most
    /// of the planes' remaining errors are a pixel or two of foreground
    /// along depth edges, and the median snaps those to the colour edge.
    /// Bad > 1 px over the 20 shared scenes 8.45 % against 8.52 % without,
    /// Tsukuba / Venus / Teddy / Cones 2.09 / 0.13 / 3.07 / 2.40 against
    /// 2.20 / 0.16 / 3.18 / 2.50 %. Chosen when the boundary step's census
    /// was 9×7 (8.63 against 8.71 %): radius 1 / 3 / 4 gave 8.64 / 8.73 /
    /// 8.86 % (`K` = 150 at radius 1, 3 and 4), and radius 2 with `K` = 80 /
    /// 150 / 200 8.71 / 8.66 / 8.64 %.
    pub const AFTER_PLANES: WeightedMedian = WeightedMedian {
        radius: 2,
        color_reach: 250,
        step: 1,
    };

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
    /// The colour planes apart and border-replicated by `radius` on every
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
        Self::with_avx2(guide, p, crate::wta::avx2_available())
    }

    /// [`Self::new`] with the AVX2 kernels (`avx2`, only if the CPU has it)
    /// or the portable ones.
    fn with_avx2(guide: &RgbImage, p: &WeightedMedian, avx2: bool) -> Self {
        let mut g = WeightedMedianGuide {
            p: *p,
            dims: (0, 0),
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
        let dims = guide.dims();
        for (k, plane) in self.planes.iter_mut().enumerate() {
            pad_into(plane, guide.as_slice(), dims, p.radius, |row, src| {
                row.iter_mut().zip(src).for_each(|(o, c)| *o = c[k]);
            });
        }
        let (r, step) = (p.radius as isize, p.step);
        let wp = dims.0 as isize + 2 * r;
        self.offsets.clear();
        self.offsets.extend(
            (-r..=r)
                .step_by(step)
                .flat_map(|dy| (-r..=r).step_by(step).map(move |dx| dy * wp + dx)),
        );
        self.shift = weight_shift(p.color_reach, self.offsets.len());
        (self.p, self.dims) = (*p, dims);
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
    /// them ([`search`]).
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
        out.as_mut_slice().copy_from_slice(map.as_slice());
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
            return;
        }
        // Rounding is monotonic: the extremes' bins are the extreme bins.
        let (lo, hi) = (lo.round(), hi.round());
        let bins = (hi - lo) as usize + 1;
        if bins >= i16::MAX as usize {
            // Not a disparity map of any image this crate matches: left as
            // is (bins and their differences are `i16` in the lanes).
            return;
        }
        let r = self.p.radius;
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

/// [`filter_row`] compiled for AVX2 (a function of its own: LLVM does not
/// always inline a closure this large into [`with_avx2`]'s).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn filter_row_avx2(job: &MapJob, y: usize, row: &mut [f32], scratch: &mut RowScratch) {
    filter_row(job, y, row, scratch)
}

/// Pixels whose sums [`settle`] keeps in registers together.
const LANES: usize = 16;

/// A bin above every valid one and `invalid`: the pixel is left to
/// [`search`].
const HARD: u16 = u16::MAX;

/// [`WeightedMedianGuide::filter`] for row `y` of the output, `row` (a
/// copy of the map's).
#[inline(always)]
fn filter_row(job: &MapJob, y: usize, row: &mut [f32], scratch: &mut RowScratch) {
    let (w, r) = (row.len(), job.guide.p.radius);
    let wp = w + 2 * r;
    let (lo, invalid) = (job.lo, job.invalid);
    let centre = (y + r) * wp + r;
    let own = &job.bin_pad[centre..centre + w];
    // The bin tested: a valid pixel's own; for an invalid one, that of the
    // nearest valid pixel to its left (else the row's first valid one),
    // the likeliest value of a hole amid one surface.
    let candidates = &mut scratch.candidates;
    candidates.clear();
    let first_valid = own.iter().copied().find(|&b| b != invalid);
    let mut left = first_valid.unwrap_or(invalid);
    candidates.extend(own.iter().map(|&b| {
        left = if b != invalid { b } else { left };
        left
    }));
    // The pixels that stay as they are: with `borders`, all but the valid
    // ones with an invalid pixel among their 8 neighbours (the padded
    // bins replicate the border as the window does).
    let stay = &mut scratch.stay;
    stay.clear();
    if job.borders {
        let near = &mut scratch.near_hole;
        let rows =
            [centre - wp - 1, centre - 1, centre + wp - 1].map(|s| &job.bin_pad[s..s + w + 2]);
        near.clear();
        near.extend(
            (rows[0].iter().zip(rows[1]).zip(rows[2]))
                .map(|((&a, &b), &c)| (a == invalid) | (b == invalid) | (c == invalid)),
        );
        stay.extend(
            own.iter()
                .zip(near.windows(3))
                .map(|(&b, n)| (b == invalid) | !(n[0] | n[1] | n[2])),
        );
    } else {
        stay.resize(w, false);
    }
    // Chunks of `LANES` over the pixels that do not stay ([`covering`]); a
    // narrower row pixel by pixel. The others need no sums: they stay
    // whatever their sums hold (those of an earlier row, or zero).
    let (candidates, stay) = (&scratch.candidates[..], &scratch.stay[..]);
    let s = &mut scratch.sums;
    for v in [
        &mut s.total,
        &mut s.below,
        &mut s.at,
        &mut s.lower,
        &mut s.upper,
    ] {
        v.resize(w, 0);
    }
    let n = if w >= LANES { LANES } else { 1 };
    for x in covering(stay, n, |&stays| !stays) {
        let at = x..x + n;
        let sums = [
            &mut s.total,
            &mut s.below,
            &mut s.at,
            &mut s.lower,
            &mut s.upper,
        ]
        .map(|v| &mut v[at.clone()]);
        if n == LANES {
            settle::<LANES>(job, centre + x, &candidates[at], sums);
        } else {
            settle::<1>(job, centre + x, &candidates[at], sums);
        }
    }
    // Which of `c`, `c − 1`, `c + 1` is the median, for the whole row at
    // once (branch-free selects, so that it vectorises): bin `c` is when
    // twice the sum below it is under the total and twice the sum up to
    // it is at least the total; `c − 1` and `c + 1` likewise. A pixel
    // that stays, or without weight, keeps its bin; those that none
    // settles are [`HARD`].
    let medians = &mut scratch.medians;
    medians.resize(w, 0);
    let lanes = (s.total.iter().zip(&s.below).zip(&s.at))
        .zip(s.lower.iter().zip(&s.upper))
        .zip(candidates.iter().zip(own).zip(stay));
    for (m, ((((&t, &b), &a), (&lw, &up)), ((&c, &own), &stay))) in medians.iter_mut().zip(lanes) {
        let (t, b, a) = (u32::from(t), u32::from(b), u32::from(a));
        let (lw, up) = (u32::from(lw), u32::from(up));
        // `c` is `invalid` only in a row without valid pixels; its sums
        // are then those of no bin.
        let known = c != invalid;
        let at_c = known & (2 * b < t) & (2 * (b + a) >= t);
        let at_lower = known & (2 * (b - lw) < t) & (2 * b >= t);
        let at_upper = known & (2 * (b + a) < t) & (2 * (b + a + up) >= t);
        let pick = if at_c {
            c
        } else if at_lower {
            c.wrapping_sub(1)
        } else {
            c.wrapping_add(1)
        };
        let pick = if at_c | at_lower | at_upper {
            pick
        } else {
            HARD
        };
        *m = if (t == 0) | stay { own } else { pick };
    }
    for ((d, &m), &b) in row.iter_mut().zip(medians.iter()).zip(own) {
        // `HARD` and `invalid` are above every valid bin.
        let take = (m != b) & (m < invalid);
        *d = if take { lo + f32::from(m) } else { *d };
    }
    // The rest, in chunks as above (a pixel of overlapping chunks may be
    // searched twice, to the same result).
    for x in covering(medians, n, |&m| m == HARD) {
        let at = x..x + n;
        let mut found = [0u16; LANES];
        if n == LANES {
            found = search::<LANES>(job, centre + x, &mut scratch.samples);
        } else {
            found[..1].copy_from_slice(&search::<1>(job, centre + x, &mut scratch.samples));
        }
        for (((d, &m), &b), &f) in row[at.clone()]
            .iter_mut()
            .zip(&medians[at.clone()])
            .zip(&own[at])
            .zip(&found)
        {
            // `HARD` pixels have weight (the others do not search).
            if (m == HARD) & (f != b) {
                *d = lo + f32::from(f);
            }
        }
    }
}

/// The starts of chunks of `n` pixels of `row` (at least `n` long) that
/// cover every pixel where `flagged` holds, as few as can: each starts at
/// the first flagged pixel not yet covered (moved back to end with the
/// row at the latest). Flagged pixels cluster (at holes' borders, at
/// disparity edges), so that this takes fewer chunks than a fixed grid.
fn covering<'a, T>(
    row: &'a [T],
    n: usize,
    flagged: impl Fn(&T) -> bool + 'a,
) -> impl Iterator<Item = usize> + 'a {
    let mut next = 0;
    std::iter::from_fn(move || {
        let x = next + row.get(next..)?.iter().position(&flagged)?;
        let start = x.min(row.len() - n);
        next = start + n;
        Some(start)
    })
}

/// Per pixel, the weights of the valid samples in all, below `c`, in `c`,
/// in `c − 1` and in `c + 1` for the candidate bin `c` (apart, so that
/// the decisions over a row vectorise).
#[derive(Default)]
struct Sums {
    total: Vec<u16>,
    below: Vec<u16>,
    at: Vec<u16>,
    lower: Vec<u16>,
    upper: Vec<u16>,
}

/// The [`Sums`] of the `N` pixels from padded index `p` on, with candidate
/// bins `candidates`, into `sums` (slices of `N`), in `u16` lanes kept in
/// registers for the whole window: branch-free selects on bins relative
/// to `c`, as `i16`.
#[inline(always)]
fn settle<const N: usize>(job: &MapJob, p: usize, candidates: &[u16], sums: [&mut [u16]; 5]) {
    let guide = job.guide;
    let (invalid, reach, shift) = (job.invalid, guide.p.color_reach, guide.shift);
    let c: &[u16; N] = candidates.try_into().expect("N candidates");
    let colours = |q: usize| -> [&[u8; N]; 3] {
        guide.planes.each_ref().map(|plane| {
            let lanes: &[u8; N] = plane[q..q + N].try_into().expect("N colours");
            lanes
        })
    };
    let centre = colours(p);
    let (mut total, mut below, mut at) = ([0u16; N], [0u16; N], [0u16; N]);
    let (mut lower, mut upper) = ([0u16; N], [0u16; N]);
    for &offset in &guide.offsets {
        let q = p.wrapping_add_signed(offset);
        let bins: &[u16; N] = job.bin_pad[q..q + N].try_into().expect("N bins");
        let [r, g, b] = colours(q);
        for l in 0..N {
            let sample = [r[l], g[l], b[l]];
            let w = weight(
                [centre[0][l], centre[1][l], centre[2][l]],
                sample,
                reach,
                shift,
            );
            let w = if bins[l] == invalid { 0 } else { w };
            // Bins and `invalid` are below 2¹⁵ (checked by the caller).
            let rel = (bins[l] as i16).wrapping_sub(c[l] as i16);
            total[l] += w;
            below[l] += if rel < 0 { w } else { 0 };
            at[l] += if rel == 0 { w } else { 0 };
            lower[l] += if rel == -1 { w } else { 0 };
            upper[l] += if rel == 1 { w } else { 0 };
        }
    }
    for (out, lanes) in sums.into_iter().zip([total, below, at, lower, upper]) {
        out.copy_from_slice(&lanes);
    }
}

/// The weighted median bins of the windows of the `N` pixels from padded
/// index `p` on, by the definition: the smallest bin `b` where twice the
/// weight of the valid samples at or below `b` reaches the window's total
/// (no bin below `b` can: it is the first bin, ascending, where the running
/// sum of a histogram reaches half the total). Found bit by bit from the
/// top in `u16` lanes, as the number of bins that fall short: each step
/// sums the window's weights at or below a bin per lane, over the weights
/// and bins listed once in `samples` (scratch). A pixel without weight
/// gets some bin.
#[inline(always)]
fn search<const N: usize>(job: &MapJob, p: usize, samples: &mut Vec<Sample>) -> [u16; N] {
    let guide = job.guide;
    let (invalid, reach, shift) = (job.invalid, guide.p.color_reach, guide.shift);
    let colours = |q: usize| -> [&[u8; N]; 3] {
        guide.planes.each_ref().map(|plane| {
            let lanes: &[u8; N] = plane[q..q + N].try_into().expect("N colours");
            lanes
        })
    };
    let centre = colours(p);
    let mut total = [0u16; N];
    samples.clear();
    for &offset in &guide.offsets {
        let q = p.wrapping_add_signed(offset);
        let bins: &[u16; N] = job.bin_pad[q..q + N].try_into().expect("N bins");
        let [r, g, b] = colours(q);
        let mut sample: Sample = [[0; LANES]; 2];
        for l in 0..N {
            let w = weight(
                [centre[0][l], centre[1][l], centre[2][l]],
                [r[l], g[l], b[l]],
                reach,
                shift,
            );
            let w = if bins[l] == invalid { 0 } else { w };
            sample[0][l] = bins[l];
            sample[1][l] = w;
            total[l] += w;
        }
        samples.push(sample);
    }
    // `2 · sum ≥ total` without overflow; the valid bins are `0..invalid`,
    // below 2¹⁵ (checked by the caller), so their bits are the low `bits`.
    let half = total.map(|t| t - t / 2);
    let bits = u16::BITS - (invalid.max(1) - 1).leading_zeros();
    let mut short = [0u16; N];
    for k in (0..bits).rev() {
        let step = 1u16 << k;
        // Is the sum at or below `short + step − 1` short of half?
        let top = short.map(|s| (s + step - 1) as i16);
        let mut sum = [0u16; N];
        // By index, with a bounds check LLVM keeps: without it, its loop
        // vectoriser takes this loop across samples (gathering each lane's
        // bins and weights) instead of leaving the lanes to one vector
        // each (checked in the disassembly; a Cones frame with the default
        // WTA then took 14.9 ms CPU on one thread, against 11.0 ms).
        #[allow(clippy::needless_range_loop)]
        for j in 0..guide.offsets.len() {
            let [bins, weights] = &samples[j];
            for l in 0..N {
                // A lane mask, as one vector comparison.
                let below = u16::from(bins[l] as i16 <= top[l]).wrapping_neg();
                sum[l] += weights[l] & below;
            }
        }
        for l in 0..N {
            short[l] += if sum[l] < half[l] { step } else { 0 };
        }
    }
    short
}

/// The bins and weights of one sample of a chunk's windows, a lane each
/// (the first `N` of [`search`]).
type Sample = [[u16; LANES]; 2];

/// Per-row buffers of [`WeightedMedianGuide::filter`].
#[derive(Default)]
struct RowScratch {
    /// The bins tested for the row's pixels.
    candidates: Vec<u16>,
    /// The [`settle`] sums of the row's pixels.
    sums: Sums,
    /// The bin each pixel of the row takes, as its sums settle it.
    medians: Vec<u16>,
    /// Whether each pixel of the row stays as it is.
    stay: Vec<bool>,
    /// Whether each column from −1 to `w` has a hole in the rows `y − 1`,
    /// `y`, `y + 1`.
    near_hole: Vec<bool>,
    /// For [`search`], the bins and weights of a chunk's samples.
    samples: Vec<Sample>,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_disparity_edge_snaps_to_the_colour_edge() {
        // Colour edge at x = 10; the disparity edge is fattened to x = 12.
        let guide = RgbImage::from_fn(
            24,
            8,
            |x, _| if x < 10 { [200, 40, 40] } else { [20, 20, 90] },
        );
        let map = DisparityMap::from_fn(24, 8, |x, _| if x < 12 { 9.0 } else { 3.0 });
        let p = WeightedMedian {
            radius: 4,
            color_reach: 30,
            step: 1,
        };
        let out = weighted_median(&map, &guide, &p);
        for x in 0..24 {
            assert_eq!(out.get(x, 4), if x < 10 { 9.0 } else { 3.0 }, "x = {x}");
        }
    }

    #[test]
    fn holes_take_their_neighbours_and_subpixel_values_stay() {
        let guide = RgbImage::new(9, 9, [50, 50, 50]);
        let mut map = DisparityMap::from_fn(9, 9, |x, _| if x % 2 == 0 { 4.25 } else { 3.9 });
        map.set(4, 4, f32::INFINITY);
        let out = weighted_median(&map, &guide, &WeightedMedian::DEFAULT);
        assert!(out
            .as_slice()
            .iter()
            .all(|&d| d == 4.0 || d == 4.25 || d == 3.9));
        assert_eq!(out.get(4, 4), 4.0);
        assert_eq!(out.get(2, 2), 4.25);
        let empty = DisparityMap::new(5, 5, f32::INFINITY);
        assert_eq!(
            weighted_median(
                &empty,
                &RgbImage::new(5, 5, [0; 3]),
                &WeightedMedian::DEFAULT
            ),
            empty
        );
    }

    /// The definition, pixel by pixel, in `u32`; if `borders`, only valid
    /// pixels with an invalid 8-neighbour take the median.
    fn naive(
        map: &DisparityMap,
        guide: &RgbImage,
        p: &WeightedMedian,
        borders: bool,
    ) -> DisparityMap {
        let (w, h) = map.dims();
        let finite: Vec<f32> = map
            .as_slice()
            .iter()
            .copied()
            .filter(|d| d.is_finite())
            .collect();
        let Some(lo) = finite.iter().map(|d| d.round()).reduce(f32::min) else {
            return map.clone();
        };
        let r = p.radius as isize;
        let at = |x: isize, y: isize| {
            (
                x.clamp(0, w as isize - 1) as usize,
                y.clamp(0, h as isize - 1) as usize,
            )
        };
        DisparityMap::from_fn(w, h, |x, y| {
            let next_to_hole = (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (qx, qy) = at(x as isize + dx, y as isize + dy);
                    !map.get(qx, qy).is_finite()
                })
            });
            if borders && !(map.get(x, y).is_finite() && next_to_hole) {
                return map.get(x, y);
            }
            let c = guide.get(x, y);
            let mut hist = vec![0u32; 70_000];
            let mut used = Vec::new();
            let n = (2 * p.radius / p.step + 1).pow(2);
            let peak = u32::from(p.color_reach).pow(2);
            let shift = (0..).find(|&s| n as u32 * (peak >> s) <= 65535).unwrap();
            for dy in (-r..=r).step_by(p.step) {
                for dx in (-r..=r).step_by(p.step) {
                    let (qx, qy) = at(x as isize + dx, y as isize + dy);
                    let d = map.get(qx, qy);
                    if !d.is_finite() {
                        continue;
                    }
                    let q = guide.get(qx, qy);
                    let diff: u32 = (0..3).map(|k| c[k].abs_diff(q[k]) as u32).sum();
                    let wt = u32::from(p.color_reach).saturating_sub(diff).pow(2) >> shift;
                    if wt == 0 {
                        continue;
                    }
                    let b = (d.round() - lo) as usize;
                    hist[b] += wt;
                    used.push(b);
                }
            }
            let own = map.get(x, y);
            let (Some(&a), Some(&b)) = (used.iter().min(), used.iter().max()) else {
                return own;
            };
            let total: u32 = hist[a..=b].iter().sum();
            let mut acc = 0;
            let median = (a..=b)
                .find(|&k| {
                    acc += hist[k];
                    2 * acc >= total
                })
                .unwrap_or(b);
            if own.is_finite() && (own.round() - lo) as usize == median {
                own
            } else {
                lo + median as f32
            }
        })
    }

    /// A xorshift generator seeded with `seed`.
    fn xorshift(seed: u64) -> impl FnMut() -> u64 {
        let mut s = seed | 1;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    }

    /// Both paths (AVX2 where the CPU has it, and the portable one) give
    /// the definition's map, bit for bit, with holes filled and kept.
    fn as_defined(
        map: &DisparityMap,
        guide: &RgbImage,
        p: &WeightedMedian,
    ) -> Result<(), proptest::test_runner::TestCaseError> {
        let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let want = bits(&naive(map, guide, p, false));
        proptest::prop_assert_eq!(bits(&weighted_median(map, guide, p)), want.clone());
        let mut portable = WeightedMedianGuide::with_avx2(guide, p, false);
        let mut out = DisparityMap::default();
        portable.filter(map, &mut out);
        proptest::prop_assert_eq!(bits(&out), want);
        let want = bits(&naive(map, guide, p, true));
        WeightedMedianGuide::new(guide, p).filter_borders(map, &mut out);
        proptest::prop_assert_eq!(bits(&out), want.clone());
        portable.filter_borders(map, &mut out);
        proptest::prop_assert_eq!(bits(&out), want);
        Ok(())
    }

    proptest::proptest! {
        #[test]
        /// Both kernels, as the definition computes it.
        fn equals_the_definition(
            w in 1usize..30, h in 1usize..30, seed in proptest::prelude::any::<u64>(),
            radius in 1usize..6, step in 1usize..4, reach in 1u8..=255,
        ) {
            let mut next = xorshift(seed);
            let guide = RgbImage::from_fn(w, h, |_, _| {
                let v = next();
                [v as u8 & 0xF0, (v >> 8) as u8, (v >> 16) as u8 & 0xC0]
            });
            let map = DisparityMap::from_fn(w, h, |x, y| match (x * 7 + y * 13 + seed as usize) % 11 {
                0 => f32::INFINITY,
                k => 3.0 + (k % 4) as f32 + if x > w / 2 { 0.25 } else { 0.0 },
            });
            let p = WeightedMedian { radius, color_reach: reach, step: step.min(radius) };
            as_defined(&map, &guide, &p)?;
        }

        #[test]
        /// Smooth colours and disparities (most pixels settled by the fast
        /// test on `c`, `c − 1` or `c + 1`), with steps of either and holes
        /// in runs, over ranges of more than 64 bins, the default window
        /// and large ones (961 samples, shifted weights): as defined.
        fn equals_the_definition_on_smooth_maps(
            w in 1usize..48, h in 1usize..40, seed in proptest::prelude::any::<u64>(),
            radius in 1usize..16, step in 1usize..5, reach in 1u8..=255, span in 1f32..200.0,
        ) {
            let mut next = xorshift(seed);
            let edge = (seed % 29) as usize;
            let guide = RgbImage::from_fn(w, h, |x, y| {
                let n = (next() % 9) as u8;
                if x < edge { [40 + n, 90 + (y as u8 & 15), 30] } else { [200 - n, 60, 120 + n] }
            });
            let hole = |x: usize, y: usize| (x / 3 + y * 5 + seed as usize) % 7 == 0;
            let map = DisparityMap::from_fn(w, h, |x, y| {
                if hole(x, y) {
                    return f32::INFINITY;
                }
                let slant = span * (x + y) as f32 / (w + h) as f32;
                let jitter = (next() % 3) as f32 - 1.0;
                let base = if x + 2 < edge { 2.0 * span } else { 0.0 };
                base + slant.round() + jitter + if (x ^ y) & 4 == 0 { 0.5 } else { 0.0 }
            });
            let p = WeightedMedian { radius, color_reach: reach, step: step.min(radius) };
            as_defined(&map, &guide, &p)?;
        }
    }

    #[test]
    fn a_rebuilt_guide_filters_as_a_new_one() {
        let view = |w: usize, h: usize, seed: u64| {
            let mut next = xorshift(seed);
            RgbImage::from_fn(w, h, |_, _| {
                let v = next();
                [v as u8, (v >> 8) as u8 & 0xE0, (v >> 16) as u8]
            })
        };
        let map = DisparityMap::from_fn(37, 21, |x, y| match (x * 5 + y * 3) % 13 {
            0 => f32::INFINITY,
            k => (k % 5) as f32 + if y > 10 { 0.5 } else { 0.0 },
        });
        let guide = view(37, 21, 9);
        let p = WeightedMedian::DEFAULT;
        let (mut fresh, mut reused) = (DisparityMap::default(), DisparityMap::default());
        WeightedMedianGuide::new(&guide, &p).filter(&map, &mut fresh);
        // Built first for another size and other parameters, and used.
        let other = WeightedMedian {
            radius: 3,
            color_reach: 9,
            step: 1,
        };
        let mut g = WeightedMedianGuide::new(&view(50, 40, 2), &other);
        g.filter(&DisparityMap::new(50, 40, 3.0), &mut reused);
        g.rebuild(&guide, &p);
        g.filter(&map, &mut reused);
        assert_eq!(reused, fresh);
        assert_eq!(fresh, naive(&map, &guide, &p, false));
    }

    #[test]
    fn a_window_of_weights_fits_sixteen_bits() {
        for (reach, n) in [(150, 25), (255, 961), (255, 1), (1, 961), (40, 9)] {
            let s = weight_shift(reach, n);
            let peak = weight([0; 3], [0; 3], reach, s);
            assert_eq!(u32::from(peak), u32::from(reach).pow(2) >> s);
            assert!(n * usize::from(peak) <= 65535 && peak >= 1, "{reach} {n}");
            // The smallest such shift.
            assert!(s == 0 || n as u32 * (u32::from(reach).pow(2) >> (s - 1)) > 65535);
        }
        // Saturating colour differences: beyond the reach, no weight.
        assert_eq!(weight([255; 3], [0; 3], 255, 0), 0);
        assert_eq!(weight([10, 0, 0], [0, 0, 0], 12, 0), 4);
    }

    #[test]
    fn bad_parameters_are_errors() {
        let ok = WeightedMedian::DEFAULT;
        assert_eq!(ok.validate(), Ok(()));
        for bad in [
            WeightedMedian { radius: 0, ..ok },
            WeightedMedian { radius: 16, ..ok },
            WeightedMedian {
                color_reach: 0,
                ..ok
            },
            WeightedMedian { step: 0, ..ok },
            WeightedMedian { step: 11, ..ok },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
