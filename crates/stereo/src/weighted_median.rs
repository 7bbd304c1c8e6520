//! Colour-weighted median refinement (a joint bilateral median, as in
//! Ma et al., "Constant time weighted median filtering for stereo
//! matching and beyond", ICCV 2013). A vectorised integer test settles
//! most pixels exactly; a histogram of the definition's `f32` weights
//! settles the rest (see [`WeightedMedianGuide::filter`]).
//!
//! Each pixel takes the weighted median of the valid disparities of a
//! window, a neighbour `q` of the centre `p` weighing
//! `exp(−Σ_k |I_k(p) − I_k(q)| / σ)` by their colour difference in the
//! left (reference) view. Neighbours of another colour, likely on another
//! surface, barely count, so disparity edges follow colour edges: this
//! undoes much of the edge fattening of window matching and cleans the
//! streaks of the hole fill. It runs after any matcher.
//!
//! Disparities are binned to whole pixels; a pixel whose own disparity
//! lies in the median bin keeps it (and so its subpixel part), any other
//! takes the bin's whole value. The window is sampled every `step`
//! pixels in both directions, which keeps its reach at a fraction of the
//! cost.

use rayon::prelude::*;
use stereolink_image::{DisparityMap, RgbImage};

use crate::StereoError;

/// Parameters of [`weighted_median`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct WeightedMedian {
    /// Window radius: the window spans `2·radius + 1` pixels each way (1..=15).
    pub radius: usize,
    /// Colour scale σ of the weights, in summed RGB levels (> 0).
    pub sigma_color: f32,
    /// Sampling step inside the window (1 = every pixel, at most `radius`).
    pub step: usize,
}

