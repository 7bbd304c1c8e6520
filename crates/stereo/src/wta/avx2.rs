//! The AVX2 band loop of the default setting (no min filter, no right
//! view's map; with or without the check of
//! [`WtaMatcher::compute_checked_into`](super::WtaMatcher::compute_checked_into)),
//! with a pixel's `B` blocks of cost lanes in registers:
//!
//! - **One pass over the column sums per row.** The column entering the
//!   window of pixel `x` is updated (entering row added, leaving row
//!   subtracted) just before the window sum slides over it, so each row
//!   reads the column sums, larger than L1, once instead of twice.
//! - **The window sum and its argmin stay in registers**; the lanes equal
//!   to the minimum become one bit each (packed to bytes) and the first
//!   set bit is the winner, without a branch per block.
//! - **The check's running minimum per right pixel is a shift register.**
//!   Lane `k` of pixel `x` is the right pixel `x − d_min − k`, so from one
//!   pixel to the next the minima move up one lane; the top lane leaves,
//!   final, for memory. Kept in memory (as the general loop does), each
//!   pixel's update loaded what the previous one had just stored, one
//!   lane off, which the CPU cannot forward from its store buffer.
//!
//! It gives the general loop's results exactly (same sums, same tie rule).

use std::arch::x86_64::*;

use super::driver::{lanes, Band, Job};
use super::portable::accumulate_row;
use super::winner::{check_row, plain, Disparity, Winner};
use crate::lanes::{Avx2, LaneOps, LANES};

/// Runs [`super::portable::band_with`]'s work for `job` without a min
/// filter nor a right map, into `out` (the band's rows); false, doing
/// nothing, when a pixel has more blocks of lanes than this loop keeps in
/// registers.
///
/// # Safety
/// The CPU must have AVX2.
pub(super) unsafe fn band<T: Disparity>(job: &Job, band: &mut Band, out: &mut [T]) -> bool {
    debug_assert!(job.params.min_filter <= 1);
    // SAFETY: forwarded from this function's contract.
    unsafe {
        match lanes(job.params.ndisp) / LANES {
            1 => band_blocks::<1, T>(job, band, out),
            2 => band_blocks::<2, T>(job, band, out),
            3 => band_blocks::<3, T>(job, band, out),
            4 => band_blocks::<4, T>(job, band, out),
            5 => band_blocks::<5, T>(job, band, out),
            6 => band_blocks::<6, T>(job, band, out),
            _ => return false,
        }
    }
    true
}

/// A pixel's cost lanes, `B` blocks of [`LANES`].
type Lanes<const B: usize> = [__m256i; B];

/// [`band`] with `B` blocks of lanes.
#[target_feature(enable = "avx2")]
unsafe fn band_blocks<const B: usize, T: Disparity>(job: &Job, band: &mut Band, out: &mut [T]) {
    let (w, h) = job.left.dims();
    let p = job.params;
    let (nd, r) = (B * LANES, p.block / 2);
    let clamp_y = |y: isize| y.clamp(0, h as isize - 1) as usize;
    let colsum = &mut band.colsum[..w * nd];
    colsum.fill(0);
    for dy in -(r as isize)..=r as isize {
        let y = clamp_y(job.y0 as isize + dy);
        // SAFETY: the CPU has AVX2 (this function's contract).
        unsafe { accumulate_row::<Avx2>(job, colsum, &mut [], y, None) };
    }
    for (i, out_row) in out.chunks_exact_mut(w).enumerate() {
        let y = (job.y0 + i) as isize;
        // The band's first row has its column sums from the priming.
        let rows = (i > 0).then(|| (clamp_y(y + r as isize), clamp_y(y - r as isize - 1)));
        // SAFETY: as above.
        unsafe { row::<B, T>(job, band, rows, out_row) };
    }
}

