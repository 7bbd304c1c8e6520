//! The vector operations of the WTA band loop: portably, with AVX2
//! intrinsics, and in SWAR for a CPU without vector instructions.
//!
//! A pixel's costs are `u16` lanes, one per disparity, padded to a whole
//! number of [`LANES`]-wide blocks. LLVM does not reliably vectorise these
//! short loops once they are inlined into the band loop (it fully unrolls
//! them into scalar code), so the AVX2 set is written with intrinsics. The
//! SWAR set (the ARM926 board: no SIMD) adds and subtracts two lanes held in
//! one `u32` word per instruction. All sets use the same integer arithmetic
//! and the same tie rule, so they give bit-identical results; the tests
//! check that.

/// Disparities per vector block (one AVX2 register of `u16`).
pub const LANES: usize = 16;

/// One implementation of the lane operations.
///
/// # Safety
/// Every method may use the instruction set the implementation is named
/// after: call them only when the CPU has it.
pub(crate) trait LaneOps {
    /// Whether the band loop should skip the column sums' update where a
    /// row and the one leaving the window agree (they cancel): it pays on
    /// a scalar CPU, not where a vector updates 16 lanes in a few
    /// instructions and camera rows almost never agree.
    const SKIP_ALIKE_ROWS: bool = false;
    /// `col[k] += |l − r[k]|`, and `−= |ls − rs[k]|` for a leaving row.
    unsafe fn accumulate(col: &mut [u16], l: u16, r: &[u16], leaving: Option<(u16, &[u16])>);
    /// `out[k] = base[k] + a[k] − s[k]`.
    unsafe fn add_sub_from(out: &mut [u16], base: &[u16], a: &[u16], s: &[u16]);
    /// `acc[k] = min(acc[k], a[k])`.
    unsafe fn min_assign(acc: &mut [u16], a: &[u16]);
    /// `acc[k] += a[k]`, and `−= s[k]` when given.
    unsafe fn add_sub(acc: &mut [u16], a: &[u16], s: Option<&[u16]>);
    /// Index and value of the smallest of `costs[..valid]` (`valid ≥ 1`);
    /// the lowest index wins ties. The value comes from the reduction, so
    /// a caller need not load it back from a just-written cost vector.
    unsafe fn argmin(costs: &[u16], valid: usize) -> (usize, u16);
    /// [`add_sub`](Self::add_sub) with `s`, then [`argmin`](Self::argmin)
    /// of the sums: one pass where a kernel fuses them.
    #[inline(always)]
    unsafe fn add_sub_argmin(acc: &mut [u16], a: &[u16], s: &[u16], valid: usize) -> (usize, u16) {
        // SAFETY: forwarded from the caller.
        unsafe {
            Self::add_sub(acc, a, Some(s));
            Self::argmin(acc, valid)
        }
    }
    /// For every lane `i` with `i < valid`: if `costs[i] < best[i]`, then
    /// `best[i] = costs[i]` and `which[i] = i` (an earlier smaller or equal
    /// cost stays).
    unsafe fn min_update(best: &mut [u16], which: &mut [u16], costs: &[u16], valid: usize);
    /// `best[i] = min(best[i], costs[i])` for every lane `i < valid`.
    unsafe fn min_first(best: &mut [u16], costs: &[u16], valid: usize);
}

/// Plain Rust, for every CPU.
pub(crate) struct Portable;

impl LaneOps for Portable {
    #[inline(always)]
    unsafe fn accumulate(col: &mut [u16], l: u16, r: &[u16], leaving: Option<(u16, &[u16])>) {
        match leaving {
            None => {
                for (c, &rv) in col.iter_mut().zip(r) {
                    *c = c.wrapping_add(l.abs_diff(rv));
                }
            }
            Some((ls, rs)) => {
                for ((c, &rv), &sv) in col.iter_mut().zip(r).zip(rs) {
                    *c = c.wrapping_add(l.abs_diff(rv)).wrapping_sub(ls.abs_diff(sv));
                }
            }
        }
    }

    #[inline(always)]
    unsafe fn add_sub_from(out: &mut [u16], base: &[u16], a: &[u16], s: &[u16]) {
        for (((o, &b), &av), &sv) in out.iter_mut().zip(base).zip(a).zip(s) {
            *o = b.wrapping_add(av).wrapping_sub(sv);
        }
    }

