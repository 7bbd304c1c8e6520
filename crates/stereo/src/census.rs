//! The 9×7 census transform (Zabih & Woodfill, ECCV 1994): per pixel, one
//! bit per neighbour darker than the centre. SGM's matching cost is the
//! Hamming distance of two codes, and the plane matcher scores its planes
//! and boundaries with the same codes (masked to smaller windows by
//! [`census_mask`]), so the transform is a module of its own that both use.

use rayon::prelude::*;
use stereolink_image::GrayImage;

/// 9×7 census transform: bit set where the neighbour is darker than the
/// centre; outside pixels replicate the border.
pub fn census(img: &GrayImage) -> Vec<u64> {
    census_with(img, stereolink_image::cpu::avx2())
}

/// The bits of a [`census`] code that compare the centre with the
/// neighbours of the centred `width × height` window (odd, at most 9×7):
/// the code of that smaller census is `code & census_mask(width, height)`,
/// so one transform serves every window inside the 9×7 one.
///
/// # Panics
/// If a side is even or larger than the census's.
pub fn census_mask(width: usize, height: usize) -> u64 {
    assert!(width % 2 == 1 && width <= 9 && height % 2 == 1 && height <= 7);
    let (rx, ry) = (width / 2, height / 2);
    // [`census_row`]'s order: neighbours in raster order, eight to a byte
    // (six in the last), the first of a byte in its highest bit.
    neighbours()
        .enumerate()
        .filter(|&(_, (dy, dx))| dy.abs_diff(3) <= ry && dx.abs_diff(4) <= rx)
        .fold(0, |mask, (i, _)| {
            let (byte, at) = (i / 8, i % 8);
            let in_byte = if byte == 7 { 6 } else { 8 };
            mask | 1 << (8 * byte + in_byte - 1 - at)
        })
}

/// The 62 neighbours of the 9×7 census window as (row, column) in the
/// window, centre `(3, 4)` left out, in the order their bits are filled.
fn neighbours() -> impl Iterator<Item = (usize, usize)> {
    (0..7)
        .flat_map(|dy| (0..9).map(move |dx| (dy, dx)))
        .filter(|&n| n != (3, 4))
}

/// [`census`] compiled for AVX2 (`avx2`: the CPU has it) or not.
pub(crate) fn census_with(img: &GrayImage, avx2: bool) -> Vec<u64> {
    let (w, h) = img.dims();
    let mut out = vec![0u64; w * h];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            if avx2 {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: AVX2 presence was checked at run time.
                unsafe {
                    census_row_avx2(img, y, row)
                }
            } else {
                census_row(img, y, row)
            }
        });
    out
}

