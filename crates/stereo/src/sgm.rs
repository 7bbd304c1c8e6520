//! Semi-global matching (Hirschmüller, "Stereo Processing by Semiglobal
//! Matching and Mutual Information", PAMI 2008), beyond the paper.
//!
//! * **Cost**: Hamming distance of 9×7 census transforms (62 bits), robust to
//!   the exposure differences of real cameras. `C(p, d)` lies in 0..=62;
//!   matches outside the right view cost [`OUTSIDE_COST`].
//! * **Aggregation** along 4 or 8 straight paths `r`:
//!   `L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1,
//!   min_k L_r(p−r, k) + P2(p)) − min_k L_r(p−r, k)`, summed into
//!   `S(p, d)` (`u16`). `P2` adapts to the intensity step along the path:
//!   `P2(p) = max(P1 + 1, P2 · γ / (γ + |I(p) − I(p−r)|))`, so depth may jump
//!   where the image has an edge.
//! * **Disparity**: winner-take-all on `S`, with a parabola fit when the
//!   refinement asks for it; the right view's map comes from the same `S`
//!   for the left-right check.
//!
//! Memory is the `u8` cost volume (census costs computed once for all
//! paths) and the `u16` sum volume, `3·W·H·D'` bytes with `D'` the
//! disparities padded to 32 lanes, plus a few rows of path costs (`u8`, see
//! `step`); both volumes are kept in [`SgmBuffers`] between frames:
//! 220 MiB peak RSS for the 741×497 Motorcycle scene at 190 disparities.
//!
//! Aggregation is two sweeps, down and up, that run in parallel and each
//! add all their paths into a pixel's sums in one visit (see `sweep`); the
//! second sweep to visit a row picks its disparities while the sums are in
//! cache. Census, costs, path steps and the winner search have AVX2 kernels
//! (runtime-detected) with portable twins that give the same bits (tested).

use rayon::prelude::*;
use std::sync::Mutex;
use stereolink_image::{DisparityMap, GrayImage};

use crate::census::census_with;
use crate::lanes::{LaneOps, Portable};
use crate::refine::{parabola, Raw};
use crate::{MatchSpec, StereoError};

/// Cost of a match that falls outside the right view.
pub const OUTSIDE_COST: u16 = 62;
/// Path cost of the missing neighbours of `d_min` and `d_max`.
const SENTINEL: u8 = u8::MAX;
/// Largest `P2`: path costs must fit `u8` (see `step`).
pub const MAX_P2: u16 = 255 - OUTSIDE_COST;

/// SGM parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SgmParams {
    /// Penalty for a disparity change of one.
    pub p1: u16,
    /// Base penalty for larger disparity changes.
    pub p2: u16,
    /// Intensity scale γ of the adaptive P2 (larger: less adaptive).
    pub p2_gamma: u16,
    /// 4 or 8 paths.
    pub paths: u8,
}

impl Default for SgmParams {
    /// Measured on the Middlebury v2 scenes with `stereolink eval`.
    fn default() -> Self {
        SgmParams {
            p1: 24,
            p2: 90,
            p2_gamma: 24,
            paths: 8,
        }
    }
}

impl SgmParams {
    pub(crate) fn validate(&self) -> Result<(), StereoError> {
        if self.paths != 4 && self.paths != 8 {
            return Err(StereoError::Parameter(format!(
                "SGM paths must be 4 or 8, not {}",
                self.paths
            )));
        }
        if self.p1 == 0 || self.p2 <= self.p1 || self.p2 > MAX_P2 || self.p2_gamma == 0 {
            return Err(StereoError::Parameter(format!(
                "SGM penalties need 0 < P1 < P2 <= {MAX_P2} and γ > 0 (got P1 {}, P2 {}, γ {})",
                self.p1, self.p2, self.p2_gamma
            )));
        }
        Ok(())
    }
}

struct Volume<'a> {
    w: usize,
    h: usize,
    nd: usize,
    /// Lanes per pixel: `nd` padded to a multiple of [`BLOCK`].
    np: usize,
    min_disp: usize,
    /// `C(x, y, d_min + k)` at `((y·W + x)·np + k)`; [`PAD`] for `k ≥ nd`.
    cost: &'a [u8],
    img: &'a GrayImage,
    p: SgmParams,
    /// `P2` by intensity step `|I(p) − I(p−r)|`.
    p2_by_step: [u8; 256],
    /// Fit a parabola to the winner's neighbouring sums.
    subpixel: bool,
}

impl Volume<'_> {
    #[inline(always)]
    fn p2(&self, a: u8, b: u8) -> u8 {
        self.p2_by_step[a.abs_diff(b) as usize]
    }
}