    #[inline(always)]
    unsafe fn min_assign(acc: &mut [u16], a: &[u16]) {
        acc.iter_mut().zip(a).for_each(|(m, &v)| *m = (*m).min(v));
    }

    #[inline(always)]
    unsafe fn add_sub(acc: &mut [u16], a: &[u16], s: Option<&[u16]>) {
        match s {
            None => acc
                .iter_mut()
                .zip(a)
                .for_each(|(h, &v)| *h = h.wrapping_add(v)),
            Some(s) => {
                for ((h, &av), &sv) in acc.iter_mut().zip(a).zip(s) {
                    *h = h.wrapping_add(av).wrapping_sub(sv);
                }
            }
        }
    }

    #[inline(always)]
    unsafe fn argmin(costs: &[u16], valid: usize) -> (usize, u16) {
        // Cost in the high half, index in the low half: the smallest packed
        // value is the smallest cost at the smallest index.
        let packed = costs[..valid]
            .iter()
            .zip(0u32..)
            .map(|(&c, k)| (c as u32) << 16 | k)
            .min()
            .expect("at least one valid lane");
        ((packed & 0xFFFF) as usize, (packed >> 16) as u16)
    }

    #[inline(always)]
    unsafe fn min_update(best: &mut [u16], which: &mut [u16], costs: &[u16], valid: usize) {
        let lanes = best.iter_mut().zip(which.iter_mut()).zip(&costs[..valid]);
        // Unconditional stores of selected values, so that it vectorises.
        for (((b, w), &c), i) in lanes.zip(0u16..) {
            let take = c < *b;
            (*b, *w) = if take { (c, i) } else { (*b, *w) };
        }
    }

    #[inline(always)]
    unsafe fn min_first(best: &mut [u16], costs: &[u16], valid: usize) {
        for (b, &c) in best.iter_mut().zip(&costs[..valid]) {
            *b = (*b).min(c);
        }
    }
}

/// Two lanes per `u32` word for the column sums' and the sliding window
/// sum's updates (the board's WTA runs without a min filter), the latter
/// fused with the search for the smallest cost; [`Portable`] for the rest.
/// Absolute differences, minima and compares stay one lane at a time: a
/// scalar CPU does them in fewer instructions than their SWAR forms.
///
/// Exact because of what the band loop adds and subtracts: every lane is a
/// sum of absolute differences that the window bound keeps below 2^16
/// (`WtaParams::max_block`), and every subtraction removes a term of that
/// sum, so subtracting before adding never borrows from, nor carries into,
/// the other lane of a word.
pub(crate) struct Swar;

/// `acc`, `a` and `s` (each cut to `acc.len()`) as words of two lanes, if
/// all three are aligned for `u32` (they are where they come from a `Vec`
/// at an even offset).
#[inline(always)]
fn as_words<'a>(
    acc: &'a mut [u16],
    a: &'a [u16],
    s: &'a [u16],
) -> Option<(&'a mut [u32], &'a [u32], &'a [u32])> {
    let n = acc.len();
    // SAFETY: every bit pattern is a valid u32, and a valid pair of u16.
    let ((a0, a, a1), (s0, s, s1), (h0, acc, h1)) = unsafe {
        (
            a[..n].align_to::<u32>(),
            s[..n].align_to::<u32>(),
            acc.align_to_mut::<u32>(),
        )
    };
    let aligned = [a0, a1, s0, s1, h0, h1].iter().all(|rest| rest.is_empty());
    aligned.then_some((acc, a, s))
}

/// The word holding the lanes `first` and `second`, in memory order.
#[inline(always)]
pub(crate) fn word(first: u16, second: u16) -> u32 {
    let (a, b) = (first as u32, second as u32);
    if cfg!(target_endian = "little") {
        a | b << 16
    } else {
        a << 16 | b
    }
}

/// A word's two lanes, in memory order.
#[inline(always)]
fn lanes_of(v: u32) -> (u32, u32) {
    if cfg!(target_endian = "little") {
        (v & 0xFFFF, v >> 16)
    } else {
        (v >> 16, v & 0xFFFF)
    }
}

