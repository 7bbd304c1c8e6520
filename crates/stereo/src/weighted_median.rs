//! Colour-weighted median refinement (a joint bilateral median, as in
//! Ma et al., "Constant time weighted median filtering for stereo
//! matching and beyond", ICCV 2013, with a plain histogram for the pixels
//! that a vectorised test of one candidate bin does not settle; see
//! [`WeightedMedianGuide::filter`]).
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
    /// (16.53 %).
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
    WeightedMedianGuide::new(guide, p).filter(map)
}

/// What [`weighted_median`] takes from the guide and the parameters alone,
/// built once for any number of maps of the guide's size (the refinement
/// filters twice with one guide).
pub struct WeightedMedianGuide {
    p: WeightedMedian,
    dims: (usize, usize),
    /// The colour planes apart and border-replicated by `radius` on every
    /// side, so that the samples at one offset from a row's pixels are one
    /// slice and the colour differences of a whole row vectorise.
    planes: [Vec<u8>; 3],
    weight: Box<WeightTable>,
    /// Whether the kernels run with AVX2 (same results either way).
    avx2: bool,
}

impl WeightedMedianGuide {
    /// The padded colour planes and the weight table for `p`.
    pub fn new(guide: &RgbImage, p: &WeightedMedian) -> Self {
        Self::with_avx2(guide, p, crate::wta::avx2_available())
    }

    /// [`Self::new`] with the AVX2 kernel (`avx2`, only if the CPU has it)
    /// or the portable one.
    fn with_avx2(guide: &RgbImage, p: &WeightedMedian, avx2: bool) -> Self {
        let dims = guide.dims();
        let plane = |k: usize| {
            pad(guide.as_slice(), dims, p.radius, |row, src| {
                row.iter_mut().zip(src).for_each(|(o, c)| *o = c[k]);
            })
        };
        WeightedMedianGuide {
            p: *p,
            dims,
            planes: [plane(0), plane(1), plane(2)],
            weight: Box::new(std::array::from_fn(|i| (-(i as f32) / p.sigma_color).exp())),
            avx2,
        }
    }

    /// The weighted median of `map` (see [`weighted_median`]).
    ///
    /// Disparities are binned to whole pixels. Most pixels need no
    /// histogram:
    /// - windows whose valid samples all lie in one bin (or none valid;
    ///   most of a smooth map) are settled from per-pixel bin ranges;
    /// - for the others, one vectorised pass over the row sums, per pixel,
    ///   the weights of the samples below, in and above a candidate bin:
    ///   the pixel's own, or for an invalid pixel its left neighbour's. The
    ///   candidate is the median when the weight below it is less than
    ///   half the total and the weight up to it at least half; where that
    ///   holds by a margin of `total / 1024`, far beyond the rounding of
    ///   either way of summing (each within `(n − 1)·2⁻²⁴·total` for `n` ≤
    ///   961 terms, Higham, "Accuracy and Stability of Numerical
    ///   Algorithms", §4.2), the pixel keeps its value (or a hole takes the
    ///   candidate's), exactly as the histogram would decide;
    /// - only the rest (pixels near a disparity or colour edge, and holes
    ///   unlike their left neighbour) build a histogram of their window.
    ///
    /// # Panics
    /// If `map` is not the guide's size.
    pub fn filter(&self, map: &DisparityMap) -> DisparityMap {
        assert_eq!(map.dims(), self.dims);
        let (w, h) = self.dims;
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
            return map.clone();
        }
        // Rounding is monotonic: the extremes' bins are the extreme bins.
        let (lo, hi) = (lo.round(), hi.round());
        let bins = (hi - lo) as usize + 1;
        if bins >= u16::MAX as usize {
            // Not a disparity map of any image this crate matches: left as is.
            return map.clone();
        }
        let (r, step) = (self.p.radius, self.p.step);
        // Invalid pixels go to the extra bin `bins`, which never counts.
        let invalid = bins as u16;
        let bin_pad = pad(map.as_slice(), self.dims, r, |row, src| {
            with_avx2(self.avx2, || bin_row(row, src, lo, invalid))
        });
        let wp = w + 2 * r;
        let (span_lo, span_hi) = sample_spans(&bin_pad, (w, h), (r, step), invalid, self.avx2);
        // The window's samples, as offsets from its top-left corner in the padded images.
        let n = 2 * r + 1;
        let samples: Vec<usize> = (0..n)
            .step_by(step)
            .flat_map(|dy| (0..n).step_by(step).map(move |dx| dy * wp + dx))
            .collect();
        let job = MapJob {
            guide: self,
            bin_pad: &bin_pad,
            spans: (&span_lo, &span_hi),
            samples: &samples,
            lo,
            invalid,
        };
        let mut out = map.clone();
        out.as_mut_slice()
            .par_chunks_mut(w)
            .enumerate()
            .for_each_init(RowScratch::default, |scratch, (y, row)| {
                with_avx2(self.avx2, || filter_row(&job, y, row, scratch))
            });
        out
    }
}

