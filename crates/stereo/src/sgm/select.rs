//! SGM's disparity selection: winner-take-all on a row of summed costs,
//! for the left view and, from the same sums, the right view (the
//! left-right check's input), with the parabola fit when asked for.

use super::Volume;
use crate::lanes::{LaneOps, Portable};
use crate::refine::parabola;

/// Winner-take-all on a row of summed costs `s_row`, for the left view and
/// the right view; `avx2`: the CPU has it.
pub(super) fn select_row(
    vol: &Volume,
    s_row: &[u16],
    lrow: &mut [f32],
    rrow: &mut [f32],
    avx2: bool,
) {
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