impl LaneOps for Swar {
    const SKIP_ALIKE_ROWS: bool = true;

    /// The differences per lane, the column sums a word at a time: the
    /// leaving row's pair subtracted, then the entering row's added.
    #[inline(always)]
    unsafe fn accumulate(col: &mut [u16], l: u16, r: &[u16], leaving: Option<(u16, &[u16])>) {
        let n = col.len();
        // SAFETY: every bit pattern is a valid u32, and a valid pair of u16.
        let (head, words, tail) = unsafe { col.align_to_mut::<u32>() };
        match leaving {
            Some((ls, rs)) if head.is_empty() && tail.is_empty() => {
                let pairs = r[..n].chunks_exact(2).zip(rs[..n].chunks_exact(2));
                for (c, (r, s)) in words.iter_mut().zip(pairs) {
                    let new = word(l.abs_diff(r[0]), l.abs_diff(r[1]));
                    let old = word(ls.abs_diff(s[0]), ls.abs_diff(s[1]));
                    *c = c.wrapping_sub(old).wrapping_add(new);
                }
            }
            // SAFETY: portable code.
            _ => unsafe { Portable::accumulate(col, l, r, leaving) },
        }
    }

    #[inline(always)]
    unsafe fn add_sub_from(out: &mut [u16], base: &[u16], a: &[u16], s: &[u16]) {
        // SAFETY: portable code.
        unsafe { Portable::add_sub_from(out, base, a, s) }
    }

    #[inline(always)]
    unsafe fn min_assign(acc: &mut [u16], a: &[u16]) {
        // SAFETY: portable code.
        unsafe { Portable::min_assign(acc, a) }
    }

    #[inline(always)]
    unsafe fn add_sub(acc: &mut [u16], a: &[u16], s: Option<&[u16]>) {
        match s {
            Some(s) => {
                if let Some((h, a, s)) = as_words(acc, a, s) {
                    for ((h, &a), &s) in h.iter_mut().zip(a).zip(s) {
                        *h = h.wrapping_sub(s).wrapping_add(a);
                    }
                    return;
                }
            }
            None => {
                if let Some((h, a, _)) = as_words(acc, a, a) {
                    h.iter_mut()
                        .zip(a)
                        .for_each(|(h, &a)| *h = h.wrapping_add(a));
                    return;
                }
            }
        }
        // SAFETY: portable code.
        unsafe { Portable::add_sub(acc, a, s) }
    }

    /// One pass: each word's new sums are compared while in registers.
    #[inline(always)]
    unsafe fn add_sub_argmin(acc: &mut [u16], a: &[u16], s: &[u16], valid: usize) -> (usize, u16) {
        let Some((h, a, s)) = as_words(acc, a, s) else {
            // SAFETY: portable code.
            return unsafe { Portable::add_sub_argmin(acc, a, s, valid) };
        };
        // Packed as in Portable::argmin: cost high, lane low. The words
        // whose both lanes are valid, then the one with a last valid lane,
        // then the rest (only updated).
        let slide = |h: &mut u32, a: u32, s: u32| *h = h.wrapping_sub(s).wrapping_add(a);
        let (mut best, mut k) = (u32::MAX, 0);
        let full = valid / 2;
        for ((h, &a), &s) in h[..full].iter_mut().zip(&a[..full]).zip(&s[..full]) {
            slide(h, a, s);
            let (first, second) = lanes_of(*h);
            best = best.min(first << 16 | k).min(second << 16 | (k + 1));
            k += 2;
        }
        let mut rest = h[full..].iter_mut().zip(&a[full..]).zip(&s[full..]);
        if valid % 2 == 1 {
            if let Some(((h, &a), &s)) = rest.next() {
                slide(h, a, s);
                best = best.min(lanes_of(*h).0 << 16 | k);
            }
        }
        rest.for_each(|((h, &a), &s)| slide(h, a, s));
        ((best & 0xFFFF) as usize, (best >> 16) as u16)
    }

    #[inline(always)]
    unsafe fn argmin(costs: &[u16], valid: usize) -> (usize, u16) {
        // SAFETY: portable code.
        unsafe { Portable::argmin(costs, valid) }
    }