/// What [`filter_row`] reads for the whole map.
struct MapJob<'a> {
    guide: &'a WeightedMedianGuide,
    bin_pad: &'a [u16],
    /// [`sample_spans`].
    spans: (&'a [u16], &'a [u16]),
    samples: &'a [usize],
    /// The disparity of bin 0.
    lo: f32,
    /// The bin of invalid pixels, one past the last valid one.
    invalid: u16,
}

/// [`WeightedMedianGuide::filter`] for row `y` of the output, `row` (a
/// copy of the map's).
#[inline(always)]
fn filter_row(job: &MapJob, y: usize, row: &mut [f32], scratch: &mut RowScratch) {
    let (w, r) = (row.len(), job.guide.p.radius);
    let wp = w + 2 * r;
    let (lo, invalid) = (job.lo, job.invalid);
    let centre = (y + r) * wp + r;
    let own = &job.bin_pad[centre..centre + w];
    let spans = (
        &job.spans.0[y * w..(y + 1) * w],
        &job.spans.1[y * w..(y + 1) * w],
    );
    // Windows of one bin (or none valid) are settled at once.
    let todo = &mut scratch.todo;
    todo.clear();
    for (x, d) in row.iter_mut().enumerate() {
        let (a, b) = (spans.0[x], spans.1[x]);
        if a < b {
            todo.push(x);
        } else if a == b && own[x] != a {
            *d = lo + a as f32;
        }
    }
    let (Some(&x0), Some(&last)) = (todo.first(), todo.last()) else {
        return;
    };
    let sums = &mut scratch.sums;
    sums.iter_mut().for_each(|s| {
        s.clear();
        s.resize(last + 1 - x0, 0.0);
    });
    // The bin tested: a valid pixel's own; for an invalid one, that of the
    // nearest valid pixel to its left (else the row's first valid one),
    // the likeliest value of a hole amid one surface.
    let candidates = &mut scratch.candidates;
    candidates.clear();
    let first_valid = own.iter().copied().find(|&b| b != invalid);
    let mut left = first_valid.unwrap_or(invalid);
    candidates.extend(own[..=last].iter().map(|&b| {
        left = if b != invalid { b } else { left };
        left
    }));
    let sum_job = SumJob {
        candidates: &candidates[x0..],
        planes: &job.guide.planes,
        weight: &job.guide.weight,
        bin_pad: job.bin_pad,
        samples: job.samples,
        at: y * wp + x0,
        centre: centre + x0,
        invalid,
    };
    own_bin_sums(&sum_job, sums, (&mut scratch.diffs, &mut scratch.weights));
    // The test for the whole run at once (it vectorises), then the pixels
    // to do that fail it.
    let keeps = &mut scratch.keeps;
    keeps.clear();
    let [below, at, above] = sums.each_ref();
    keeps.extend(
        below
            .iter()
            .zip(at)
            .zip(above)
            .zip(&candidates[x0..])
            .map(|(((&b, &e), &a), &c)| c != invalid && keeps_own_bin(b, e, a)),
    );
    let hard = &mut scratch.hard;
    hard.clear();
    for &x in todo.iter() {
        if !keeps[x - x0] {
            hard.push(x);
        } else if own[x] == invalid {
            // A hole whose window's median is the candidate bin.
            row[x] = lo + candidates[x] as f32;
        }
    }
    let histogram_job = HistogramJob {
        bin_pad: job.bin_pad,
        samples: job.samples,
        weights: &scratch.weights,
        corner: y * wp,
        x0,
        spans,
        stride: invalid as usize + 1,
    };
    for group in hard.chunks(GROUP) {
        let medians = histogram_medians(&histogram_job, group, &mut scratch.hist);
        for (&x, median) in group.iter().zip(medians) {
            if own[x] as usize != median {
                row[x] = lo + median as f32;
            }
        }
    }
}

