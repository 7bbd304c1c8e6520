//! k-means on RGB pixels (the paper's eq. 5, `J = Σ_j Σ_{x ∈ C_j} ||x − c_j||²`),
//! with k-means++ seeding and Lloyd iterations.
//!
//! It runs on the image's distinct colours weighted by their counts, which
//! gives exactly the pixel-level result (identical pixels always share a
//! cluster) at a fraction of the cost; assignment runs in parallel.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use stereolink_image::{Plane, RgbImage};

use crate::{compact, SegmentError, Segmentation};

/// Lloyd iterations stop when no centroid moves more than this (RGB units),
/// or after 100: a hundredth of a level, fine enough to keep J below
/// scikit-learn's and coarse enough to save steps (docs/tuning.md,
/// “k-means tolerance”).
pub const TOLERANCE: f64 = 1e-2;
const MAX_ITERATIONS: usize = 100;

/// Clusters found by [`cluster`].
#[derive(Clone, Debug, PartialEq)]
pub struct KMeans {
    /// Cluster centres in RGB.
    pub centroids: Vec<[f64; 3]>,
    /// The objective J (sum of squared distances to the centres).
    pub objective: f64,
    /// Lloyd iterations run.
    pub iterations: usize,
}

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// The nearest centroid and its squared distance (the first on ties).
fn nearest(c: [f64; 3], centroids: &[[f64; 3]]) -> (usize, f64) {
    let mut best = (0, dist2(c, centroids[0]));
    for (i, &m) in centroids.iter().enumerate().skip(1) {
        let d = dist2(c, m);
        if d < best.1 {
            best = (i, d);
        }
    }
    best
}

/// Sorts values below 2²⁴ (packed RGB): three stable counting passes, one
/// per byte, from the lowest, with the three histograms taken in one read.
fn radix_sort_24(values: &mut Vec<u32>) {
    let mut other = vec![0u32; values.len()];
    let mut starts = [[0usize; 256]; 3];
    for &v in values.iter() {
        for (byte, start) in starts.iter_mut().enumerate() {
            start[(v >> (8 * byte) & 0xFF) as usize] += 1;
        }
    }
    for (byte, start) in starts.iter_mut().enumerate() {
        let mut at = 0;
        for s in start.iter_mut() {
            (*s, at) = (at, at + *s);
        }
        for &v in values.iter() {
            let b = (v >> (8 * byte) & 0xFF) as usize;
            other[start[b]] = v;
            start[b] += 1;
        }
        std::mem::swap(values, &mut other);
    }
}

/// The distinct colours of an image with their counts, in a fixed order
/// (sorted packed RGB; sorting beats hashing here by a wide margin).
fn colour_counts(image: &RgbImage) -> Colours {
    let mut packed: Vec<u32> = image
        .as_slice()
        .iter()
        .map(|p| u32::from_be_bytes([0, p[0], p[1], p[2]]))
        .collect();
    radix_sort_24(&mut packed);
    // One pass over the sorted values: each run is a colour and its count.
    let mut out = Colours {
        r: Vec::with_capacity(packed.len()),
        g: Vec::with_capacity(packed.len()),
        b: Vec::with_capacity(packed.len()),
        n: Vec::with_capacity(packed.len()),
    };
    let mut start = 0;
    for (i, pair) in packed.windows(2).enumerate() {
        if pair[0] != pair[1] {
            out.push(pair[0], (i + 1 - start) as u32);
            start = i + 1;
        }
    }
    if let Some(&last) = packed.last() {
        out.push(last, (packed.len() - start) as u32);
    }
    out
}

/// Weights summed per block by [`pick`] and [`exact_sum`].
const PICK_BLOCK: usize = 256;

/// The sum of whole-number weights (exact below 2⁵³, so any order gives
/// it): four accumulators, so that the additions do not wait on each other.
fn exact_sum(weights: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let blocks = weights.chunks_exact(4);
    let rest: f64 = blocks.remainder().iter().sum();
    for b in blocks {
        for (a, &w) in acc.iter_mut().zip(b) {
            *a += w;
        }
    }
    acc.iter().sum::<f64>() + rest
}

