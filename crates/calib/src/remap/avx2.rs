//! The inside pass of an RGB remap in AVX2, four output pixels a step.
//!
//! The portable blend packs a pixel's channels into lanes of a `u64` and
//! multiplies each neighbour by its weight; most of its time goes into
//! moving bytes into lanes. Here each pixel's two source rows come in
//! with two 8-byte loads (top-left and top-right neighbours, then the
//! two below), one shuffle lines their bytes up channel by channel, and
//! the bilinear weights, which are a product `w(fx, fy) = g(fx)·g(fy)`
//! of the two fractions' weights ([`separable_weights`]), are applied as
//! two multiply-adds: horizontally on bytes (`vpmaddubsw`, fraction
//! weights up to 32), then vertically on the 16-bit sums (`vpmaddwd`).
//! Every sum is exact, so the rounded result is the portable blend's, bit
//! for bit (`Σ p·w + 512 >> 10`, which is OpenCV's `INTER_REMAP_COEF_BITS`
//! = 15 rounding with weights 32 times these).

use std::arch::x86_64::*;

use super::{Rgb, FRACTION_BITS, OUTSIDE, STEPS, TABLE};

/// Per weight index (`fy·32 + fx`, as in the portable table): bytes 0–1
/// the horizontal weights `32 − fx, fx`, bytes 2–5 the vertical ones
/// `32 − fy, fy` as little-endian `u16`; zero for [`OUTSIDE`] and above.
pub(super) fn separable_weights() -> Box<[u64; TABLE]> {
    let mut table = Box::new([0u64; TABLE]);
    for (i, entry) in table.iter_mut().enumerate().take(OUTSIDE as usize) {
        let (fx, fy) = (i as u64 % STEPS as u64, i as u64 >> FRACTION_BITS);
        let (gx, gy) = (STEPS as u64 - fx, STEPS as u64 - fy);
        *entry = gx | fx << 8 | gy << 16 | fy << 32;
    }
    table
}