/// The weighted median bins of the pixels `xs` (at most [`GROUP`]) of a
/// row: for each, the first bin where the cumulative weight reaches half
/// the total, its histogram summed bin by bin in sample order, from the
/// weights [`own_bin_sums`] left. The pixels' histograms are filled side by
/// side, so that the additions to one bin (often sample after sample) are
/// not one chain of dependent stores and loads.
#[inline(always)]
fn histogram_medians(job: &HistogramJob, xs: &[usize], hist: &mut Vec<f32>) -> [usize; GROUP] {
    let stride = job.stride;
    let run = job.weights.len() / job.samples.len();
    hist.clear();
    hist.resize(xs.len() * stride, 0.0);
    for (&o, weights) in job.samples.iter().zip(job.weights.chunks_exact(run)) {
        let at = job.corner + o;
        for (&x, h) in xs.iter().zip(hist.chunks_exact_mut(stride)) {
            h[job.bin_pad[at + x] as usize] += weights[x - job.x0];
        }
    }
    let mut medians = [0; GROUP];
    for ((m, &x), h) in medians.iter_mut().zip(xs).zip(hist.chunks_exact(stride)) {
        // The valid samples' bins are a..=b; invalid ones went to the last bin.
        let (a, b) = (job.spans.0[x] as usize, job.spans.1[x] as usize);
        let h = &h[a..=b];
        let total: f32 = h.iter().sum();
        let mut acc = 0f32;
        *m = b;
        for (k, v) in h.iter().enumerate() {
            acc += v;
            if acc >= total / 2.0 {
                *m = a + k;
                break;
            }
        }
    }
    medians
}

/// Pixels whose histograms [`histogram_medians`] fills together.
const GROUP: usize = 4;

/// What [`histogram_medians`] reads for a row.
struct HistogramJob<'a> {
    bin_pad: &'a [u16],
    samples: &'a [usize],
    /// The weights of the run from `x0` at each sample offset, one after the other.
    weights: &'a [f32],
    /// The row's window corner in the padded images.
    corner: usize,
    x0: usize,
    /// The row's valid sample bins, smallest and largest.
    spans: (&'a [u16], &'a [u16]),
    /// Bins per histogram, the invalid one included.
    stride: usize,
}

/// Whether a pixel's own bin is its window's weighted median for certain,
/// given the summed weights of the valid samples below, in and above it:
/// the weight below is less than half the total and the weight up to the
/// bin more than half, both by `total / 1024` (see
/// [`WeightedMedianGuide::filter`]). Totals too small for that relative
/// bound (below 2⁻⁶⁰, near the subnormals) never qualify.
#[inline]
fn keeps_own_bin(below: f32, at: f32, above: f32) -> bool {
    let total = below + at + above;
    let (half, margin) = (total / 2.0, total / 1024.0);
    (total >= f32::powi(2.0, -60)) & (below < half - margin) & (below + at > half + margin)
}

/// The colour differences of a run's samples at one offset, and their
/// weights at every offset.
type Buffers<'a> = (&'a mut Vec<u16>, &'a mut Vec<f32>);

/// What [`own_bin_sums`] reads for a run of a row's pixels.
struct SumJob<'a> {
    planes: &'a [Vec<u8>; 3],
    weight: &'a WeightTable,
    bin_pad: &'a [u16],
    samples: &'a [usize],
    /// The first pixel's window corner in the padded images.
    at: usize,
    /// The first pixel itself there.
    centre: usize,
    /// The bin tested for each pixel of the run.
    candidates: &'a [u16],
    /// The bin of invalid pixels.
    invalid: u16,
}