/// The adaptive `P2` for every intensity step (see the module doc).
fn p2_table(p: &SgmParams) -> [u8; 256] {
    let g = p.p2_gamma as u32;
    // P1 < P2 ≤ MAX_P2 (validated), so every value fits `u8`.
    std::array::from_fn(|step| ((p.p2 as u32 * g / (g + step as u32)) as u8).max(p.p1 as u8 + 1))
}

/// Lanes of one vector step along the disparity axis (one AVX2 register of `u8`).
const BLOCK: usize = 32;

/// Cost of the padding lanes past `d_max`: saturates every path cost there
/// to [`SENTINEL`], so they act as the missing neighbour of `d_max`.
const PAD: u8 = u8::MAX;

/// The census Hamming costs of every pixel and disparity, `u8`, computed
/// once for all paths, `np` lanes per pixel.
fn cost_volume(
    cl: &[u64],
    cr: &[u64],
    w: usize,
    (nd, np): (usize, usize),
    min_disp: usize,
    cost: &mut Vec<u8>,
    avx2: bool,
) {
    cost.resize(cl.len() * np, 0);
    cost.par_chunks_mut(w * np)
        .zip(cl.par_chunks(w).zip(cr.par_chunks(w)))
        .for_each(|(out, (l, r))| {
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: AVX2 presence was checked at run time.
                return unsafe { cost_row_avx2(l, r, min_disp, nd, out) };
            }
            let _ = avx2; // only x86-64 has an AVX2 kernel
            cost_row(l, r, min_disp, nd, out, false)
        });
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn cost_row_avx2(l: &[u64], r: &[u64], min_disp: usize, nd: usize, out: &mut [u8]) {
    cost_row(l, r, min_disp, nd, out, true)
}

/// The costs of one row (`np` lanes per pixel); `avx2`: the CPU has it.
#[inline(always)]
fn cost_row(l: &[u64], r: &[u64], min_disp: usize, nd: usize, out: &mut [u8], avx2: bool) {
    let w = l.len();
    let np = out.len() / w;
    // The right row reversed, so that the right pixels x − d of increasing d
    // are read forwards: r[x − d] = reversed[W − 1 − x + d]; padded so that
    // whole blocks of `BLOCK` can be read.
    let mut reversed: Vec<u64> = r.iter().rev().copied().collect();
    reversed.resize(w + BLOCK, 0);
    for (x, (&c, costs)) in l.iter().zip(out.chunks_exact_mut(np)).enumerate() {
        let inside = nd.min((x + 1).saturating_sub(min_disp));
        let base = w - 1 - x + min_disp;
        if avx2 {
            #[cfg(target_arch = "x86_64")]
            for (b, out) in costs.chunks_exact_mut(BLOCK).enumerate() {
                let lanes = (b * BLOCK, inside, nd);
                // SAFETY: the caller saw AVX2.
                unsafe { hamming_block_avx2(c, &reversed, base + b * BLOCK, lanes, out) };
            }
        } else {
            for (v, &rv) in costs[..inside].iter_mut().zip(&reversed[base..]) {
                *v = (c ^ rv).count_ones() as u8;
            }
            let (real, padding) = costs.split_at_mut(nd);
            real[inside..].fill(OUTSIDE_COST as u8);
            padding.fill(PAD);
        }
    }
}