/// Index `i` drawn with probability `weights[i] / sum`: the first whose
/// running total passes a uniform draw in `[0, sum)`. Weights are whole
/// numbers, so block totals are exact and the block holding the draw is
/// found before stepping through its weights one by one.
fn pick(rng: &mut ChaCha8Rng, weights: &[f64], sum: f64) -> usize {
    let r = rng.gen_range(0.0..sum);
    let mut before = 0.0;
    for (b, block) in weights.chunks(PICK_BLOCK).enumerate() {
        let total = exact_sum(block);
        if r < before + total {
            for (i, &w) in block.iter().enumerate() {
                before += w;
                if r < before {
                    return b * PICK_BLOCK + i;
                }
            }
        }
        before += total;
    }
    weights.len() - 1
}

/// Colours as structure of arrays, for vector code: channels and counts as
/// compact integers (a Lloyd step streams them all, so their size sets its
/// speed), widened to `f64` where used.
struct Colours {
    r: Vec<u8>,
    g: Vec<u8>,
    b: Vec<u8>,
    n: Vec<u32>,
}

impl Colours {
    /// Every pixel of `image` once, weight 1.
    fn pixels(image: &RgbImage) -> Self {
        let channel = |i: usize| image.as_slice().iter().map(|p| p[i]).collect();
        Colours {
            r: channel(0),
            g: channel(1),
            b: channel(2),
            n: vec![1; image.len()],
        }
    }

    /// Appends the packed colour `rgb` (`0x00RRGGBB`) with `count`.
    #[inline]
    fn push(&mut self, rgb: u32, count: u32) {
        let [_, r, g, b] = rgb.to_be_bytes();
        self.r.push(r);
        self.g.push(g);
        self.b.push(b);
        self.n.push(count);
    }

    /// Colour `i` and its count.
    fn get(&self, i: usize) -> ([f64; 3], f64) {
        let c = [self.r[i], self.g[i], self.b[i]].map(f64::from);
        (c, f64::from(self.n[i]))
    }

    fn len(&self) -> usize {
        self.n.len()
    }
}

/// For every colour (in parallel), its nearest centre and its weighted
/// squared distance `n·d²` to it: [`nearest`] for all, with the AVX2 copy
/// for up to 8 centres (bit-identical).
struct Assignment {
    labels: Vec<u32>,
    weighted: Vec<f64>,
}

fn assign(colours: &Colours, centroids: &[[f64; 3]], avx2: bool) -> Assignment {
    let mut labels = vec![0u32; colours.len()];
    let mut weighted = vec![0.0f64; colours.len()];
    const CHUNK: usize = 4096;
    let chunks = labels
        .par_chunks_mut(CHUNK)
        .zip(weighted.par_chunks_mut(CHUNK));
    chunks.enumerate().for_each(|(c, (labels, weighted))| {
        let range = c * CHUNK..c * CHUNK + labels.len();
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: AVX2 was detected at run time; the arm matches the count.
            let done = unsafe {
                with_centres!(centroids.len(), K => assign_avx2::<K>(colours, range.clone(), centroids, labels, weighted))
            };
            if done.is_some() {
                return;
            }
        }
        let _ = avx2;
        for ((l, w), i) in labels.iter_mut().zip(weighted.iter_mut()).zip(range) {
            let (c, n) = colours.get(i);
            let (j, d) = nearest(c, centroids);
            (*l, *w) = (j as u32, n * d);
        }
    });
    Assignment { labels, weighted }
}

/// The nearest of `centres` to `c` in `f32` (the first on ties): the
/// assignment of the Lloyd steps, which need not be exact but must be the
/// same in the scalar and the AVX2 code (same operations in the same order,
/// no fused multiply-add).
fn nearest32(c: [f32; 3], centres: &[[f32; 3]]) -> usize {
    let dist = |m: &[f32; 3]| {
        let e = [c[0] - m[0], c[1] - m[1], c[2] - m[2]];
        e[0] * e[0] + e[1] * e[1] + e[2] * e[2]
    };
    let mut best = (0, dist(&centres[0]));
    for (j, m) in centres.iter().enumerate().skip(1) {
        let d = dist(m);
        if d < best.1 {
            best = (j, d);
        }
    }
    best.0
}