/// One output row: column `x`'s sums updated with `rows` (entering,
/// leaving; none for the band's first row) as the window reaches it, the
/// window sums slid along the row, each pixel's winner and, with the
/// check, the running minima per right pixel (into `band.right_best` at
/// `W − 1 − xr`, as [`check_row`] reads them).
#[target_feature(enable = "avx2")]
unsafe fn row<const B: usize, T: Disparity>(
    job: &Job,
    band: &mut Band,
    rows: Option<(usize, usize)>,
    out: &mut [T],
) {
    let w = out.len();
    let p = job.params;
    let (nd, r, md) = (B * LANES, p.block / 2, p.min_disp);
    let colsum = &mut band.colsum[..w * nd];
    // The entering and leaving rows' left samples and reversed right rows.
    let rows = rows.map(|(entering, leaving)| {
        let samples = |y| (job.left.row(y), job.reversed_row(y));
        (samples(entering), samples(leaving))
    });
    let update = |colsum: &mut [u16], x: usize| {
        if let Some(((left, right), (gone_left, gone_right))) = rows {
            let at = job.right_start(x)..job.right_start(x) + nd;
            let gone = (gone_left[x], &gone_right[at.clone()]);
            let col = &mut colsum[x * nd..(x + 1) * nd];
            // SAFETY: the CPU has AVX2 (this function's contract).
            unsafe { Avx2::accumulate(col, left[x], &right[at], Some(gone)) };
        }
    };
    let load = |colsum: &[u16], x: usize| -> Lanes<B> {
        let col = &colsum[x.min(w - 1) * nd..][..nd];
        // SAFETY: in bounds (a block of `col` each); AVX2 as above.
        std::array::from_fn(|b| unsafe { _mm256_loadu_si256(col[b * LANES..].as_ptr().cast()) })
    };
    // The window of pixel 0 (columns −r..=r, clamped).
    for x in 0..=r.min(w - 1) {
        update(colsum, x);
    }
    let mut cost = [_mm256_setzero_si256(); B];
    for dx in -(r as isize)..=r as isize {
        add(&mut cost, &load(colsum, dx.max(0) as usize));
    }
    let ones = _mm256_set1_epi16(-1);
    let mut right = [ones; B];
    let (right_best, winners) = (&mut band.right_best, &mut band.winners);
    // The costs are spilled for the winner only if it needs them.
    let plain = plain(p);
    for (x, d) in out.iter_mut().enumerate() {
        if x > 0 {
            if x + r < w {
                update(colsum, x + r);
            }
            add(&mut cost, &load(colsum, x + r));
            sub(&mut cost, &load(colsum, x.saturating_sub(r + 1)));
        }
        // Disparities d_min.. up to x (none below d_min).
        let valid = (x + 1).saturating_sub(md).min(p.ndisp);
        if valid == 0 {
            *d = T::NONE;
            continue;
        }
        let costs = masked(&cost, valid);
        let (lane, best) = argmin(&costs);
        let mut spilled = [[0u16; LANES]; B];
        *d = if plain {
            T::at(lane, p)
        } else {
            store(&mut spilled, &costs);
            T::winner(spilled.as_flattened(), valid, (lane, best), p)
        };
        if job.check {
            store(&mut spilled, &right);
            winners[x] = Winner {
                lane: lane as u16,
                cost: best,
                first: spilled.as_flattened()[lane] > best,
            };
            for (m, &c) in right.iter_mut().zip(&costs) {
                *m = _mm256_min_epu16(*m, c);
            }
            // The top lane, right pixel x − d_min − (nd − 1), is final.
            if let Some(xr) = (x - md).checked_sub(nd - 1) {
                right_best[w - 1 - xr] = _mm256_extract_epi16::<15>(right[B - 1]) as u16;
            }
            shift_up(&mut right, ones);
        }
    }
    if job.check {
        // The minima still in the register after the last pixel: lane k is
        // the right pixel w − d_min − 1 − k (one lane shifted since).
        let mut spilled = [[0u16; LANES]; B];
        store(&mut spilled, &right);
        let lanes = &spilled.as_flattened()[1..];
        for (k, &m) in lanes.iter().enumerate() {
            if let Some(xr) = (w - 1).checked_sub(md + k) {
                right_best[w - 1 - xr] = m;
            }
        }
        check_row(out, winners, right_best, md);
    }
}

/// `acc += a`, lane by lane (wrapping).
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn add<const B: usize>(acc: &mut Lanes<B>, a: &Lanes<B>) {
    for (v, &a) in acc.iter_mut().zip(a) {
        *v = _mm256_add_epi16(*v, a);
    }
}

/// `acc −= a`, lane by lane (wrapping).
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn sub<const B: usize>(acc: &mut Lanes<B>, a: &Lanes<B>) {
    for (v, &a) in acc.iter_mut().zip(a) {
        *v = _mm256_sub_epi16(*v, a);
    }
}

/// Writes `v` to `out`.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn store<const B: usize>(out: &mut [[u16; LANES]; B], v: &Lanes<B>) {
    for (o, &v) in out.iter_mut().zip(v) {
        // A block of LANES u16 holds one vector.
        _mm256_storeu_si256(o.as_mut_ptr().cast(), v);
    }
}

/// `cost` with the lanes from `valid` on set to the largest cost, which
/// never wins nor lowers a minimum.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn masked<const B: usize>(cost: &Lanes<B>, valid: usize) -> Lanes<B> {
    if valid == B * LANES {
        return *cost;
    }
    let iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    std::array::from_fn(|b| {
        let left = valid as isize - (b * LANES) as isize;
        let inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(left.clamp(0, 16) as i16), iota);
        _mm256_or_si256(cost[b], _mm256_andnot_si256(inside, _mm256_set1_epi16(-1)))
    })
}

/// The index and value of the smallest lane, the lowest index winning ties.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn argmin<const B: usize>(costs: &Lanes<B>) -> (usize, u16) {
    let m = costs[1..]
        .iter()
        .fold(costs[0], |m, &c| _mm256_min_epu16(m, c));
    let half = _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256::<1>(m));
    let best = _mm_extract_epi16::<0>(_mm_minpos_epu16(half)) as u16;
    let target = _mm256_set1_epi16(best as i16);
    // Two blocks at a time: their lanes equal to the minimum as bytes in
    // lane order (the pack interleaves 128-bit halves; the permute puts
    // them back), one bit per lane.
    for pair in 0..B.div_ceil(2) {
        let hit = |b: usize| match costs.get(b) {
            Some(&c) => _mm256_cmpeq_epi16(c, target),
            None => _mm256_setzero_si256(),
        };
        let bytes = _mm256_packs_epi16(hit(2 * pair), hit(2 * pair + 1));
        let bits = _mm256_movemask_epi8(_mm256_permute4x64_epi64::<0b11_01_10_00>(bytes));
        if bits != 0 {
            return (2 * pair * LANES + bits.trailing_zeros() as usize, best);
        }
    }
    unreachable!("the minimum is one of the lanes")
}

/// Moves every lane up by one across the blocks (lane `k` to `k + 1`);
/// lane 0 takes `fill`'s, the top lane leaves.
#[inline]
#[target_feature(enable = "avx2")]
unsafe fn shift_up<const B: usize>(v: &mut Lanes<B>, fill: __m256i) {
    let mut below = fill;
    for v in v.iter_mut() {
        // [below's high half, v's low half], then per 128-bit half the top
        // lane of the half before it enters at the bottom.
        let t = _mm256_permute2x128_si256::<0x03>(*v, below);
        below = *v;
        *v = _mm256_alignr_epi8::<14>(*v, t);
    }
}