/// One block of a pixel's costs, lanes `first..first + BLOCK`:
/// `popcount(c ^ right[at + k])` for the lanes below `inside`, then
/// [`OUTSIDE_COST`] below `nd` and [`PAD`] above, by masks (no calls to
/// fill). Popcounts by nibble table, summed per `u64` by `vpsadbw`; the
/// eight vectors of four sums packed into one by shifts, then put in order
/// by three shuffles.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[inline]
#[target_feature(enable = "avx2")]
#[allow(clippy::erasing_op, clippy::identity_op)] // the unrolled k = 0 and 1
unsafe fn hamming_block_avx2(
    c: u64,
    right: &[u64],
    at: usize,
    (first, inside, nd): (usize, usize, usize),
    out: &mut [u8],
) {
    use std::arch::x86_64::*;
    assert!(out.len() >= BLOCK);
    let iota = _mm256_setr_epi8(
        0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24,
        25, 26, 27, 28, 29, 30, 31,
    );
    // Lanes at or past `limit` (clamped to 0..=BLOCK) as a mask.
    let past = |limit: usize| {
        let limit = limit.saturating_sub(first).min(BLOCK) as i8;
        _mm256_cmpgt_epi8(iota, _mm256_set1_epi8(limit - 1))
    };
    let fixed = _mm256_blendv_epi8(
        _mm256_set1_epi8(OUTSIDE_COST as i8),
        _mm256_set1_epi8(PAD as i8),
        past(nd),
    );
    if first >= inside {
        _mm256_storeu_si256(out.as_mut_ptr().cast(), fixed);
        return;
    }
    let right = &right[at..at + BLOCK];
    #[rustfmt::skip]
    let nibbles = _mm256_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
    );
    let low = _mm256_set1_epi8(0x0F);
    let cv = _mm256_set1_epi64x(c as i64);
    let mut packed = _mm256_setzero_si256();
    // Vector k holds the sums of k·4 + j in its u64 lane j (each below 64),
    // shifted to byte k of the lane: byte 8j + k of `packed`.
    seq_macro::seq!(K in 0..8 {
        let v = _mm256_xor_si256(cv, _mm256_loadu_si256(right.as_ptr().add(4 * K).cast()));
        let counts = _mm256_add_epi8(
            _mm256_shuffle_epi8(nibbles, _mm256_and_si256(v, low)),
            _mm256_shuffle_epi8(nibbles, _mm256_and_si256(_mm256_srli_epi16(v, 4), low)),
        );
        let sums = _mm256_sad_epu8(counts, _mm256_setzero_si256());
        packed = _mm256_or_si256(packed, _mm256_slli_epi64(sums, 8 * K));
    });
    // Per 128-bit lane (j = 0, 1 or 2, 3): bytes ordered (k, j) so that each
    // 16-bit word holds k for both j ...
    #[rustfmt::skip]
    let by_k = _mm256_setr_epi8(
        0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15,
        0, 8, 1, 9, 2, 10, 3, 11, 4, 12, 5, 13, 6, 14, 7, 15,
    );
    let v = _mm256_shuffle_epi8(packed, by_k);
    // ... k 0–3 of both lanes into the low lane, k 4–7 into the high one ...
    let v = _mm256_permute4x64_epi64(v, 0b11_01_10_00);
    // ... and the words of j 0, 1 interleaved with those of j 2, 3: 4k + j.
    let v = _mm256_unpacklo_epi16(v, _mm256_srli_si256(v, 8));
    let v = _mm256_blendv_epi8(v, fixed, past(inside));
    _mm256_storeu_si256(out.as_mut_ptr().cast(), v);
}

/// Values per pixel and path: `[SENTINEL, L(d_min)..L(d_max), padding, SENTINEL, min_k L]`,
/// `np + 3` in all. The sentinels stand for the missing neighbours `d_min − 1`
/// and `d_max + 1` (the padding lanes are [`SENTINEL`] too); the minimum is
/// kept so the next step need not search it. A path's first pixel steps
/// from an all-zero cell, which gives `L = C`.
const fn cell(np: usize) -> usize {
    np + 3
}

/// One path step: `cur[k] = C[k] + min(prev[k], prev[k±1] + P1, min_prev + P2) − min_prev`,
/// on cells laid out as [`cell`] describes, and `cur[k]` added into the
/// sums `acc` (stored when `FIRST`: the first path written into them).
///
/// Path costs fit `u8`: the minimum over `k` of a step's result is at most
/// `C ≤ 62`, so `min_prev + P2 ≤ 62 + MAX_P2 = 255`, and every result is
/// `C + (best − min_prev) ≤ 62 + P2`. The `± 1` neighbours add `P1`
/// saturating: a saturated value is still above `min_prev + P2`, which wins;
/// the padding lanes' [`PAD`] cost saturates them to [`SENTINEL`].
#[inline(always)]
fn step<const FIRST: bool>(
    prev: &[u8],
    cost: &[u8],
    cur: &mut [u8],
    acc: &mut [u16],
    p1: u8,
    p2: u8,
) {
    let np = cost.len();
    let min_prev = prev[np + 2];
    let jump = min_prev + p2;
    let mut min_cur = u8::MAX;
    // Zipped slices (no indexing) so that the loop compiles to vector code.
    let (below, same, above) = (&prev[..np], &prev[1..=np], &prev[2..np + 2]);
    let outs = cur[1..=np].iter_mut().zip(acc.iter_mut());
    let lanes = outs.zip(cost).zip(below.iter().zip(same).zip(above));
    for (((out, sum), &c), ((&b, &s), &a)) in lanes {
        let best = s
            .min(b.saturating_add(p1))
            .min(a.saturating_add(p1))
            .min(jump);
        let v = c.saturating_add(best - min_prev);
        *out = v;
        *sum = if FIRST { 0 } else { *sum } + u16::from(v);
        min_cur = min_cur.min(v);
    }
    cur[np + 2] = min_cur;
}