impl WeightedMedian {
    /// The measured default after WTA: a 17×17 window sampled every fourth
    /// pixel (25 samples), σ = 50. Bad > 1 px on the 20 Middlebury scenes
    /// 27.25 % on average (σ = 20 / 25 / 30 / 40 / 60 / 80: 27.51 / 27.40 /
    /// 27.33 / 27.27 / 27.26 / 27.30 %), 3.60 / 1.03 / 15.71 / 7.25 % on
    /// Tsukuba / Venus / Teddy / Cones. Every second pixel (81 samples,
    /// σ = 30) gives 27.02 % at about twice the time; radius 9 at step 3
    /// 27.27 %, radius 10 at step 5 27.88 %, radius 12 at step 6 28.75 %,
    /// radius 7 at step 3 27.87 % (σ = 30). Earlier, at step 2, σ = 30 beat
    /// σ = 14 and 20 and radius 8 beat 7 and 10; radius 7 at step 1 (225
    /// samples) is better on the 2014 scenes but misses the Teddy target
    /// (16.53 %). (These figures are from when the first pass filled
    /// holes too; with it on valid pixels only, the default gives 26.93 %
    /// and 3.60 / 0.87 / 15.35 / 6.85 %.)
    pub const DEFAULT: WeightedMedian = WeightedMedian {
        radius: 8,
        sigma_color: 50.0,
        step: 4,
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
        if !(self.sigma_color > 0.0 && self.sigma_color.is_finite()) {
            return bad(format!(
                "weighted median colour sigma {} must be positive",
                self.sigma_color
            ));
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

/// Largest summed RGB difference.
const MAX_DIFF: usize = 3 * 255;

/// The weight `exp(−diff / σ)` of every summed colour difference, indexed
/// by `diff & WEIGHT_INDEX` (a power of two: the index needs no bounds
/// check; the entries past [`MAX_DIFF`] are never read).
type WeightTable = [f32; WEIGHT_INDEX + 1];

/// The index mask of a [`WeightTable`].
const WEIGHT_INDEX: usize = 1023;
const _: () = assert!(MAX_DIFF <= WEIGHT_INDEX);

/// The weighted median of `map` guided by `guide` (same size; checked by
/// the caller). Invalid pixels take a value when some valid neighbour has
/// weight; pixels without any stay invalid. A map whose values span 65535
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
    /// side, so that the pairs at one offset along a row are two slices.
    planes: [Vec<u8>; 3],
    table: Box<WeightTable>,
    /// The window's samples in order.
    samples: Vec<Sample>,
    /// The weights of every pixel's samples.
    weights: Weights,
    /// Whether the kernels run with AVX2 (same results either way).
    avx2: bool,
    /// The bins of the map being filtered, padded as the colour planes.
    bin_pad: Vec<u16>,
}

/// One sample of the window, for the pixel at padded index `P` (the grid
/// border-replicated by `radius` on every side): its position is
/// `P + offset`, and its weights are at `P + shift` in plane `plane` of
/// [`Weights`].
#[derive(Clone, Copy, Debug)]
struct Sample {
    offset: isize,
    plane: usize,
    shift: isize,
}

/// The weights `w` of the guide's pairs of pixels as integers `q`, the
/// table's `Q·w` rounded, for the fast test, computed once per guide (the
/// refinement filters twice with one guide). `Q` is `65535 / n` for `n`
/// samples (2621 for the default 25), so that a window's sum fits a
/// `u16`.
///
/// The weight of a pair of pixels does not depend on which is the centre,
/// so the offsets `o` and `−o` share a plane: plane `o` holds, at padded
/// index `P`, the weight of `P` and `P + o`, and the sample `−o` of the
/// pixel `P` reads it at `P − o` (the padded colours replicate the border
/// as the definition clamps its samples). A symmetric window needs about
/// half as many planes as samples.
struct Weights {
    quantized: Vec<Vec<u16>>,
    /// A bound on `|Σ q − Q·Σ w|` over any set of a window's samples, in
    /// units of `q`: `n` times the largest error of one weight, rounded up.
    slack: u32,
}

impl WeightedMedianGuide {
    /// The weights of the guide's pairs for `p`.
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
            table: Box::new([0.0; WEIGHT_INDEX + 1]),
            samples: Vec::new(),
            weights: Weights {
                quantized: Vec::new(),
                slack: 0,
            },
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
        let table = &mut self.table;
        for (i, w) in table.iter_mut().enumerate() {
            *w = (-(i as f32) / p.sigma_color).exp();
        }
        let (r, step) = (p.radius as isize, p.step);
        let wp = dims.0 as isize + 2 * r;
        let offsets: Vec<(isize, isize)> = (-r..=r)
            .step_by(step)
            .flat_map(|dy| (-r..=r).step_by(step).map(move |dx| (dx, dy)))
            .collect();
        // A plane per offset whose mirror has none yet.
        let mut computed: Vec<(isize, isize)> = Vec::new();
        let samples = offsets
            .iter()
            .map(|&(dx, dy)| {
                let offset = dy * wp + dx;
                if let Some(j) = computed.iter().position(|&o| o == (-dx, -dy)) {
                    Sample {
                        offset,
                        plane: j,
                        shift: offset,
                    }
                } else {
                    computed.push((dx, dy));
                    Sample {
                        offset,
                        plane: computed.len() - 1,
                        shift: 0,
                    }
                }
            })
            .collect::<Vec<_>>();
        let n = samples.len();
        let scale = (65535 / n) as f32;
        // The largest error of one quantized weight, over every difference.
        let error = table[..=MAX_DIFF]
            .iter()
            .map(|&w| (f64::from(quantize(w, scale)) - f64::from(scale) * f64::from(w)).abs())
            .fold(0f64, f64::max);
        // At most 2¹⁶ + 1 (beyond, nothing would pass the test anyway).
        let slack = (n as f64 * error).ceil().min(65536.0) as u32 + 1;
        let padded_dims = (dims.0 + 2 * p.radius, dims.1 + 2 * p.radius);
        let qtable: Box<[u16; WEIGHT_INDEX + 1]> =
            Box::new(std::array::from_fn(|d| quantize(table[d], scale)));
        let quantized = &mut self.weights.quantized;
        quantized.resize_with(computed.len(), Vec::new);
        let (planes, avx2) = (&self.planes, self.avx2);
        quantized.par_iter_mut().zip(&computed).for_each(|(q, &o)| {
            with_avx2(avx2, || weight_plane(q, planes, padded_dims, o, &qtable))
        });
        self.weights.slack = slack;
        self.samples = samples;
        (self.p, self.dims) = (*p, dims);
    }

    /// The weighted median of `map` (see [`weighted_median`]).
    ///
    /// Disparities are binned to whole pixels. Most pixels need no
    /// histogram: one vectorised pass over a row sums, per pixel, the
    /// quantized weights ([`Weights`]) of its valid samples below, in and
    /// at any bin for a candidate bin `c` (the pixel's own, or for an
    /// invalid pixel its left neighbour's), and in the bins `c − 1` and
    /// `c + 1`. That gives the same sums for `c ± 1`; where one of the
    /// three is the median by a margin that covers the quantization (see
    /// [`keeps_candidate`]), the pixel takes it (keeping its own value if
    /// it is its own bin), exactly as the histogram would decide. A window
    /// without valid samples leaves the pixel as it is. Only the rest
    /// (pixels at a disparity edge, holes unlike their left neighbour, and
    /// near ties) go through the definition ([`exact_medians`]).
    ///
    /// The result goes into `out` (resized, storage reused).
    ///
    /// # Panics
    /// If `map` is not the guide's size.
    pub fn filter(&mut self, map: &DisparityMap, out: &mut DisparityMap) {
        self.filter_with(map, out, false)
    }

    /// As [`Self::filter`], but only valid pixels take the median: invalid
    /// ones stay invalid (for a hole fill that follows) and need no work.
    ///
    /// # Panics
    /// If `map` is not the guide's size.
    pub fn filter_valid(&mut self, map: &DisparityMap, out: &mut DisparityMap) {
        self.filter_with(map, out, true)
    }

    /// [`Self::filter`], or [`Self::filter_valid`] if `keep_holes`.
    fn filter_with(&mut self, map: &DisparityMap, out: &mut DisparityMap, keep_holes: bool) {
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
        if bins >= u16::MAX as usize {
            // Not a disparity map of any image this crate matches: left as is.
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
            keep_holes,
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

/// The integer weight `q ≈ scale · w` of a weight `w` in `[0, 1]`, rounded
/// (the whole number as the low mantissa bits of `x + 2²³`, [`MAGIC`]: a
/// float-to-integer cast would not vectorise).
#[inline(always)]
fn quantize(w: f32, scale: f32) -> u16 {
    ((w * scale + 0.5).floor() + MAGIC).to_bits() as u16
}

/// Writes into `quantized` the quantized weights of the pairs `P`, `P + o`
/// over the padded grid (`(wp, hp)`; 0 where `P + o` is off it, never
/// read).
#[inline(always)]
fn weight_plane(
    quantized: &mut Vec<u16>,
    planes: &[Vec<u8>; 3],
    (wp, hp): (usize, usize),
    (dx, dy): (isize, isize),
    table: &[u16; WEIGHT_INDEX + 1],
) {
    // Written once, row by row, zeros included (no separate clearing pass).
    quantized.clear();
    quantized.reserve(wp * hp);
    let mut diffs = Vec::new();
    let xs = (-dx).max(0) as usize..(wp as isize - dx.max(0)).max(0) as usize;
    for y in 0..hp {
        let yo = y as isize + dy;
        let row_end = quantized.len() + wp;
        if yo < 0 || yo >= hp as isize || xs.is_empty() {
            quantized.resize(row_end, 0);
            continue;
        }
        let n = xs.len();
        let at = y * wp + xs.start;
        let to = (yo * wp as isize + xs.start as isize + dx) as usize;
        let [p0, p1, p2] = planes.each_ref().map(|p| (&p[at..at + n], &p[to..to + n]));
        let pairs =
            p0.0.iter()
                .zip(p0.1)
                .zip(p1.0.iter().zip(p1.1))
                .zip(p2.0.iter().zip(p2.1));
        // The differences vectorise; the look-ups are one load each.
        diffs.clear();
        diffs.extend(pairs.map(|((a, b), c)| {
            u16::from(a.0.abs_diff(*a.1))
                + u16::from(b.0.abs_diff(*b.1))
                + u16::from(c.0.abs_diff(*c.1))
        }));
        quantized.resize(quantized.len() + xs.start, 0);
        quantized.extend(diffs.iter().map(|&d| table[usize::from(d) & WEIGHT_INDEX]));
        quantized.resize(row_end, 0);
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
    /// Whether invalid pixels stay invalid ([`WeightedMedianGuide::filter_valid`]).
    keep_holes: bool,
}

/// [`filter_row`] compiled for AVX2 (a function of its own: LLVM does not
/// always inline a closure this large into [`with_avx2`]'s).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn filter_row_avx2(job: &MapJob, y: usize, row: &mut [f32], scratch: &mut RowScratch) {
    filter_row(job, y, row, scratch)
}

/// [`WeightedMedianGuide::filter`] for row `y` of the output, `row` (a
/// copy of the map's).
#[inline(always)]
fn filter_row(job: &MapJob, y: usize, row: &mut [f32], scratch: &mut RowScratch) {
    let guide = job.guide;
    let (w, r) = (row.len(), guide.p.radius);
    let wp = w + 2 * r;
    let (lo, invalid, keep_holes) = (job.lo, job.invalid, job.keep_holes);
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
    let sums = &mut scratch.sums;
    sums.clear(w);
    let weights = &guide.weights;
    for sample in &guide.samples {
        let q = &weights.quantized[sample.plane][centre.wrapping_add_signed(sample.shift)..][..w];
        let bins = &job.bin_pad[centre.wrapping_add_signed(sample.offset)..][..w];
        candidate_sums(q, bins, candidates, invalid, sums);
    }
    // Which of `c`, `c − 1`, `c + 1` is the median for certain, for the
    // whole row at once (branch-free selects, so that it vectorises); a
    // window without valid samples keeps the pixel's bin, as does a hole
    // with `keep_holes`. The pixels that none settles (`HARD`) are listed.
    const HARD: u16 = u16::MAX;
    let slack = weights.slack;
    let medians = &mut scratch.medians;
    medians.resize(w, 0);
    let s = &*sums;
    let lanes = (s.below.iter().zip(&s.at).zip(&s.total))
        .zip(s.at_lower.iter().zip(&s.at_upper).zip(&s.count))
        .zip(candidates.iter().zip(own));
    for (m, ((((&below, &at), &total), ((&at_lower, &at_upper), &count)), (&c, &b))) in
        medians.iter_mut().zip(lanes)
    {
        // `c` is `invalid` only in a row without valid pixels.
        let known = c != invalid;
        let at_c = known & keeps_candidate(below, at, total, slack);
        let lower = below.wrapping_sub(at_lower);
        let at_lower = known & (c > 0) & keeps_candidate(lower, at_lower, total, slack);
        let upper = below.wrapping_add(at);
        let at_upper =
            (c.wrapping_add(1) < invalid) & keeps_candidate(upper, at_upper, total, slack);
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
        let keep = (count == 0) | (keep_holes & (b == invalid));
        *m = if keep { b } else { pick };
    }
    for ((d, &m), &b) in row.iter_mut().zip(medians.iter()).zip(own) {
        // `HARD` and `invalid` are above every valid bin.
        let take = (m != b) & (m < invalid);
        *d = if take { lo + f32::from(m) } else { *d };
    }
    let hard = &mut scratch.hard;
    hard.resize(w, 0);
    let mut n = 0;
    for (x, &m) in medians.iter().enumerate() {
        hard[n] = x;
        n += usize::from(m == HARD);
    }
    hard.truncate(n);
    if !hard.is_empty() && scratch.histogram.hist.len() != GROUP * (usize::from(invalid) + 1) {
        scratch.histogram.reset(invalid);
    }
    for group in hard.chunks(GROUP) {
        let ps: [usize; GROUP] =
            std::array::from_fn(|k| centre + group.get(k).copied().unwrap_or(0));
        let medians = exact_medians(job, &ps[..group.len()], &mut scratch.histogram);
        for (&x, median) in group.iter().zip(medians) {
            if let Some(m) = median.filter(|&m| m != own[x]) {
                row[x] = lo + f32::from(m);
            }
        }
    }
}

/// Per pixel of a row, the quantized weights of its valid samples below,
/// in and at any bin for its candidate bin `c`, in the bins `c − 1` and
/// `c + 1`, and the number of valid samples (apart, so that the additions
/// vectorise).
#[derive(Default)]
struct Sums {
    below: Vec<u16>,
    at: Vec<u16>,
    total: Vec<u16>,
    at_lower: Vec<u16>,
    at_upper: Vec<u16>,
    count: Vec<u16>,
}

impl Sums {
    fn clear(&mut self, w: usize) {
        for v in [
            &mut self.below,
            &mut self.at,
            &mut self.total,
            &mut self.at_lower,
            &mut self.at_upper,
            &mut self.count,
        ] {
            v.clear();
            v.resize(w, 0);
        }
    }
}

/// Adds the quantized weights `q` of one sample offset to the [`Sums`] of a
/// row's pixels. Branch-free selects on `u16` lanes, so that it vectorises.
#[inline(always)]
fn candidate_sums(q: &[u16], bins: &[u16], candidates: &[u16], invalid: u16, s: &mut Sums) {
    let n = s.below.len();
    let (q, bins, candidates) = (&q[..n], &bins[..n], &candidates[..n]);
    let (at, total) = (&mut s.at[..n], &mut s.total[..n]);
    let (at_lower, at_upper, count) = (
        &mut s.at_lower[..n],
        &mut s.at_upper[..n],
        &mut s.count[..n],
    );
    for (x, below) in s.below.iter_mut().enumerate() {
        let (q, b, c) = (q[x], bins[x], candidates[x]);
        let valid = b != invalid;
        *below = below.wrapping_add(if b < c { q } else { 0 });
        at[x] = at[x].wrapping_add(if b == c { q } else { 0 });
        total[x] = total[x].wrapping_add(if valid { q } else { 0 });
        at_lower[x] = at_lower[x].wrapping_add(if b.wrapping_add(1) == c { q } else { 0 });
        at_upper[x] = at_upper[x].wrapping_add(if b == c.wrapping_add(1) { q } else { 0 });
        count[x] = count[x].wrapping_add(u16::from(valid));
    }
}

/// Whether the candidate bin is the window's weighted median for certain,
/// given the quantized weights (`q ≈ Q·w`, each sum within `slack` of `Q`
/// times the exact one) of the valid samples below and in it and of all
/// valid samples.
///
/// The definition sums `f32` weights, a histogram bin per sample in
/// sample order and then the bins in order; each of its sums is within
/// `(n − 1)·2⁻²⁴ < 2⁻¹⁴` (for `n` ≤ 961 samples) of the exact one
/// (Higham, "Accuracy and Stability of Numerical Algorithms", §4.2). With
/// `B`, `A`, `T` the exact sums below, in and in all bins (times `Q`), the
/// candidate is the median when the sum below is under half the total and
/// the sum up to it at least half:
/// - `2·below + 3·slack + total/1024 < total` gives
///   `2·(B + slack)·(1 + 2⁻¹²) < T`, so `B·(1 + 2⁻¹⁴) < T·(1 − 2⁻¹⁴)/2`;
/// - `2·(below + at) > total + 4·slack + total/1024` gives
///   `2·(B + A)·(1 − 2⁻¹⁴) ≥ T·(1 + 2⁻¹⁴)` the same way.
///
/// In `u32`: `total`, `below + at` ≤ 65535 and `slack` ≤ 2¹⁶ + 1, so no term
/// reaches 2³².
#[inline(always)]
fn keeps_candidate(below: u16, at: u16, total: u16, slack: u32) -> bool {
    let (b, a, t) = (u32::from(below), u32::from(at), u32::from(total));
    (1024 * (2 * b + 3 * slack) + t < 1024 * t) & (2048 * (b + a) > 1024 * (t + 4 * slack) + t)
}

/// The weighted median bins of the windows of the pixels at padded
/// indices `ps` (at most [`GROUP`]), by the definition: the `f32` weights
/// of the valid samples summed per bin in sample order, then the bins in
/// ascending order, and the first bin where the running sum reaches half
/// the total; `None` without valid samples.
///
/// Each pixel's bins are a dense histogram (`hist`, zero on entry and on
/// return), with a bit per bin that occurs (in a register when they span
/// less than 64, else in `occurs`, zero on entry and return), so that only
/// those are summed: an empty bin adds `+0.0`, which changes no sum. The
/// running sums are kept (`running`); the last is the total, summed the
/// same way. The pixels' histograms are filled side by side, so that the
/// additions to one bin (often sample after sample) are not one chain of
/// dependent stores and loads.
#[inline(always)]
fn exact_medians(job: &MapJob, ps: &[usize], h: &mut Histogram) -> [Option<u16>; GROUP] {
    let guide = job.guide;
    let invalid = job.invalid;
    let stride = usize::from(invalid) + 1;
    let n = guide.samples.len();
    h.bins.resize(GROUP * n, 0);
    let [r, g, b] = &guide.planes;
    let centres: [[u8; 3]; GROUP] = std::array::from_fn(|k| {
        let p = ps.get(k).copied().unwrap_or(ps[0]);
        [r[p], g[p], b[p]]
    });
    let mut first = [invalid; GROUP];
    let mut last = [0u16; GROUP];
    for (i, sample) in guide.samples.iter().enumerate() {
        for (k, &p) in ps.iter().enumerate() {
            let q = p.wrapping_add_signed(sample.offset);
            let bin = job.bin_pad[q];
            let c = &centres[k];
            let diff = usize::from(c[0].abs_diff(r[q]))
                + usize::from(c[1].abs_diff(g[q]))
                + usize::from(c[2].abs_diff(b[q]));
            // The invalid bin takes its samples too, and is cleared below.
            h.hist[k * stride + usize::from(bin)] += guide.table[diff & WEIGHT_INDEX];
            h.bins[k * n + i] = bin;
            first[k] = first[k].min(bin);
            last[k] = last[k].max(if bin != invalid { bin } else { 0 });
        }
    }
    let mut medians = [None; GROUP];
    for k in 0..ps.len() {
        let hist = &mut h.hist[k * stride..(k + 1) * stride];
        hist[usize::from(invalid)] = 0.0;
        let (first, last) = (first[k], last[k]);
        if first == invalid {
            continue;
        }
        let bins = &h.bins[k * n..(k + 1) * n];
        h.running.clear();
        let mut acc = 0f32;
        if last - first < 64 {
            // The bins that occur as the bits of one register.
            let mut bits = 0u64;
            for &bin in bins {
                bits |= u64::from(bin != invalid) << ((bin - first) & 63);
            }
            while bits != 0 {
                let bin = usize::from(first) + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                acc += std::mem::take(&mut hist[bin]);
                h.running.push((bin as u16, acc));
            }
        } else {
            for &bin in bins {
                h.occurs[usize::from(bin >> 6)] |= 1 << (bin & 63);
            }
            h.occurs[usize::from(invalid >> 6)] &= !(1 << (invalid & 63));
            for word in usize::from(first >> 6)..=usize::from(last >> 6) {
                let mut bits = std::mem::take(&mut h.occurs[word]);
                while bits != 0 {
                    let bin = word * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    acc += std::mem::take(&mut hist[bin]);
                    h.running.push((bin as u16, acc));
                }
            }
        }
        let total = acc;
        let median = h.running.iter().find(|&&(_, acc)| acc >= total / 2.0);
        medians[k] = Some(median.map_or(last, |&(bin, _)| bin));
    }
    medians
}

/// Pixels whose histograms [`exact_medians`] fills together.
const GROUP: usize = 8;

/// The scratch of [`exact_medians`], for bins `0..=invalid`.
#[derive(Default)]
struct Histogram {
    hist: Vec<f32>,
    bins: Vec<u16>,
    occurs: Vec<u64>,
    running: Vec<(u16, f32)>,
}

impl Histogram {
    /// Room for the bins `0..=invalid`, all empty.
    fn reset(&mut self, invalid: u16) {
        let n = usize::from(invalid) + 1;
        self.hist.clear();
        self.hist.resize(GROUP * n, 0.0);
        self.occurs.clear();
        self.occurs.resize(n.div_ceil(64), 0);
    }
}

/// Per-row buffers of [`WeightedMedianGuide::filter`].
#[derive(Default)]
struct RowScratch {
    /// The bins tested for the row's pixels.
    candidates: Vec<u16>,
    /// Their [`candidate_sums`].
    sums: Sums,
    /// The bin each pixel of the row takes, as the fast test settles it.
    medians: Vec<u16>,
    /// The pixels that the fast test does not settle.
    hard: Vec<usize>,
    /// For [`exact_medians`].
    histogram: Histogram,
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
            sigma_color: 10.0,
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

    /// The definition, pixel by pixel, with the same summation order;
    /// holes stay holes if `keep_holes`.
    fn naive(
        map: &DisparityMap,
        guide: &RgbImage,
        p: &WeightedMedian,
        keep_holes: bool,
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
            if keep_holes && !map.get(x, y).is_finite() {
                return map.get(x, y);
            }
            let c = guide.get(x, y);
            let mut hist = vec![0f32; 70_000];
            let mut used = Vec::new();
            for dy in (-r..=r).step_by(p.step) {
                for dx in (-r..=r).step_by(p.step) {
                    let (qx, qy) = at(x as isize + dx, y as isize + dy);
                    let d = map.get(qx, qy);
                    if !d.is_finite() {
                        continue;
                    }
                    let q = guide.get(qx, qy);
                    let diff: u32 = (0..3).map(|k| c[k].abs_diff(q[k]) as u32).sum();
                    let b = (d.round() - lo) as usize;
                    hist[b] += (-(diff as f32) / p.sigma_color).exp();
                    used.push(b);
                }
            }
            let own = map.get(x, y);
            let (Some(&a), Some(&b)) = (used.iter().min(), used.iter().max()) else {
                return own;
            };
            let total: f32 = hist[a..=b].iter().sum();
            let mut acc = 0.0;
            let median = (a..=b)
                .find(|&k| {
                    acc += hist[k];
                    acc >= total / 2.0
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
        WeightedMedianGuide::new(guide, p).filter_valid(map, &mut out);
        proptest::prop_assert_eq!(bits(&out), want.clone());
        portable.filter_valid(map, &mut out);
        proptest::prop_assert_eq!(bits(&out), want);
        Ok(())
    }

    proptest::proptest! {
        #[test]
        /// Both kernels, as the definition computes it.
        fn equals_the_definition(
            w in 1usize..30, h in 1usize..30, seed in proptest::prelude::any::<u64>(),
            radius in 1usize..6, step in 1usize..4, sigma in 5f32..60.0,
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
            let p = WeightedMedian { radius, sigma_color: sigma, step: step.min(radius) };
            as_defined(&map, &guide, &p)?;
        }

        #[test]
        /// Smooth colours and disparities (most pixels settled by the fast
        /// test on `c`, `c − 1` or `c + 1`), with steps of either and holes
        /// in runs, over ranges of more than 64 bins, the default window
        /// and large ones (down to `Q` = 68 for 961 samples): as defined.
        fn equals_the_definition_on_smooth_maps(
            w in 1usize..48, h in 1usize..40, seed in proptest::prelude::any::<u64>(),
            radius in 1usize..16, step in 1usize..5, sigma in 5f32..80.0, span in 1f32..200.0,
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
            let p = WeightedMedian { radius, sigma_color: sigma, step: step.min(radius) };
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
            sigma_color: 9.0,
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
    fn the_quantized_weights_are_within_the_slack() {
        for (radius, step, sigma) in [(8, 4, 50.0), (15, 1, 5.0), (3, 1, 200.0)] {
            let p = WeightedMedian {
                radius,
                sigma_color: sigma,
                step,
            };
            let guide = RgbImage::from_fn(40, 30, |x, y| {
                [(x * 6) as u8, (y * 8) as u8, ((x * y) % 256) as u8]
            });
            let g = WeightedMedianGuide::new(&guide, &p);
            let n = g.samples.len();
            let scale = (65535 / n) as f32;
            // Every weight of the table, quantized, is within slack / n of Q·w.
            let table: Vec<f32> = (0..=MAX_DIFF)
                .map(|i| (-(i as f32) / sigma).exp())
                .collect();
            for &w in &table {
                let err = (f64::from(quantize(w, scale)) - f64::from(scale) * f64::from(w)).abs();
                assert!(err * n as f64 <= f64::from(g.weights.slack), "{p:?}: {err}");
            }
            assert!(n * usize::from(quantize(1.0, scale)) <= 65535);
        }
    }

    #[test]
    fn bad_parameters_are_errors() {
        let ok = WeightedMedian::DEFAULT;
        assert_eq!(ok.validate(), Ok(()));
        for bad in [
            WeightedMedian { radius: 0, ..ok },
            WeightedMedian { radius: 16, ..ok },
            WeightedMedian {
                sigma_color: 0.0,
                ..ok
            },
            WeightedMedian {
                sigma_color: f32::NAN,
                ..ok
            },
            WeightedMedian { step: 0, ..ok },
            WeightedMedian { step: 11, ..ok },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