/// [`census_row`] with AVX2 intrinsics, 32 pixels at a time with all eight
/// groups in registers: `n < c` as one signed comparison of values offset
/// by 128, `b = 2b + bit` as an add and a subtract of the comparison mask,
/// then the eight group bytes of each pixel transposed into its `u64` by
/// unpacking. Bit for bit the portable code's output.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::erasing_op, clippy::identity_op)] // the unrolled group 0
unsafe fn census_row_avx2(img: &GrayImage, y: usize, out: &mut [u64]) {
    use std::arch::x86_64::*;
    const CHUNK: usize = 32;
    let (w, h) = img.dims();
    // Rows y − 3..=y + 3, padded by 4 replicated pixels on the left and
    // enough on the right for whole chunks, offset by 128 (signed order).
    let pw = w.next_multiple_of(CHUNK) + 8;
    let mut padded = vec![0u8; 7 * pw];
    for (dy, dst) in padded.chunks_exact_mut(pw).enumerate() {
        let line = img.row((y + dy).saturating_sub(3).min(h - 1));
        let (left, rest) = dst.split_at_mut(4);
        let (middle, right) = rest.split_at_mut(w);
        left.fill(line[0] ^ 0x80);
        for (m, &v) in middle.iter_mut().zip(line) {
            *m = v ^ 0x80;
        }
        right.fill(line[w - 1] ^ 0x80);
    }
    // The 62 neighbours of the 9×7 window as offsets into `padded`.
    let mut offsets = [0; 62];
    let neighbours = (0..7)
        .flat_map(|dy| (0..9).map(move |dx| (dy, dx)))
        .filter(|&n| n != (3, 4));
    for (o, (dy, dx)) in offsets.iter_mut().zip(neighbours) {
        *o = dy * pw + dx;
    }
    // Every load below reads 32 bytes at x0 + an offset ≤ 6·pw + 8, with
    // x0 + 32 ≤ pw − 8: within the 7·pw bytes.
    let rows = padded.as_ptr();
    let mut codes = [0u64; CHUNK];
    for x0 in (0..w).step_by(CHUNK) {
        let at = rows.add(x0);
        let centre = _mm256_loadu_si256(at.add(3 * pw + 4).cast());
        let mut groups = [_mm256_setzero_si256(); 8];
        seq_macro::seq!(G in 0..8 {
            let mut b = _mm256_setzero_si256();
            for &o in offsets[G * 8..].iter().take(8) {
                let darker = _mm256_cmpgt_epi8(centre, _mm256_loadu_si256(at.add(o).cast()));
                b = _mm256_sub_epi8(_mm256_add_epi8(b, b), darker);
            }
            groups[G] = b;
        });
        // Byte l of groups[g] is group g of pixel x0 + l; within each
        // 128-bit lane, unpacking interleaves the groups of a pixel.
        let [g0, g1, g2, g3, g4, g5, g6, g7] = groups;
        let pairs = |a, b| (_mm256_unpacklo_epi8(a, b), _mm256_unpackhi_epi8(a, b));
        let (p01l, p01h) = pairs(g0, g1);
        let (p23l, p23h) = pairs(g2, g3);
        let (p45l, p45h) = pairs(g4, g5);
        let (p67l, p67h) = pairs(g6, g7);
        let quads = |a, b| (_mm256_unpacklo_epi16(a, b), _mm256_unpackhi_epi16(a, b));
        // Pixels (lane 0 | lane 1): 0–3 | 16–19, 4–7 | 20–23, 8–11 | 24–27, 12–15 | 28–31.
        let low = [quads(p01l, p23l), quads(p01h, p23h)];
        let high = [quads(p45l, p67l), quads(p45h, p67h)];
        for (half, ((la, lb), (ha, hb))) in low.into_iter().zip(high).enumerate() {
            for (quarter, (l, h)) in [(la, ha), (lb, hb)].into_iter().enumerate() {
                // Two pixels' codes per lane: pixels a, a + 1 | a + 16, a + 17 ...
                let (first, second) = (_mm256_unpacklo_epi32(l, h), _mm256_unpackhi_epi32(l, h));
                let a = 8 * half + 4 * quarter;
                let dst = codes.as_mut_ptr();
                _mm256_storeu_si256(
                    dst.add(a).cast(),
                    _mm256_permute2x128_si256(first, second, 0x20),
                );
                _mm256_storeu_si256(
                    dst.add(a + 16).cast(),
                    _mm256_permute2x128_si256(first, second, 0x31),
                );
            }
        }
        let n = CHUNK.min(w - x0);
        out[x0..x0 + n].copy_from_slice(&codes[..n]);
    }
}