/// The steps of all `N` paths of a sweep at one pixel: path `p` from the
/// cell at `prev[p]` to the cell at `cur[p]` with penalty `p2[p]`, their
/// costs added into the pixel's `np` sums at `acc` (stored when `FIRST`).
///
/// Raw pointers, because building `N` checked slices per pixel cost more
/// than the steps themselves. The contract of [`PixelSteps::run`] and
/// [`PixelSteps::run_avx2`]: every cell pointer is valid for `cell(np)`
/// bytes, `cost` for `np` bytes and `acc` for `np` sums, and the `cur`
/// cells overlap neither each other nor anything else given.
struct PixelSteps<const N: usize> {
    prev: [*const u8; N],
    cur: [*mut u8; N],
    p2: [u8; N],
    p1: u8,
    np: usize,
    cost: *const u8,
    acc: *mut u16,
}

impl<const N: usize> PixelSteps<N> {
    /// One [`step`] per path.
    ///
    /// # Safety
    /// The pointers keep the contract of [`PixelSteps`].
    #[inline(always)]
    unsafe fn run<const FIRST: bool>(&self) {
        let np = self.np;
        let cost = std::slice::from_raw_parts(self.cost, np);
        let acc = std::slice::from_raw_parts_mut(self.acc, np);
        for p in 0..N {
            let prev = std::slice::from_raw_parts(self.prev[p], cell(np));
            let cur = std::slice::from_raw_parts_mut(self.cur[p], cell(np));
            if FIRST && p == 0 {
                step::<true>(prev, cost, cur, acc, self.p1, self.p2[p]);
            } else {
                step::<false>(prev, cost, cur, acc, self.p1, self.p2[p]);
            }
        }
    }