/// For a run of `sums[0].len()` pixels, the summed weights of each one's
/// valid samples below, in and above its own bin (`sums[0..3]`), added in
/// sample order, one sample offset at a time for the whole run (each pixel
/// is a lane: the same arithmetic with or without AVX2). The loops are
/// split so that all but the table look-up vectorise; a sample outside a
/// sum adds `+0.0` (a bit-mask select, which LLVM keeps branch-free).
#[inline(always)]
fn own_bin_sums(job: &SumJob, sums: &mut [Vec<f32>; 3], (diffs, weights): Buffers) {
    let [below, at, above] = sums;
    let n = below.len();
    let (at, above) = (&mut at[..n], &mut above[..n]);
    diffs.resize(n, 0);
    weights.resize(n * job.samples.len(), 0.0);
    let centres = job
        .planes
        .each_ref()
        .map(|p| &p[job.centre..job.centre + n]);
    let own = &job.candidates[..n];
    let masked =
        |wt: f32, keep: bool| f32::from_bits(wt.to_bits() & u32::from(keep).wrapping_neg());
    for (&o, weights) in job.samples.iter().zip(weights.chunks_exact_mut(n)) {
        let q = job.at + o;
        let qs = job.planes.each_ref().map(|p| &p[q..q + n]);
        for (x, dv) in diffs.iter_mut().enumerate() {
            *dv = centres[0][x].abs_diff(qs[0][x]) as u16
                + centres[1][x].abs_diff(qs[1][x]) as u16
                + centres[2][x].abs_diff(qs[2][x]) as u16;
        }
        for (wt, &dv) in weights.iter_mut().zip(diffs.iter()) {
            *wt = job.weight[dv as usize & WEIGHT_INDEX];
        }
        let bin_q = &job.bin_pad[q..q + n];
        for x in 0..n {
            let (b, c, wt) = (bin_q[x], own[x], weights[x]);
            below[x] += masked(wt, b < c);
            at[x] += masked(wt, b == c);
            above[x] += masked(wt, b > c && b != job.invalid);
        }
    }
}

/// Per-row buffers of [`WeightedMedianGuide::filter`].
#[derive(Default)]
struct RowScratch {
    /// The row's pixels whose samples span several bins.
    todo: Vec<usize>,
    /// Their [`own_bin_sums`], from the first to the last.
    sums: [Vec<f32>; 3],
    /// The run's colour differences at one sample offset.
    diffs: Vec<u16>,
    /// Their weights, at every sample offset.
    weights: Vec<f32>,
    /// The bins tested for the row's pixels up to the run's end.
    candidates: Vec<u16>,
    /// Whether each pixel of the run takes its candidate bin for certain.
    keeps: Vec<bool>,
    /// The pixels to do that may not.
    hard: Vec<usize>,
    /// The histograms of a [`GROUP`] of them.
    hist: Vec<f32>,
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

/// `src` (`w`×`h`, row-major) border-replicated by `r` on every side, each
/// row mapped by `f(out, src)` (`out` as long as `src`); rows in parallel.
fn pad<S: Sync, T: Copy + Default + Send>(
    src: &[S],
    (w, h): (usize, usize),
    r: usize,
    f: impl Fn(&mut [T], &[S]) + Sync,
) -> Vec<T> {
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let wp = w + 2 * r;
    let mut out = vec![T::default(); wp * (h + 2 * r)];
    out.par_chunks_mut(wp).enumerate().for_each(|(yp, row)| {
        let y = yp.clamp(r, r + h - 1) - r;
        let (left, rest) = row.split_at_mut(r);
        let (middle, right) = rest.split_at_mut(w);
        f(middle, &src[y * w..(y + 1) * w]);
        left.fill(middle[0]);
        right.fill(middle[w - 1]);
    });
    out
}

/// The bins of a row of disparities (`invalid` for an invalid one);
/// branch-free, so that it vectorises.
#[inline(always)]
fn bin_row(out: &mut [u16], src: &[f32], lo: f32, invalid: u16) {
    for (o, &d) in out.iter_mut().zip(src) {
        // A non-finite `d` saturates the cast and is replaced.
        let bin = (d.round() - lo) as u16;
        *o = if d.is_finite() { bin } else { invalid };
    }
}

/// `lo` and `hi` become the smallest bin and the largest valid bin (0 for
/// none) of each column of `rows`.
#[inline(always)]
fn min_max_down<'a>(
    lo: &mut [u16],
    hi: &mut [u16],
    rows: impl Iterator<Item = &'a [u16]>,
    invalid: u16,
) {
    for q in rows {
        for ((a, b), &q) in lo.iter_mut().zip(hi.iter_mut()).zip(q) {
            *a = (*a).min(q);
            *b = (*b).max(if q < invalid { q } else { 0 });
        }
    }
}

