//! SGM's path aggregation: the step of the recurrence on `u8` path costs,
//! all of a pixel's paths at once ([`PixelSteps`], portable and AVX2), and
//! the two sweeps, down and up, that add them into the sum volume.

use std::sync::Mutex;

use super::select::select_row;
#[cfg(target_arch = "x86_64")]
use super::BLOCK;
use super::{SumRow, Volume, SENTINEL};

/// Values per pixel and path: `[SENTINEL, L(d_min)..L(d_max), padding, SENTINEL, min_k L]`,
/// `np + 3` in all. The sentinels stand for the missing neighbours `d_min − 1`
/// and `d_max + 1` (the padding lanes are [`SENTINEL`] too); the minimum is
/// kept so the next step need not search it. A path's first pixel steps
/// from an all-zero cell, which gives `L = C`.
pub(super) const fn cell(np: usize) -> usize {
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
/// the padding lanes' [`PAD`](super::PAD) cost saturates them to [`SENTINEL`].
#[inline(always)]
pub(super) fn step<const FIRST: bool>(
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
pub(super) struct PixelSteps<const N: usize> {
    pub(super) prev: [*const u8; N],
    pub(super) cur: [*mut u8; N],
    pub(super) p2: [u8; N],
    pub(super) p1: u8,
    pub(super) np: usize,
    pub(super) cost: *const u8,
    pub(super) acc: *mut u16,
}

impl<const N: usize> PixelSteps<N> {
    /// One [`step`] per path.
    ///
    /// # Safety
    /// The pointers keep the contract of [`PixelSteps`].
    #[inline(always)]
    pub(super) unsafe fn run<const FIRST: bool>(&self) {
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
    pub(super) unsafe fn run_avx2<const FIRST: bool>(&self) {
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

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
pub(super) unsafe fn sweep_avx2<const N: usize>(
    vol: &Volume,
    rows: &[Mutex<SumRow>],
    downward: bool,
) {
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
pub(super) fn sweep<const N: usize>(
    vol: &Volume,
    rows: &[Mutex<SumRow>],
    downward: bool,
    avx2: bool,
) {
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