    /// [`Self::run`] with AVX2 intrinsics, [`BLOCK`] lanes at a time for
    /// every path, the paths' costs summed in registers and added into
    /// `acc` once (the same integers: bit-identical).
    ///
    /// # Safety
    /// The CPU must have AVX2; the pointers keep the contract of [`PixelSteps`].
    #[cfg(target_arch = "x86_64")]
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn run_avx2<const FIRST: bool>(&self) {
        use std::arch::x86_64::*;
        // `$body` once per path with `$p` a constant, so that every path's
        // vectors stay in registers (a loop over paths keeps them in memory).
        macro_rules! each_path {
            ($p:ident => $body:block) => {{
                {
                    let $p = 0;
                    $body
                }
                if N > 1 {
                    let $p = 1;
                    $body
                }
                if N > 2 {
                    let $p = 2;
                    $body
                }
                if N > 3 {
                    let $p = 3;
                    $body
                }
            }};
        }
        let np = self.np;
        debug_assert!(N <= 4 && np % BLOCK == 0);
        let (prev, cur) = (self.prev, self.cur);
        let p1 = _mm256_set1_epi8(self.p1 as i8);
        let mut base = [_mm256_setzero_si256(); N];
        let mut jump = [_mm256_setzero_si256(); N];
        each_path!(p => {
            let min_prev = *prev[p].add(np + 2);
            base[p] = _mm256_set1_epi8(min_prev as i8);
            jump[p] = _mm256_set1_epi8((min_prev + self.p2[p]) as i8);
        });
        let mut mins = [_mm256_set1_epi8(-1); N];
        let acc = self.acc.cast::<__m256i>();
        for b in 0..np / BLOCK {
            let c = _mm256_loadu_si256(self.cost.add(b * BLOCK).cast());
            let (mut lo, mut hi) = if FIRST {
                (_mm256_setzero_si256(), _mm256_setzero_si256())
            } else {
                (
                    _mm256_loadu_si256(acc.add(2 * b)),
                    _mm256_loadu_si256(acc.add(2 * b + 1)),
                )
            };
            each_path!(p => {
                let at = prev[p].add(b * BLOCK);
                let load = |k: usize| _mm256_loadu_si256(at.add(k).cast());
                let (below, same, above) = (load(0), load(1), load(2));
                let near =
                    _mm256_min_epu8(_mm256_adds_epu8(below, p1), _mm256_adds_epu8(above, p1));
                let best = _mm256_min_epu8(_mm256_min_epu8(same, near), jump[p]);
                let v = _mm256_adds_epu8(c, _mm256_sub_epi8(best, base[p]));
                _mm256_storeu_si256(cur[p].add(b * BLOCK + 1).cast(), v);
                mins[p] = _mm256_min_epu8(mins[p], v);
                lo = _mm256_add_epi16(lo, _mm256_cvtepu8_epi16(_mm256_castsi256_si128(v)));
                hi = _mm256_add_epi16(hi, _mm256_cvtepu8_epi16(_mm256_extracti128_si256(v, 1)));
            });
            _mm256_storeu_si256(acc.add(2 * b), lo);
            _mm256_storeu_si256(acc.add(2 * b + 1), hi);
        }
        each_path!(p => {
            let m = mins[p];
            let m = _mm_min_epu8(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
            let m = _mm_min_epu8(m, _mm_srli_si128(m, 8));
            let m = _mm_minpos_epu16(_mm_cvtepu8_epi16(m));
            *cur[p].add(np + 2) = _mm_cvtsi128_si32(m) as u8;
        });
    }
}

/// The cost and sum volumes, kept from one frame to the next: both are
/// entirely overwritten, so a frame of the same size neither allocates nor
/// clears them.
#[derive(Default)]
pub struct SgmBuffers {
    cost: Vec<u8>,
    sum: Vec<u16>,
}

/// Computes the raw SGM disparity (and the right view's map) of gray views.
pub fn sgm(left: &GrayImage, right: &GrayImage, spec: &MatchSpec, buffers: &mut SgmBuffers) -> Raw {
    sgm_with(left, right, spec, buffers, crate::wta::avx2_available())
}

/// [`sgm`] with the AVX2 kernels (`use_avx2`, only if the CPU has it) or the
/// portable ones.
fn sgm_with(
    left: &GrayImage,
    right: &GrayImage,
    spec: &MatchSpec,
    buffers: &mut SgmBuffers,
    use_avx2: bool,
) -> Raw {
    let (w, h) = left.dims();
    let (cl, cr) = rayon::join(
        || census_with(left, use_avx2),
        || census_with(right, use_avx2),
    );
    let SgmBuffers { cost, sum } = buffers;
    let (nd, np) = (spec.ndisp(), spec.ndisp().next_multiple_of(BLOCK));
    cost_volume(&cl, &cr, w, (nd, np), spec.min_disp, cost, use_avx2);
    drop((cl, cr));
    let vol = Volume {
        w,
        h,
        nd,
        np,
        min_disp: spec.min_disp,
        cost,
        img: left,
        p: spec.sgm,
        p2_by_step: p2_table(&spec.sgm),
        subpixel: spec.refine.subpixel,
    };
    sum.resize(w * h * np, 0);
    let mut disparity = DisparityMap::new(w, h, f32::INFINITY);
    let mut right_map = DisparityMap::new(w, h, f32::INFINITY);
    let rows: Vec<Mutex<SumRow>> = sum
        .chunks_mut((w * np).max(1))
        .zip(disparity.as_mut_slice().chunks_mut(w.max(1)))
        .zip(right_map.as_mut_slice().chunks_mut(w.max(1)))
        .map(|((sums, left), right)| {
            Mutex::new(SumRow {
                sums,
                left,
                right,
                visited: false,
            })
        })
        .collect();
    let run = |downward: bool| {
        let eight = vol.p.paths == 8;
        #[cfg(target_arch = "x86_64")]
        if use_avx2 {
            // SAFETY: AVX2 and POPCNT presence was checked at run time.
            return unsafe {
                if eight {
                    sweep_avx2::<4>(&vol, &rows, downward)
                } else {
                    sweep_avx2::<2>(&vol, &rows, downward)
                }
            };
        }
        if eight {
            sweep::<4>(&vol, &rows, downward, false)
        } else {
            sweep::<2>(&vol, &rows, downward, false)
        }
    };
    rayon::join(|| run(true), || run(false));
    drop(rows);
    Raw {
        disparity,
        right: Some(right_map),
    }
}

/// A row of the sum volume and of both disparity maps, shared by the two
/// sweeps; whichever visits it second finds `visited` set and computes the
/// disparities while the sums are still in cache.
struct SumRow<'a> {
    sums: &'a mut [u16],
    left: &'a mut [f32],
    right: &'a mut [f32],
    visited: bool,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn sweep_avx2<const N: usize>(vol: &Volume, rows: &[Mutex<SumRow>], downward: bool) {
    sweep::<N>(vol, rows, downward, true)
}

/// Which way the paths from the previous row lean, in the direction of
/// travel: straight, then the two diagonals (8 paths).
const LEANS: [isize; 3] = [0, -1, 1];

/// One of the two sweeps over the image, each run by its own worker, with
/// `N` paths: the downward sweep aggregates the left-to-right path (path 0)
/// and the paths from the row above (straight, and both diagonals for 8
/// paths), the upward sweep the right-to-left path and the paths from the
/// row below. Every pixel's path costs are added into its sums in one visit
/// ([`PixelSteps`]), so the sum and cost volumes are read twice in all; the
/// two sweeps run in parallel, meeting in the middle, and a row is locked
/// while a sweep works on it. `avx2`: the CPU has it.
#[inline(always)]
fn sweep<const N: usize>(vol: &Volume, rows: &[Mutex<SumRow>], downward: bool, avx2: bool) {
    let (w, h, np) = (vol.w, vol.h, vol.np);
    let stride = cell(np);
    let p1 = vol.p.p1 as u8;
    let zero = vec![0u8; stride];
    let mut prev = vec![SENTINEL; (N - 1) * w * stride];
    let mut cur = prev.clone();
    let (mut along_prev, mut along_cur) = (vec![SENTINEL; stride], vec![SENTINEL; stride]);
    for i in 0..h {
        let y = if downward { i } else { h - 1 - i };
        let line = vol.img.row(y);
        let line_prev = (i > 0).then(|| vol.img.row(if downward { y - 1 } else { y + 1 }));
        let mut row = rows[y].lock().unwrap_or_else(|e| e.into_inner());
        let row = &mut *row;
        let first = !row.visited;
        let costs = &vol.cost[y * w * np..(y + 1) * w * np];
        let sums = &mut row.sums[..w * np];
        // Every pointer below is to a whole cell of `zero`, `prev`, `cur`,
        // `along_prev` or `along_cur`, or to pixel x's lanes of `costs` and
        // `sums`, as `PixelSteps` requires; the cur cells are distinct.
        let (prev_cells, cur_cells) = (prev.as_ptr(), cur.as_mut_ptr());
        for j in 0..w {
            let x = if downward { j } else { w - 1 - j };
            let mut steps = PixelSteps {
                prev: [zero.as_ptr(); N],
                cur: [along_cur.as_mut_ptr(); N],
                p2: [0; N],
                p1,
                np,
                cost: costs[x * np..].as_ptr(),
                acc: sums[x * np..].as_mut_ptr(),
            };
            if j > 0 {
                let xa = if downward { x - 1 } else { x + 1 };
                steps.prev[0] = along_prev.as_ptr();
                steps.p2[0] = vol.p2(line[x], line[xa]);
            }
            for p in 1..N {
                steps.cur[p] = cur_cells.wrapping_add(((p - 1) * w + x) * stride);
                let lean = if downward {
                    LEANS[p - 1]
                } else {
                    -LEANS[p - 1]
                };
                let xp = x.wrapping_add_signed(lean);
                if let Some(above) = line_prev.filter(|_| xp < w) {
                    steps.prev[p] = prev_cells.wrapping_add(((p - 1) * w + xp) * stride);
                    steps.p2[p] = vol.p2(line[x], above[xp]);
                }
            }
            // SAFETY: the pointers keep the contract (see above); AVX2 is
            // used only when the caller saw it.
            unsafe {
                match (avx2, first) {
                    #[cfg(target_arch = "x86_64")]
                    (true, true) => steps.run_avx2::<true>(),
                    #[cfg(target_arch = "x86_64")]
                    (true, false) => steps.run_avx2::<false>(),
                    (_, true) => steps.run::<true>(),
                    (_, false) => steps.run::<false>(),
                }
            }
            std::mem::swap(&mut along_prev, &mut along_cur);
        }
        if !first {
            select_row(vol, row.sums, row.left, row.right, avx2);
        }
        row.visited = true;
        std::mem::swap(&mut prev, &mut cur);
    }
}

/// Winner-take-all on a row of summed costs `s_row`, for the left view and
/// the right view; `avx2`: the CPU has it.
fn select_row(vol: &Volume, s_row: &[u16], lrow: &mut [f32], rrow: &mut [f32], avx2: bool) {
    let (w, nd, np) = (vol.w, vol.nd, vol.np);
    assert!(s_row.len() >= w * np && lrow.len() >= w && rrow.len() >= w);
    // The right pixel x − d_min − k costs what left x does at lane
    // k: a running minimum per right pixel, kept at W − 1 − xr so
    // that the lanes of one left pixel are contiguous.
    let (mut best, mut lane) = (vec![u16::MAX; w + np], vec![0u16; w + np]);
    for x in vol.min_disp..w {
        // Padded to whole blocks of lanes, as the lane operations need.
        let costs = &s_row[x * np..(x + 1) * np];
        let valid = nd.min(x - vol.min_disp + 1);
        let at = w - 1 - (x - vol.min_disp);
        let (best, lane) = (&mut best[at..at + np], &mut lane[at..at + np]);
        let k = match avx2 {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the caller saw AVX2; whole blocks of `np` lanes.
            true => unsafe { winner_avx2(costs, valid, best, lane) },
            _ => {
                // SAFETY: the portable lane operations need nothing.
                unsafe { Portable::min_update(best, lane, costs, valid) };
                // SAFETY: as above.
                unsafe { Portable::argmin(costs, valid).0 }
            }
        };
        let mut d = (vol.min_disp + k) as f32;
        if vol.subpixel && k > 0 && k + 1 < valid {
            d += parabola(costs[k - 1] as f32, costs[k] as f32, costs[k + 1] as f32);
        }
        lrow[x] = d;
    }
    for (xr, out) in rrow.iter_mut().enumerate() {
        let at = w - 1 - xr;
        if best[at] != u16::MAX {
            *out = (vol.min_disp + lane[at] as usize) as f32;
        }
    }
}

/// One pixel of [`select_row`] in one pass over its lanes: the first lane
/// of the smallest of `costs[..valid]`, and the running minimum `best`
/// (with its lane in `lane`) of the right-view pixels these lanes reach.
/// The same results as [`LaneOps::argmin`] and [`LaneOps::min_update`].
///
/// # Safety
/// The CPU must have AVX2; `costs`, `best` and `lane` hold whole blocks of
/// 16 lanes covering `valid ≥ 1`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn winner_avx2(costs: &[u16], valid: usize, best: &mut [u16], lane: &mut [u16]) -> usize {
    use std::arch::x86_64::*;
    const LANES: usize = 16;
    let blocks = valid.div_ceil(LANES);
    assert!(valid >= 1 && costs.len() >= blocks * LANES);
    assert!(best.len() >= blocks * LANES && lane.len() >= blocks * LANES);
    let iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let (ones, sign) = (_mm256_set1_epi16(-1), _mm256_set1_epi16(i16::MIN));
    let (c_at, b_at, l_at) = (costs.as_ptr(), best.as_mut_ptr(), lane.as_mut_ptr());
    let mut m = ones;
    for b in 0..blocks {
        let left = (valid - b * LANES).min(LANES) as i16;
        // Lanes past `valid` become the largest cost, which never wins.
        let inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(left), iota);
        let c = _mm256_loadu_si256(c_at.add(b * LANES).cast());
        let c = _mm256_or_si256(c, _mm256_andnot_si256(inside, ones));
        m = _mm256_min_epu16(m, c);
        let (bp, lp) = (
            b_at.add(b * LANES).cast::<__m256i>(),
            l_at.add(b * LANES).cast::<__m256i>(),
        );
        let old = _mm256_loadu_si256(bp);
        // Unsigned c < old, as a signed comparison of sign-flipped values.
        let less = _mm256_cmpgt_epi16(_mm256_xor_si256(old, sign), _mm256_xor_si256(c, sign));
        _mm256_storeu_si256(bp, _mm256_min_epu16(old, c));
        let index = _mm256_add_epi16(iota, _mm256_set1_epi16((b * LANES) as i16));
        _mm256_storeu_si256(lp, _mm256_blendv_epi8(_mm256_loadu_si256(lp), index, less));
    }
    let half = _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    let target = _mm256_set1_epi16(_mm_extract_epi16(_mm_minpos_epu16(half), 0) as i16);
    // The first lane equal to the minimum is a valid one: lanes past
    // `valid` come after every valid lane.
    for b in 0..blocks {
        let c = _mm256_loadu_si256(c_at.add(b * LANES).cast());
        let hit = _mm256_movemask_epi8(_mm256_cmpeq_epi16(c, target)) as u32;
        if hit != 0 {
            return b * LANES + hit.trailing_zeros() as usize / 2;
        }
    }
    unreachable!("the minimum is one of the lanes")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 cost rows equal the portable ones (Hamming distances).
    #[test]
    fn avx2_cost_rows_equal_portable_rows() {
        if !crate::wta::avx2_available() {
            return;
        }
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s & ((1 << 62) - 1)
        };
        for (w, nd, min_disp) in [(1, 1, 0), (7, 3, 0), (40, 33, 2), (70, 64, 0), (100, 90, 5)] {
            let np = usize::next_multiple_of(nd, BLOCK);
            let l: Vec<u64> = (0..w).map(|_| next()).collect();
            let r: Vec<u64> = (0..w).map(|_| next()).collect();
            let (mut a, mut b) = (vec![0u8; w * np], vec![1u8; w * np]);
            cost_row(&l, &r, min_disp, nd, &mut a, false);
            cost_row(&l, &r, min_disp, nd, &mut b, true);
            assert_eq!(a, b, "w {w} nd {nd}");
            let x = w - 1;
            if x >= min_disp {
                assert_eq!(u32::from(a[x * np]), (l[x] ^ r[x - min_disp]).count_ones());
            }
        }
    }

    /// Whole SGM runs, AVX2 against portable, bit for bit, on random views
    /// of awkward sizes and ranges (a few pixels, ranges past a block).
    #[test]
    fn avx2_and_portable_sgm_agree() {
        if !crate::wta::avx2_available() {
            return;
        }
        let mut s = 0x1234_5678_9ABC_DEF1u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let cases = [
            (2, 1, 0, 1, 8),
            (5, 3, 1, 3, 4),
            (37, 9, 0, 35, 8),
            (70, 6, 3, 40, 8),
        ];
        for (w, h, min_disp, max_disp, paths) in cases {
            let left = GrayImage::from_fn(w, h, |_, _| (next() >> 58) as u8 * 16);
            let right = GrayImage::from_fn(w, h, |_, _| (next() >> 58) as u8 * 16);
            let mut spec = MatchSpec::new(crate::Algorithm::Sgm, min_disp, max_disp).unwrap();
            spec.sgm.paths = paths;
            let mut buffers = SgmBuffers::default();
            let a = sgm_with(&left, &right, &spec, &mut buffers, false);
            let b = sgm_with(&left, &right, &spec, &mut buffers, true);
            let bits =
                |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&a.disparity),
                bits(&b.disparity),
                "{w}x{h} {min_disp}..={max_disp}"
            );
            let (ar, br) = (a.right.unwrap(), b.right.unwrap());
            assert_eq!(bits(&ar), bits(&br));
        }
    }

    #[test]
    fn step_follows_the_recurrence() {
        // From the zero cell a path starts at its costs: L = C.
        let mut prev = [SENTINEL; cell(3)];
        let mut acc = [0; 3];
        step::<true>(&[0; cell(3)], &[5, 0, 9], &mut prev, &mut acc, 2, 6);
        assert_eq!(prev, [SENTINEL, 5, 0, 9, SENTINEL, 0]);
        assert_eq!(acc, [5, 0, 9]);
        let cost = [3, 3, 3];
        let mut cur = [0; cell(3)];
        let mut acc = [10; 3];
        step::<false>(&prev, &cost, &mut cur, &mut acc, 2, 6);
        // min_prev 0: k0 min(5, 0+2, jump 6) = 2 → 3+2; k1: 0 → 3; k2: min(9, 0+2) = 2 → 5.
        assert_eq!(cur, [0, 5, 3, 5, 0, 3]);
        assert_eq!(acc, [15, 13, 15]);
        step::<true>(&prev, &cost, &mut cur, &mut acc, 2, 6);
        assert_eq!(acc, [5, 3, 5]);
    }

    /// The AVX2 pixel kernel equals one portable step per path, on cells
    /// that paths can reach (built by stepping from random costs).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_pixel_steps_equal_portable_steps() {
        if !crate::wta::avx2_available() {
            return;
        }
        fn steps(
            prev: &[Vec<u8>],
            cur: &mut [Vec<u8>],
            acc: &mut [u16],
            cost: &[u8],
            p1: u8,
        ) -> PixelSteps<4> {
            PixelSteps {
                prev: std::array::from_fn(|p| prev[p].as_ptr()),
                cur: std::array::from_fn(|p| cur[p].as_mut_ptr()),
                p2: [90, 40, 193, 30],
                p1,
                np: cost.len(),
                cost: cost.as_ptr(),
                acc: acc.as_mut_ptr(),
            }
        }
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut costs = |nd: usize, np: usize| -> Vec<u8> {
            let mut c: Vec<u8> = (0..nd)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s % 63) as u8
                })
                .collect();
            c.resize(np, PAD);
            c
        };
        for (nd, p1) in [
            (1usize, 3u8),
            (5, 24),
            (31, 1),
            (32, 29),
            (33, 7),
            (64, 24),
            (100, 12),
        ] {
            let np = nd.next_multiple_of(BLOCK);
            // Four reachable previous cells: a few steps from the zero cell.
            let prev: Vec<Vec<u8>> = (0..4)
                .map(|p| {
                    let mut now = vec![0u8; cell(np)];
                    for _ in 0..=p {
                        let mut out = vec![SENTINEL; cell(np)];
                        step::<true>(&now, &costs(nd, np), &mut out, &mut vec![0; np], p1, 90);
                        now = out;
                    }
                    now
                })
                .collect();
            let cost = costs(nd, np);
            for first in [false, true] {
                let (mut cur_a, mut acc_a) = (vec![vec![SENTINEL; cell(np)]; 4], vec![7u16; np]);
                let (mut cur_b, mut acc_b) = (cur_a.clone(), acc_a.clone());
                let a = steps(&prev, &mut cur_a, &mut acc_a, &cost, p1);
                let b = steps(&prev, &mut cur_b, &mut acc_b, &cost, p1);
                // SAFETY: AVX2 was detected above; whole cells and lanes.
                unsafe {
                    if first {
                        a.run::<true>();
                        b.run_avx2::<true>();
                    } else {
                        a.run::<false>();
                        b.run_avx2::<false>();
                    }
                }
                assert_eq!((cur_a, acc_a), (cur_b, acc_b), "nd {nd}, first {first}");
            }
        }
    }

    #[test]
    fn bad_penalties_are_rejected() {
        assert!(SgmParams {
            paths: 6,
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(SgmParams {
            p1: 10,
            p2: 5,
            ..Default::default()
        }
        .validate()
        .is_err());
    }
}