/// Each cluster's weighted colour sum and count over colours `range`, every
/// colour in the cluster of its nearest centre by [`nearest32`].
///
/// The sums are of integers below 2⁵³, exact in any order, so the AVX2 copy
/// ([`chunk_sums_avx2`]) gives the same result bit for bit.
fn chunk_sums(
    colours: &Colours,
    range: std::ops::Range<usize>,
    centroids: &[[f64; 3]],
) -> Vec<([f64; 3], f64)> {
    let centres: Vec<[f32; 3]> = centroids.iter().map(|m| m.map(|v| v as f32)).collect();
    let mut acc = vec![([0.0f64; 3], 0.0f64); centroids.len()];
    for i in range {
        let (c, n) = colours.get(i);
        let j = nearest32(c.map(|v| v as f32), &centres);
        for ch in 0..3 {
            acc[j].0[ch] += c[ch] * n;
        }
        acc[j].1 += n;
    }
    acc
}

/// Runs `$call` with the const `$k` equal to `$n` when `$n` is 1 to 8:
/// `Some(result)`, else `None`.
#[cfg(target_arch = "x86_64")]
macro_rules! with_centres {
    ($n:expr, $k:ident => $call:expr) => {
        match $n {
            1 => {
                const $k: usize = 1;
                Some($call)
            }
            2 => {
                const $k: usize = 2;
                Some($call)
            }
            3 => {
                const $k: usize = 3;
                Some($call)
            }
            4 => {
                const $k: usize = 4;
                Some($call)
            }
            5 => {
                const $k: usize = 5;
                Some($call)
            }
            6 => {
                const $k: usize = 6;
                Some($call)
            }
            7 => {
                const $k: usize = 7;
                Some($call)
            }
            8 => {
                const $k: usize = 8;
                Some($call)
            }
            _ => None,
        }
    };
}
#[cfg(target_arch = "x86_64")]
use with_centres;

/// The nearest of `K` centres for four colours: distances as in [`dist2`]
/// (no fused multiply-add: the same rounding), the nearest kept by a strict
/// comparison (the first on ties); the label as `f64` lanes and the squared
/// distance.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn nearest4<const K: usize>(
    [cr, cg, cb]: [std::arch::x86_64::__m256d; 3],
    centres: &[[std::arch::x86_64::__m256d; 3]; K],
    ids: &[std::arch::x86_64::__m256d; K],
) -> (std::arch::x86_64::__m256d, std::arch::x86_64::__m256d) {
    use std::arch::x86_64::*;
    let dist = |m: &[__m256d; 3]| {
        let (dr, dg, db) = (
            _mm256_sub_pd(cr, m[0]),
            _mm256_sub_pd(cg, m[1]),
            _mm256_sub_pd(cb, m[2]),
        );
        _mm256_add_pd(
            _mm256_add_pd(_mm256_mul_pd(dr, dr), _mm256_mul_pd(dg, dg)),
            _mm256_mul_pd(db, db),
        )
    };
    let mut best = dist(&centres[0]);
    let mut label = _mm256_setzero_pd();
    for j in 1..K {
        let d = dist(&centres[j]);
        let closer = _mm256_cmp_pd(d, best, _CMP_LT_OQ);
        best = _mm256_blendv_pd(best, d, closer);
        label = _mm256_blendv_pd(label, ids[j], closer);
    }
    (label, best)
}

/// Colours `i..i + 4` as `f64` lanes: the three channels and the counts.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn load4(colours: &Colours, i: usize) -> [std::arch::x86_64::__m256d; 4] {
    use std::arch::x86_64::*;
    let channel = |v: &[u8]| {
        let bytes = u32::from_le_bytes(v[i..i + 4].try_into().expect("four bytes"));
        _mm256_cvtepi32_pd(_mm_cvtepu8_epi32(_mm_cvtsi32_si128(bytes as i32)))
    };
    // Counts are at most the pixel count, far below 2³¹: exact as i32.
    let counts = _mm_loadu_si128(colours.n[i..i + 4].as_ptr().cast());
    [
        channel(&colours.r),
        channel(&colours.g),
        channel(&colours.b),
        _mm256_cvtepi32_pd(counts),
    ]
}