/// `lo` and `hi` become the smallest and largest of `down` at the columns
/// `x + dx` for each `dx` of `offsets`.
#[inline(always)]
fn min_max_across(
    lo: &mut [u16],
    hi: &mut [u16],
    (down_lo, down_hi): (&[u16], &[u16]),
    offsets: impl Iterator<Item = usize>,
) {
    for dx in offsets {
        let (qa, qb) = (&down_lo[dx..], &down_hi[dx..]);
        for (((a, b), &qa), &qb) in lo.iter_mut().zip(hi.iter_mut()).zip(qa).zip(qb) {
            *a = (*a).min(qa);
            *b = (*b).max(qb);
        }
    }
}

/// For every pixel, the smallest and the largest valid bin among its
/// window's samples (`invalid`, above every valid bin, and 0 when there is
/// none), from separable passes over the border-padded bins, whole rows at
/// a time (`u16` min and max are SSE4.1 instructions: with AVX2 if `avx2`).
fn sample_spans(
    bin_pad: &[u16],
    (w, h): (usize, usize),
    (r, step): (usize, usize),
    invalid: u16,
    avx2: bool,
) -> (Vec<u16>, Vec<u16>) {
    let wp = w + 2 * r;
    let offsets = || (0..=2 * r).step_by(step);
    // Down the window's sampled rows, for every padded column.
    let (mut down_lo, mut down_hi) = (vec![invalid; wp * h], vec![0u16; wp * h]);
    down_lo
        .par_chunks_mut(wp)
        .zip(down_hi.par_chunks_mut(wp))
        .enumerate()
        .for_each(|(y, (lo, hi))| {
            let rows = offsets().map(|dy| &bin_pad[(y + dy) * wp..(y + dy + 1) * wp]);
            with_avx2(avx2, || min_max_down(lo, hi, rows, invalid))
        });
    let (mut span_lo, mut span_hi) = (vec![invalid; w * h], vec![0u16; w * h]);
    span_lo
        .par_chunks_mut(w)
        .zip(span_hi.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (lo, hi))| {
            let (down_lo, down_hi) = (&down_lo[y * wp..], &down_hi[y * wp..]);
            with_avx2(avx2, || {
                min_max_across(lo, hi, (down_lo, down_hi), offsets())
            })
        });
    (span_lo, span_hi)
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

    /// The definition, pixel by pixel, with the same summation order.
    fn naive(map: &DisparityMap, guide: &RgbImage, p: &WeightedMedian) -> DisparityMap {
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

    proptest::proptest! {
        #[test]
        /// Both kernels, as the definition computes it.
        fn equals_the_definition(
            w in 1usize..30, h in 1usize..30, seed in proptest::prelude::any::<u64>(),
            radius in 1usize..6, step in 1usize..4, sigma in 5f32..60.0,
        ) {
            let mut s = seed | 1;
            let mut next = move || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s };
            let guide = RgbImage::from_fn(w, h, |_, _| {
                let v = next();
                [v as u8 & 0xF0, (v >> 8) as u8, (v >> 16) as u8 & 0xC0]
            });
            let map = DisparityMap::from_fn(w, h, |x, y| match (x * 7 + y * 13 + seed as usize) % 11 {
                0 => f32::INFINITY,
                k => 3.0 + (k % 4) as f32 + if x > w / 2 { 0.25 } else { 0.0 },
            });
            let p = WeightedMedian { radius, sigma_color: sigma, step: step.min(radius) };
            let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            let want = bits(&naive(&map, &guide, &p));
            proptest::prop_assert_eq!(bits(&weighted_median(&map, &guide, &p)), want.clone());
            let portable = WeightedMedianGuide::with_avx2(&guide, &p, false);
            proptest::prop_assert_eq!(bits(&portable.filter(&map)), want);
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