    #[inline(always)]
    unsafe fn min_update(best: &mut [u16], which: &mut [u16], costs: &[u16], valid: usize) {
        // SAFETY: portable code.
        unsafe { Portable::min_update(best, which, costs, valid) }
    }

    #[inline(always)]
    unsafe fn min_first(best: &mut [u16], costs: &[u16], valid: usize) {
        // SAFETY: portable code.
        unsafe { Portable::min_first(best, costs, valid) }
    }
}

/// AVX2 intrinsics (x86-64 only).
#[cfg(target_arch = "x86_64")]
pub(crate) struct Avx2;

#[cfg(target_arch = "x86_64")]
impl LaneOps for Avx2 {
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn accumulate(col: &mut [u16], l: u16, r: &[u16], leaving: Option<(u16, &[u16])>) {
        use std::arch::x86_64::*;
        let absdiff = |a: __m256i, b: __m256i| {
            _mm256_or_si256(_mm256_subs_epu16(a, b), _mm256_subs_epu16(b, a))
        };
        let load = |b: &[u16]| _mm256_loadu_si256(b.as_ptr().cast());
        let lv = _mm256_set1_epi16(l as i16);
        let cols = col.chunks_exact_mut(LANES);
        let rs = r.chunks_exact(LANES);
        match leaving {
            None => {
                for (c, r) in cols.zip(rs) {
                    let p = c.as_mut_ptr().cast::<__m256i>();
                    let d = absdiff(lv, load(r));
                    _mm256_storeu_si256(p, _mm256_add_epi16(_mm256_loadu_si256(p), d));
                }
            }
            Some((ls, srs)) => {
                let sv = _mm256_set1_epi16(ls as i16);
                for ((c, r), s) in cols.zip(rs).zip(srs.chunks_exact(LANES)) {
                    let p = c.as_mut_ptr().cast::<__m256i>();
                    let d = absdiff(lv, load(r));
                    let e = absdiff(sv, load(s));
                    let v = _mm256_sub_epi16(_mm256_add_epi16(_mm256_loadu_si256(p), d), e);
                    _mm256_storeu_si256(p, v);
                }
            }
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn add_sub(acc: &mut [u16], a: &[u16], s: Option<&[u16]>) {
        use std::arch::x86_64::*;
        let load = |b: &[u16]| _mm256_loadu_si256(b.as_ptr().cast());
        let accs = acc.chunks_exact_mut(LANES);
        let adds = a.chunks_exact(LANES);
        match s {
            None => {
                for (h, a) in accs.zip(adds) {
                    let p = h.as_mut_ptr().cast::<__m256i>();
                    _mm256_storeu_si256(p, _mm256_add_epi16(_mm256_loadu_si256(p), load(a)));
                }
            }
            Some(s) => {
                for ((h, a), s) in accs.zip(adds).zip(s.chunks_exact(LANES)) {
                    let p = h.as_mut_ptr().cast::<__m256i>();
                    let v = _mm256_add_epi16(_mm256_loadu_si256(p), load(a));
                    _mm256_storeu_si256(p, _mm256_sub_epi16(v, load(s)));
                }
            }
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn add_sub_from(out: &mut [u16], base: &[u16], a: &[u16], s: &[u16]) {
        use std::arch::x86_64::*;
        let load = |b: &[u16]| _mm256_loadu_si256(b.as_ptr().cast());
        let ins = base.chunks_exact(LANES).zip(a.chunks_exact(LANES));
        for ((o, (b, a)), s) in out
            .chunks_exact_mut(LANES)
            .zip(ins)
            .zip(s.chunks_exact(LANES))
        {
            let v = _mm256_sub_epi16(_mm256_add_epi16(load(b), load(a)), load(s));
            _mm256_storeu_si256(o.as_mut_ptr().cast(), v);
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn min_assign(acc: &mut [u16], a: &[u16]) {
        use std::arch::x86_64::*;
        for (m, a) in acc.chunks_exact_mut(LANES).zip(a.chunks_exact(LANES)) {
            let p = m.as_mut_ptr().cast::<__m256i>();
            let v = _mm256_loadu_si256(a.as_ptr().cast());
            _mm256_storeu_si256(p, _mm256_min_epu16(_mm256_loadu_si256(p), v));
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn argmin(costs: &[u16], valid: usize) -> (usize, u16) {
        use std::arch::x86_64::*;
        let load = |b: usize| _mm256_loadu_si256(costs[b * LANES..(b + 1) * LANES].as_ptr().cast());
        let (full, rest) = (valid / LANES, valid % LANES);
        let mut m = _mm256_set1_epi16(-1);
        for b in 0..full {
            m = _mm256_min_epu16(m, load(b));
        }
        if rest > 0 {
            // Lanes past `valid` read as the largest cost, which never wins.
            let iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
            let inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(rest as i16), iota);
            let tail = _mm256_or_si256(
                load(full),
                _mm256_andnot_si256(inside, _mm256_set1_epi16(-1)),
            );
            m = _mm256_min_epu16(m, tail);
        }
        let half = _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
        let best = _mm_extract_epi16(_mm_minpos_epu16(half), 0) as i16;
        let target = _mm256_set1_epi16(best);
        // The first lane equal to the minimum is a valid one: lanes past
        // `valid` come after every valid lane.
        for b in 0..valid.div_ceil(LANES) {
            let hit = _mm256_movemask_epi8(_mm256_cmpeq_epi16(load(b), target)) as u32;
            if hit != 0 {
                return (b * LANES + hit.trailing_zeros() as usize / 2, best as u16);
            }
        }
        unreachable!("the minimum is one of the lanes")
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn min_update(best: &mut [u16], which: &mut [u16], costs: &[u16], valid: usize) {
        use std::arch::x86_64::*;
        let iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let (ones, sign) = (_mm256_set1_epi16(-1), _mm256_set1_epi16(i16::MIN));
        if valid % LANES == 0 {
            // Whole blocks (the usual case): no lane to mask, and the
            // lanes' indices step from block to block.
            let blocks = best
                .chunks_exact_mut(LANES)
                .zip(which.chunks_exact_mut(LANES))
                .zip(costs.chunks_exact(LANES))
                .take(valid / LANES);
            let mut index = iota;
            for ((best, which), cost) in blocks {
                let c = _mm256_loadu_si256(cost.as_ptr().cast());
                let (bp, wp) = (
                    best.as_mut_ptr().cast::<__m256i>(),
                    which.as_mut_ptr().cast(),
                );
                let old = _mm256_loadu_si256(bp);
                let m = _mm256_min_epu16(old, c);
                // `old ≤ c`: the old one stays.
                let stay = _mm256_cmpeq_epi16(m, old);
                _mm256_storeu_si256(bp, m);
                let w = _mm256_blendv_epi8(index, _mm256_loadu_si256(wp), stay);
                _mm256_storeu_si256(wp, w);
                index = _mm256_add_epi16(index, _mm256_set1_epi16(LANES as i16));
            }
            return;
        }
        let blocks = best
            .chunks_exact_mut(LANES)
            .zip(which.chunks_exact_mut(LANES));
        for (b, ((best, which), cost)) in blocks.zip(costs.chunks_exact(LANES)).enumerate() {
            if b * LANES >= valid {
                break;
            }
            let left = (valid - b * LANES).min(LANES) as i16;
            let inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(left), iota);
            // Lanes past `valid` become the largest cost, which never wins.
            let c = _mm256_loadu_si256(cost.as_ptr().cast());
            let c = _mm256_or_si256(c, _mm256_andnot_si256(inside, ones));
            let (bp, wp) = (
                best.as_mut_ptr().cast::<__m256i>(),
                which.as_mut_ptr().cast(),
            );
            let old = _mm256_loadu_si256(bp);
            // Unsigned c < old, as a signed comparison of sign-flipped values.
            let less = _mm256_cmpgt_epi16(_mm256_xor_si256(old, sign), _mm256_xor_si256(c, sign));
            let index = _mm256_add_epi16(iota, _mm256_set1_epi16((b * LANES) as i16));
            _mm256_storeu_si256(bp, _mm256_min_epu16(old, c));
            let w = _mm256_blendv_epi8(_mm256_loadu_si256(wp), index, less);
            _mm256_storeu_si256(wp, w);
        }
    }

    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn min_first(best: &mut [u16], costs: &[u16], valid: usize) {
        use std::arch::x86_64::*;
        let iota = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let blocks = best.chunks_exact_mut(LANES).zip(costs.chunks_exact(LANES));
        for (b, (best, cost)) in blocks.enumerate().take(valid.div_ceil(LANES)) {
            let c = _mm256_loadu_si256(cost.as_ptr().cast());
            let left = valid - b * LANES;
            // Lanes past `valid` become the largest cost, which changes nothing.
            let c = if left < LANES {
                let inside = _mm256_cmpgt_epi16(_mm256_set1_epi16(left as i16), iota);
                _mm256_or_si256(c, _mm256_andnot_si256(inside, _mm256_set1_epi16(-1)))
            } else {
                c
            };
            let p = best.as_mut_ptr().cast::<__m256i>();
            _mm256_storeu_si256(p, _mm256_min_epu16(_mm256_loadu_si256(p), c));
        }
    }
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn avx2_equals_portable(
            blocks in 1usize..5,
            seed in any::<u64>(),
            l in any::<u16>(), ls in any::<u16>(),
            leave in any::<bool>(),
            valid_frac in 0.0f64..1.0,
        ) {
            if !stereolink_image::cpu::avx2() {
                return Ok(());
            }
            let n = blocks * LANES;
            let mut s = seed | 1;
            let mut next = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s };
            // Samples anywhere in u16, so wrapping sums are exercised too.
            let r: Vec<u16> = (0..n).map(|_| next() as u16).collect();
            let rs: Vec<u16> = (0..n).map(|_| next() as u16).collect();
            // Small costs so ties are frequent.
            let col: Vec<u16> = (0..n).map(|_| (next() % 8) as u16).collect();
            let leaving = leave.then_some((ls, rs.as_slice()));
            let (mut a, mut b) = (col.clone(), col.clone());
            // SAFETY: AVX2 was detected above; Portable needs nothing.
            unsafe {
                Portable::accumulate(&mut a, l, &r, leaving);
                Avx2::accumulate(&mut b, l, &r, leaving);
                prop_assert_eq!(&a, &b);
                let sub = leave.then_some(col.as_slice());
                Portable::add_sub(&mut a, &col, sub);
                Avx2::add_sub(&mut b, &col, sub);
                prop_assert_eq!(&a, &b);
                let (mut fa, mut fb) = (vec![0; n], vec![0; n]);
                Portable::add_sub_from(&mut fa, &a, &col, &r);
                Avx2::add_sub_from(&mut fb, &b, &col, &r);
                prop_assert_eq!(&fa, &fb);
                Portable::min_assign(&mut a, &r);
                Avx2::min_assign(&mut b, &r);
                prop_assert_eq!(&a, &b);
                let valid = 1 + ((n - 1) as f64 * valid_frac) as usize;
                let ties: Vec<u16> = col.iter().map(|c| c % 3).collect();
                prop_assert_eq!(Portable::argmin(&ties, valid), Avx2::argmin(&ties, valid));
                prop_assert_eq!(Portable::argmin(&a, valid), Avx2::argmin(&a, valid));
                let (mut best_p, mut which_p) = (ties.clone(), vec![99u16; n]);
                let (mut best_a, mut which_a) = (ties.clone(), vec![99u16; n]);
                Portable::min_update(&mut best_p, &mut which_p, &col, valid);
                Avx2::min_update(&mut best_a, &mut which_a, &col, valid);
                prop_assert_eq!((&best_p, &which_p), (&best_a, &which_a));
                // All lanes valid (the AVX2 kernel's path without masks).
                Portable::min_update(&mut best_p, &mut which_p, &r, n);
                Avx2::min_update(&mut best_a, &mut which_a, &r, n);
                prop_assert_eq!((&best_p, which_p), (&best_a, which_a));
                for v in [valid, n] {
                    Portable::min_first(&mut best_p, &col, v);
                    Avx2::min_first(&mut best_a, &col, v);
                    prop_assert_eq!(&best_p, &best_a);
                }
            }
        }
    }
}