/// The centres broadcast, and their indices as `f64` lanes.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
#[allow(clippy::type_complexity)]
unsafe fn broadcast<const K: usize>(
    centroids: &[[f64; 3]],
) -> (
    [[std::arch::x86_64::__m256d; 3]; K],
    [std::arch::x86_64::__m256d; K],
) {
    use std::arch::x86_64::*;
    assert_eq!(centroids.len(), K);
    (
        std::array::from_fn(|j| centroids[j].map(|v| _mm256_set1_pd(v))),
        std::array::from_fn(|j| _mm256_set1_pd(j as f64)),
    )
}

/// [`assign`] of colours `range` for `K` centres, four at a time.
///
/// # Safety
/// The CPU must have AVX2; `centroids.len() == K`; `labels` and `weighted`
/// as long as `range`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn assign_avx2<const K: usize>(
    colours: &Colours,
    range: std::ops::Range<usize>,
    centroids: &[[f64; 3]],
    labels: &mut [u32],
    weighted: &mut [f64],
) {
    use std::arch::x86_64::*;
    assert!(labels.len() == range.len() && weighted.len() == range.len());
    let (centres, ids) = broadcast::<K>(centroids);
    let whole = range.len() / 4 * 4;
    for k in (0..whole).step_by(4) {
        let [cr, cg, cb, cn] = load4(colours, range.start + k);
        let (label, d) = nearest4::<K>([cr, cg, cb], &centres, &ids);
        _mm_storeu_si128(
            labels[k..k + 4].as_mut_ptr().cast(),
            _mm256_cvtpd_epi32(label),
        );
        _mm256_storeu_pd(weighted[k..k + 4].as_mut_ptr(), _mm256_mul_pd(cn, d));
    }
    for k in whole..range.len() {
        let (c, n) = colours.get(range.start + k);
        let (j, d) = nearest(c, centroids);
        (labels[k], weighted[k]) = (j as u32, n * d);
    }
}

/// [`chunk_sums`] for `K ≥ 2` centres, eight colours at a time: the
/// [`nearest32`] distances on `f32` lanes, the weighted channels as `i32`
/// products added into the accumulators of the first `K − 1` centres under
/// lane masks; the last centre's sums are the totals minus the others'.
///
/// # Safety
/// The CPU must have AVX2; `centroids.len() == K ≥ 2`; 255 times the total
/// count of all colours fits `i32`, so that no lane sum overflows.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn chunk_sums_avx2<const K: usize>(
    colours: &Colours,
    range: std::ops::Range<usize>,
    centroids: &[[f64; 3]],
) -> Vec<([f64; 3], f64)> {
    use std::arch::x86_64::*;
    assert!(K >= 2 && centroids.len() == K);
    let (start, end) = (range.start, range.end);
    let whole = start + (end - start) / 8 * 8;
    let centres: [[__m256; 3]; K] =
        std::array::from_fn(|j| centroids[j].map(|v| _mm256_set1_ps(v as f32)));
    let ids: [__m256i; K] = std::array::from_fn(|j| _mm256_set1_epi32(j as i32));
    let zero = _mm256_setzero_si256();
    let mut sums = [[zero; 4]; K];
    let mut totals = [zero; 4];
    for i in (start..whole).step_by(8) {
        let widen = |v: &[u8]| _mm256_cvtepu8_epi32(_mm_loadl_epi64(v[i..i + 8].as_ptr().cast()));
        let (ir, ig, ib) = (widen(&colours.r), widen(&colours.g), widen(&colours.b));
        let n = _mm256_loadu_si256(colours.n[i..i + 8].as_ptr().cast());
        let (fr, fg, fb) = (
            _mm256_cvtepi32_ps(ir),
            _mm256_cvtepi32_ps(ig),
            _mm256_cvtepi32_ps(ib),
        );
        let dist = |m: &[__m256; 3]| {
            let (er, eg, eb) = (
                _mm256_sub_ps(fr, m[0]),
                _mm256_sub_ps(fg, m[1]),
                _mm256_sub_ps(fb, m[2]),
            );
            _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(er, er), _mm256_mul_ps(eg, eg)),
                _mm256_mul_ps(eb, eb),
            )
        };
        let mut best = dist(&centres[0]);
        let mut label = zero;
        for j in 1..K {
            let d = dist(&centres[j]);
            let closer = _mm256_cmp_ps(d, best, _CMP_LT_OQ);
            best = _mm256_blendv_ps(best, d, closer);
            label = _mm256_blendv_epi8(label, ids[j], _mm256_castps_si256(closer));
        }
        let weighted = [
            _mm256_mullo_epi32(ir, n),
            _mm256_mullo_epi32(ig, n),
            _mm256_mullo_epi32(ib, n),
            n,
        ];
        for (acc, &v) in totals.iter_mut().zip(&weighted) {
            *acc = _mm256_add_epi32(*acc, v);
        }
        for j in 0..K - 1 {
            let mine = _mm256_cmpeq_epi32(label, ids[j]);
            for (acc, &v) in sums[j].iter_mut().zip(&weighted) {
                *acc = _mm256_add_epi32(*acc, _mm256_and_si256(v, mine));
            }
        }
    }
    // The last centre's: all minus the others'.
    for ch in 0..4 {
        let others = (0..K - 1).fold(zero, |a, j| _mm256_add_epi32(a, sums[j][ch]));
        sums[K - 1][ch] = _mm256_sub_epi32(totals[ch], others);
    }
    let mut acc = chunk_sums(colours, whole..end, centroids);
    for (a, s) in acc.iter_mut().zip(&sums) {
        let total = |v: __m256i| {
            let lanes = std::mem::transmute::<__m256i, [i32; 8]>(v);
            lanes.iter().map(|&l| i64::from(l)).sum::<i64>() as f64
        };
        for ch in 0..3 {
            a.0[ch] += total(s[ch]);
        }
        a.1 += total(s[3]);
    }
    acc
}