/// The census of row `y`. Bits are grouped by eight neighbours into the
/// bytes of the code (the Hamming cost does not depend on their order), so
/// each group is built on `u8` lanes along the whole row.
fn census_row(img: &GrayImage, y: usize, out: &mut [u64]) {
    let (w, h) = img.dims();
    let centre = img.row(y);
    let pw = w + 8;
    // Rows y − 3..=y + 3, each padded by 4 replicated pixels on both sides.
    let mut padded = vec![0u8; 7 * pw];
    for (dy, dst) in padded.chunks_exact_mut(pw).enumerate() {
        let line = img.row((y + dy).saturating_sub(3).min(h - 1));
        let (left, rest) = dst.split_at_mut(4);
        let (middle, right) = rest.split_at_mut(w);
        left.fill(line[0]);
        middle.copy_from_slice(line);
        right.fill(line[w - 1]);
    }
    let mut byte = vec![0u8; w];
    out.fill(0);
    let mut group = 0;
    let mut filled = 0;
    for (dy, dx) in neighbours() {
        let shifted = &padded[dy * pw + dx..dy * pw + dx + w];
        for ((b, &n), &c) in byte.iter_mut().zip(shifted).zip(centre) {
            *b = (*b << 1) | u8::from(n < c);
        }
        filled += 1;
        if filled == 8 || (group == 7 && filled == 6) {
            for (v, &b) in out.iter_mut().zip(&byte) {
                *v |= u64::from(b) << (8 * group);
            }
            (group, filled) = (group + 1, 0);
            byte.fill(0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The census code holds one bit per neighbour (in any order): its
    /// popcount counts the darker neighbours, and two codes differ in
    /// exactly the neighbours whose comparison differs.
    #[test]
    fn census_matches_its_definition_at_borders_too() {
        let mut s = 0x9E37_79B9u32;
        let img = GrayImage::from_fn(23, 11, |_, _| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (s >> 28) as u8 // few levels: ties are frequent
        });
        let c = census(&img);
        let at = |x: isize, y: isize| img.get(x.clamp(0, 22) as usize, y.clamp(0, 10) as usize);
        let comparisons = |x: isize, y: isize| -> Vec<bool> {
            (-3..=3)
                .flat_map(|dy| (-4..=4).map(move |dx| (dx, dy)))
                .filter(|&o| o != (0, 0))
                .map(|(dx, dy)| at(x + dx, y + dy) < at(x, y))
                .collect()
        };
        let code = |x: isize, y: isize| c[y as usize * 23 + x as usize];
        for y in 0..11isize {
            for x in 0..23isize {
                let mine = comparisons(x, y);
                let darker = mine.iter().filter(|&&b| b).count() as u32;
                assert_eq!(code(x, y).count_ones(), darker, "({x}, {y})");
                assert_eq!(code(x, y) >> 62, 0);
                let other = comparisons((x + 7) % 23, y);
                let differ = mine.iter().zip(&other).filter(|(a, b)| a != b).count() as u32;
                assert_eq!((code(x, y) ^ code((x + 7) % 23, y)).count_ones(), differ);
            }
        }
    }

    /// A masked code is the census of the smaller window: its bits count
    /// exactly the darker neighbours inside it.
    #[test]
    fn a_census_mask_keeps_the_inner_windows_comparisons() {
        assert_eq!(census_mask(9, 7), (1 << 62) - 1);
        assert_eq!(
            census_mask(9, 7),
            crate::planes::assign::CensusPart::FULL.mask
        );
        assert_eq!(census_mask(1, 1), 0);
        let mut s = 0x2545_F491u32;
        let img = GrayImage::from_fn(19, 13, |_, _| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (s >> 27) as u8
        });
        let c = census(&img);
        let at = |x: isize, y: isize| img.get(x.clamp(0, 18) as usize, y.clamp(0, 12) as usize);
        for (w, h) in [(3, 3), (5, 3), (3, 5), (7, 5), (9, 1), (1, 7)] {
            let mask = census_mask(w, h);
            let (rx, ry) = (w as isize / 2, h as isize / 2);
            assert_eq!(mask.count_ones() as usize, w * h - 1);
            for (x, y) in [(0, 0), (5, 6), (18, 12), (9, 2)] {
                let darker = (-ry..=ry)
                    .flat_map(|dy| (-rx..=rx).map(move |dx| (dx, dy)))
                    .filter(|&(dx, dy)| at(x + dx, y + dy) < at(x, y))
                    .count() as u32;
                let code = c[y as usize * 19 + x as usize];
                assert_eq!((code & mask).count_ones(), darker, "{w}x{h} at ({x}, {y})");
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_census_equals_portable() {
        if !stereolink_image::cpu::avx2() {
            return;
        }
        let mut s = 0x0DDB_1A5E_5BAD_5EEDu64;
        for (w, h) in [(1, 1), (5, 4), (31, 3), (32, 7), (33, 9), (70, 5)] {
            let img = GrayImage::from_fn(w, h, |_, _| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 56) as u8 & 0xF8 // few levels: ties are frequent
            });
            for y in 0..h {
                let (mut a, mut b) = (vec![0; w], vec![0; w]);
                census_row(&img, y, &mut a);
                // SAFETY: AVX2 was detected above.
                unsafe { census_row_avx2(&img, y, &mut b) };
                assert_eq!(a, b, "{w}x{h}, row {y}");
            }
        }
    }

    #[test]
    fn census_of_a_ramp() {
        let img = GrayImage::from_fn(12, 9, |x, _| (x * 10) as u8);
        let c = census(&img);
        // At an interior pixel the 4 columns to the left (7 rows each) are darker.
        assert_eq!(c[4 * 12 + 6].count_ones(), 28);
    }
}
