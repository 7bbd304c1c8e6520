//! SGM's cost volume: the census Hamming distance of every pixel and
//! disparity, `u8`, computed once for all paths, with an AVX2 kernel and a
//! portable twin that give the same bytes.

use rayon::prelude::*;

use super::{BLOCK, OUTSIDE_COST, PAD};

/// The census Hamming costs of every pixel and disparity, `u8`, computed
/// once for all paths, `np` lanes per pixel.
pub(super) fn cost_volume(
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
pub(super) fn cost_row(
    l: &[u64],
    r: &[u64],
    min_disp: usize,
    nd: usize,
    out: &mut [u8],
    avx2: bool,
) {
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