/// [`chunk_sums`], with the AVX2 copy for 2 to 8 centres when `avx2` (the
/// caller checks that 255 times the pixel count fits `i32`).
fn lloyd_sums(
    colours: &Colours,
    range: std::ops::Range<usize>,
    centroids: &[[f64; 3]],
    avx2: bool,
) -> Vec<([f64; 3], f64)> {
    #[cfg(target_arch = "x86_64")]
    if avx2 && centroids.len() >= 2 {
        // SAFETY: AVX2 was detected at run time; the arm matches the count;
        // the caller checked the lane sums' range.
        let sums = unsafe {
            with_centres!(centroids.len(), K => chunk_sums_avx2::<K>(colours, range.clone(), centroids))
        };
        if let Some(sums) = sums {
            return sums;
        }
    }
    let _ = avx2;
    chunk_sums(colours, range, centroids)
}

/// Runs k-means++ and Lloyd's algorithm on the pixels of `image`.
pub fn cluster(image: &RgbImage, k: usize, seed: u64) -> Result<KMeans, SegmentError> {
    let (centroids, iterations, colours) = fit(image, k, seed)?;
    // Not whole numbers: summed in order, for a deterministic value.
    let objective = assign(&colours, &centroids, stereolink_image::cpu::avx2())
        .weighted
        .iter()
        .sum();
    Ok(KMeans {
        centroids,
        objective,
        iterations,
    })
}

/// The centres and Lloyd steps of [`cluster`], and the colours they ran on.
fn fit(
    image: &RgbImage,
    k: usize,
    seed: u64,
) -> Result<(Vec<[f64; 3]>, usize, Colours), SegmentError> {
    if k == 0 || k > image.len() {
        return Err(SegmentError::TooManyClusters {
            k,
            pixels: image.len(),
        });
    }
    let soa = colour_counts(image);
    let avx2 = stereolink_image::cpu::avx2();
    // The AVX2 Lloyd step sums in i32 lanes: up to 255 · pixels.
    let narrow = 255 * image.len() as u64 <= i32::MAX as u64;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    // k-means++: first centre by pixel count, then by count · D².
    let counts: Vec<f64> = soa.n.iter().map(|&n| f64::from(n)).collect();
    let total = exact_sum(&counts);
    let mut centroids = vec![soa.get(pick(&mut rng, &counts, total)).0];
    while centroids.len() < k {
        let weights = assign(&soa, &centroids, avx2).weighted;
        let sum = exact_sum(&weights);
        if sum <= 0.0 {
            break; // fewer distinct colours than k: every colour is a centre already
        }
        centroids.push(soa.get(pick(&mut rng, &weights, sum)).0);
    }
    let mut iterations = 0;
    loop {
        iterations += 1;
        let empty = || vec![([0.0f64; 3], 0.0f64); centroids.len()];
        const CHUNK: usize = 4096;
        let sums = (0..soa.len().div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let range = c * CHUNK..((c + 1) * CHUNK).min(soa.len());
                lloyd_sums(&soa, range, &centroids, avx2 && narrow)
            })
            .reduce(empty, |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    for ch in 0..3 {
                        x.0[ch] += y.0[ch];
                    }
                    x.1 += y.1;
                }
                a
            });
        let mut shift: f64 = 0.0;
        for (c, (s, n)) in centroids.iter_mut().zip(sums) {
            if n > 0.0 {
                let new = s.map(|v| v / n);
                shift = shift.max(dist2(*c, new).sqrt());
                *c = new;
            }
        }
        if shift <= TOLERANCE || iterations >= MAX_ITERATIONS {
            break;
        }
    }
    Ok((centroids, iterations, soa))
}