/// Blends the output pixels `out` (the first `out.len()` of the map) from
/// `src` with the map's source offsets `offset`, weight indices `weight`
/// and the [`separable_weights`] `table`, four at a time; a group with a
/// source read past `src`'s end (none from a map of `src`'s size but the
/// last pixel's) and the last `out.len() % 4` pixels are left to `rest`
/// (the portable blend of one pixel, given its index).
///
/// # Safety
/// The CPU must have AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn blend_inside(
    src: &[Rgb],
    stride: usize,
    offset: &[u32],
    weight: &[u16],
    table: &[u64; TABLE],
    out: &mut [Rgb],
    mut rest: impl FnMut(usize, &mut Rgb),
) {
    // The last top-left offset whose 8-byte read of the row below stays in
    // `src` (3·(off + stride) + 8 ≤ 3·len).
    let limit = (src.len().checked_sub(stride + 3)).map_or(-1, |l| l as i64);
    let bytes = src.as_ptr().cast::<u8>();
    // Each 128-bit lane: top-left r g b, top-right r g b, 2 bytes, then the
    // bottom pair; to r (tl tr bl br), g (...), b (...).
    let by_channel = _mm256_broadcastsi128_si256(_mm_setr_epi8(
        0, 3, 8, 11, 1, 4, 9, 12, 2, 5, 10, 13, -1, -1, -1, -1,
    ));
    let horizontal = _mm256_broadcastsi128_si256(_mm_setr_epi8(
        0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1,
    ));
    let vertical = _mm256_broadcastsi128_si256(_mm_setr_epi8(
        2, 3, 4, 5, 2, 3, 4, 5, 2, 3, 4, 5, 2, 3, 4, 5,
    ));
    let half = _mm256_set1_epi32(1 << (2 * FRACTION_BITS - 1));
    let compact = _mm_setr_epi8(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, -1, -1, -1, -1);
    // One pixel: its neighbours and weights, in a 128-bit lane each.
    let load = |i: usize| -> (__m128i, __m128i) {
        let off = offset[i] as usize;
        // SAFETY: the group's offsets are at most `limit`, so both 8-byte
        // reads are inside `src`; the weight index is masked into `table`.
        unsafe {
            let top = _mm_loadl_epi64(bytes.add(3 * off).cast());
            let below = bytes.add(3 * (off + stride)).cast::<f64>();
            let pixels = _mm_castpd_si128(_mm_loadh_pd(_mm_castsi128_pd(top), below));
            let w = table[usize::from(weight[i]) & (TABLE - 1)];
            (pixels, _mm_cvtsi64_si128(w as i64))
        }
    };
    // Two pixels, one per lane: their channels' rounded sums as `i32`
    // (r, g, b, 0 per lane).
    let blend2 = |i: usize, j: usize| -> __m256i {
        let ((pi, wi), (pj, wj)) = (load(i), load(j));
        let pixels = _mm256_shuffle_epi8(_mm256_set_m128i(pj, pi), by_channel);
        let w = _mm256_set_m128i(wj, wi);
        let rows = _mm256_maddubs_epi16(pixels, _mm256_shuffle_epi8(w, horizontal));
        let sum = _mm256_madd_epi16(rows, _mm256_shuffle_epi8(w, vertical));
        _mm256_srli_epi32::<{ 2 * FRACTION_BITS as i32 }>(_mm256_add_epi32(sum, half))
    };
    let groups = out.len() / 4;
    let out_bytes = out.as_mut_ptr().cast::<u8>();
    for g in 0..groups {
        let k = 4 * g;
        let o = &offset[k..k + 4];
        if i64::from(o[0].max(o[1]).max(o[2]).max(o[3])) > limit {
            for (i, px) in out[k..k + 4].iter_mut().enumerate() {
                rest(k + i, px);
            }
            continue;
        }
        // Lane 0 holds pixels 0 and 2, lane 1 pixels 1 and 3 once packed.
        let words = _mm256_packus_epi32(blend2(k, k + 1), blend2(k + 2, k + 3));
        let bytes4 = _mm256_packus_epi16(words, words);
        let (lo, hi) = (
            _mm256_castsi256_si128(bytes4),
            _mm256_extracti128_si256::<1>(bytes4),
        );
        let rgb = _mm_shuffle_epi8(_mm_unpacklo_epi32(lo, hi), compact);
        // SAFETY: pixels k..k + 4 of `out` are its bytes 3k..3k + 12.
        unsafe {
            let at = out_bytes.add(3 * k);
            _mm_storel_epi64(at.cast(), rgb);
            at.add(8)
                .cast::<i32>()
                .write_unaligned(_mm_extract_epi32::<2>(rgb));
        }
    }
    for (i, px) in out.iter_mut().enumerate().skip(4 * groups) {
        rest(i, px);
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use stereolink_image::{Plane, RgbImage};

    use super::super::{weight_table, RectifyMap};
    use super::*;

    #[test]
    fn separable_weights_multiply_to_the_table() {
        let (table, separable) = (weight_table(), separable_weights());
        for (w, &s) in table.iter().zip(separable.iter()) {
            let byte = |k: u32| (s >> (8 * k)) as u16 & 0xff;
            let (gx, fx, gy, fy) = (byte(0), byte(1), (s >> 16) as u16, (s >> 32) as u16);
            assert_eq!(*w, [gx * gy, fx * gy, gx * fy, fx * fy]);
        }
    }

    /// A map of `size` over a `source`-sized image with each pixel inside
    /// (any top-left neighbour that has a right and a lower one, the last
    /// such one often, as its 8-byte read of the row below ends past the
    /// image) or outside, as `picks` says.
    fn random_map(
        source: (usize, usize),
        size: (usize, usize),
        picks: &[(u32, u16)],
    ) -> RectifyMap {
        let (sw, sh) = source;
        let last = ((sh - 2) * sw + sw - 2) as u32;
        let (mut offset, mut weight) = (Vec::new(), Vec::new());
        for &(pick, w) in picks.iter().cycle().take(size.0 * size.1) {
            let (o, w) = match pick % 8 {
                0 => (0, OUTSIDE),
                1 => (last, w % OUTSIDE),
                _ => {
                    let (x, y) = (pick as usize % (sw - 1), pick as usize / 7 % (sh - 1));
                    ((y * sw + x) as u32, w % OUTSIDE)
                }
            };
            offset.push(o);
            weight.push(w);
        }
        RectifyMap {
            size,
            source,
            offset,
            weight,
            edge: Vec::new(),
            table: weight_table(),
            separable: Some(separable_weights()),
        }
    }

    proptest! {
        /// The AVX2 pass equals the portable one bit for bit, on random
        /// images, sizes (remainders of the groups of 4 included) and
        /// positions, those at the source's last pixels and outside too.
        #[test]
        fn avx2_equals_portable(
            sw in 2usize..40, sh in 2usize..12,
            w in 1usize..37, h in 1usize..9,
            picks in proptest::collection::vec((any::<u32>(), any::<u16>()), 1..64),
            seed in any::<u32>(),
        ) {
            prop_assume!(stereolink_image::cpu::avx2());
            let img: RgbImage = Plane::from_fn(sw, sh, |x, y| {
                let v = (x as u32 * 0x9E37_79B9) ^ (y as u32 * 0x85EB_CA6B) ^ seed;
                let v = v.wrapping_mul(0x2C1B_3C6D);
                [(v >> 24) as u8, (v >> 16) as u8, (v >> 8) as u8]
            });
            let fast = random_map((sw, sh), (w, h), &picks);
            let portable = RectifyMap { separable: None, ..fast.clone() };
            prop_assert_eq!(fast.apply(&img).unwrap(), portable.apply(&img).unwrap());
        }
    }
}