/// Segments into `k` clusters coloured by their rounded centres.
pub fn kmeans(image: &RgbImage, k: usize, seed: u64) -> Result<Segmentation, SegmentError> {
    let (centroids, iterations, _) = fit(image, k, seed)?;
    let pixels = Colours::pixels(image);
    let data = assign(&pixels, &centroids, stereolink_image::cpu::avx2()).labels;
    let labels = Plane::from_vec(image.width(), image.height(), data).expect("one label per pixel");
    let image = compact(labels, |l| {
        centroids[l as usize].map(|v| v.round().clamp(0.0, 255.0) as u8)
    })?;
    Ok(Segmentation {
        image,
        channels: None,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn radix_sort_sorts() {
        let mut s = 12345u32;
        let mut v: Vec<u32> = (0..5000)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                s >> 8
            })
            .collect();
        let mut want = v.clone();
        want.sort_unstable();
        radix_sort_24(&mut v);
        assert_eq!(v, want);
    }

    /// The AVX2 Lloyd sums and assignments equal the portable ones bit for
    /// bit, ties included.
    #[test]
    fn avx2_sums_equal_portable_sums() {
        if !stereolink_image::cpu::avx2() {
            return;
        }
        let mut s = 0x0005_DEEC_E66D_u64;
        let mut next = move |m: u64| {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (s >> 33) % m
        };
        for len in [1, 3, 4, 5, 37, 1000] {
            // Few levels, so that colours equidistant from two centres occur.
            let mut channel = || (0..len).map(|_| (next(8) * 32) as u8).collect();
            let (r, g, b) = (channel(), channel(), channel());
            let n = (0..len).map(|_| 1 + next(50) as u32).collect();
            let soa = Colours { r, g, b, n };
            for k in 1..=9 {
                let centroids: Vec<[f64; 3]> = (0..k)
                    .map(|_| [0, 1, 2].map(|_| (next(16) * 16) as f64))
                    .collect();
                let portable = chunk_sums(&soa, 0..len, &centroids);
                let fast = lloyd_sums(&soa, 0..len, &centroids, true);
                assert_eq!(portable, fast, "{len} colours, k {k}");
                let (a, b) = (
                    assign(&soa, &centroids, false),
                    assign(&soa, &centroids, true),
                );
                assert_eq!((a.labels, a.weighted), (b.labels, b.weighted));
            }
        }
    }

    #[test]
    fn objective_is_zero_for_k_distinct_colours() {
        let img = RgbImage::from_fn(6, 2, |x, _| [x as u8 * 40, 0, 0]);
        assert_eq!(cluster(&img, 6, 3).unwrap().objective, 0.0);
        assert!(cluster(&img, 3, 3).unwrap().objective > 0.0);
    }

    #[test]
    fn centres_are_local_optima_of_the_objective() {
        let img = RgbImage::from_fn(40, 40, |x, y| {
            [(x * 6) as u8, (y * 6) as u8, ((x + y) * 3) as u8]
        });
        let j = |cs: &[[f64; 3]]| {
            img.as_slice()
                .iter()
                .map(|p| nearest(p.map(f64::from), cs).1)
                .sum::<f64>()
        };
        for seed in 0..5 {
            let km = cluster(&img, 4, seed).unwrap();
            assert!((j(&km.centroids) - km.objective).abs() < 1e-6 * km.objective);
            let mut moved = km.centroids.clone();
            moved[0][0] += 3.0;
            assert!(j(&moved) >= km.objective);
        }
    }
}
