//! The band loop of the SWAR kernel for the board's setting (no min filter,
//! no right-view map): a CPU without vector instructions (the ARM926) does
//! per pixel and disparity only a few word operations on two `u16` lanes.
//!
//! - **Column sums from tables.** A segmented view's row holds few gray
//!   values. For a value `l` of a row, the table `|l − R(j)|` over the
//!   row's reversed right samples `j` is built once (both word alignments),
//!   so a column's update is `colsum += new − old` read a word at a time
//!   from two tables: a load, an add and a subtract per two lanes. Tables
//!   live in a ring of sets, one set per row of the window, so a row's
//!   tables built as it enters serve again when it leaves. A value without
//!   a table slot takes the direct path (absolute differences lane by lane).
//! - **Columns whose entering and leaving rows agree are skipped**, as in
//!   the generic SWAR band loop: they cancel.
//! - **The slide and the argmin are fused and unrolled** for 32 lanes: the
//!   lane in a word's high half is compared without extracting it (a
//!   running minimum kept in the high half of a word, low half zero), the
//!   one in the low half by a compare with a shifted operand.
//!
//! Word arithmetic is exact for the same reason as [`crate::lanes::Swar`]'s:
//! every lane's final value is a sum of absolute differences below 2^16, so
//! the word's result is the lanes' results whatever the order of adding and
//! subtracting (modulo 2^32, the words never borrow between lanes in the
//! end result).

use super::{lanes, Disparity, Job};

/// Table slots per row: values beyond take the direct path.
const SLOTS: usize = 6;
/// No slot (in [`TableSet::slot_of`]).
const NO_SLOT: u8 = u8::MAX;

/// The scratch of one band for [`band`].
#[derive(Default)]
pub(super) struct SwarBand {
    /// Column sums, `W × lanes / 2` words.
    colsum: Vec<u32>,
    /// The sliding window sum of the current pixel.
    h: Vec<u32>,
    /// As the generic band's `differ`: per reversed-row index, how many of
    /// the entering and leaving right rows' samples before it differ.
    differ: Vec<u32>,
    /// The tables of the window's rows, set `y % sets.len()` for row `y`.
    sets: Vec<TableSet>,
}

/// The tables of one right row, per left gray value with a slot.
#[derive(Default)]
struct TableSet {
    /// The row these tables belong to (`usize::MAX`: none).
    owner: usize,
    /// Per gray value, its slot or [`NO_SLOT`].
    slot_of: Vec<u8>,
    /// The values holding a slot, in slot order.
    values: Vec<u16>,
    /// Per slot, two tables of `tw` words: lanes `(2i, 2i + 1)` and
    /// `(2i + 1, 2i + 2)` of `|l − R(j)|` at word `i`.
    words: Vec<u32>,
}

impl TableSet {
    /// The slot of value `l` for row `y` (its reversed right samples
    /// `rev`), building its table if a slot is free; `None` when full.
    #[inline(always)]
    fn slot(&mut self, y: usize, l: u16, rev: &[u16], tw: usize) -> Option<usize> {
        if self.owner != y {
            for &v in &self.values {
                self.slot_of[v as usize] = NO_SLOT;
            }
            self.values.clear();
            self.owner = y;
        }
        let s = self.slot_of[l as usize];
        if s != NO_SLOT {
            return Some(s as usize);
        }
        let s = self.values.len();
        if s == SLOTS {
            return None;
        }
        self.slot_of[l as usize] = s as u8;
        self.values.push(l);
        let (t0, t1) = self.words[2 * s * tw..2 * (s + 1) * tw].split_at_mut(tw);
        build_table(l, rev, t0, t1);
        Some(s)
    }

    /// The words of `slot`'s table for the lanes `start..start + 2 · n`.
    #[inline(always)]
    fn lanes(&self, slot: usize, tw: usize, start: usize, n: usize) -> &[u32] {
        let t = &self.words[(2 * slot + start % 2) * tw..][..tw];
        &t[start / 2..start / 2 + n]
    }
}

/// `t0[i]` = lanes `(2i, 2i + 1)` and `t1[i]` = lanes `(2i + 1, 2i + 2)` of
/// `|l − rev[j]|` (0 past the row's end).
fn build_table(l: u16, rev: &[u16], t0: &mut [u32], t1: &mut [u32]) {
    let ad = |j: usize| rev.get(j).map_or(0, |&r| l.abs_diff(r));
    // Words whose three lanes lie inside the row, then the rest.
    let main = rev.len().saturating_sub(1) / 2;
    let mut a = ad(0);
    let words = t0.iter_mut().zip(t1.iter_mut());
    for ((t0, t1), r) in words.zip(rev[1.min(rev.len())..].chunks_exact(2)) {
        let (b, c) = (l.abs_diff(r[0]), l.abs_diff(r[1]));
        (*t0, *t1) = (word(a, b), word(b, c));
        a = c;
    }
    for i in main..t0.len() {
        t0[i] = word(ad(2 * i), ad(2 * i + 1));
        t1[i] = word(ad(2 * i + 1), ad(2 * i + 2));
    }
}

/// The word holding the lanes `first` and `second`, in memory order.
#[inline(always)]
fn word(first: u16, second: u16) -> u32 {
    let (a, b) = (first as u32, second as u32);
    if cfg!(target_endian = "little") {
        a | b << 16
    } else {
        a << 16 | b
    }
}

/// The words of `v` as `u16` lanes in memory order.
#[inline(always)]
fn as_lanes(v: &[u32]) -> &[u16] {
    // SAFETY: two u16 fit a u32 exactly, with no stricter alignment, and
    // every bit pattern is valid for both.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), 2 * v.len()) }
}

/// Adds the absolute differences of row `y` to the column sums and
/// subtracts those of row `leaving` when given, from the tables where the
/// values have them, skipping columns whose rows agree.
fn accumulate_row(job: &Job, sb: &mut SwarBand, y: usize, leaving: Option<usize>) {
    let w = job.left.width();
    let nw = lanes(job.params.ndisp) / 2;
    let stride = job.stride;
    let tw = stride / 2 + 1;
    let start = |x: usize| w + job.params.min_disp - 1 - x;
    let row = |y: usize| &job.reversed[y * stride..(y + 1) * stride];
    let left = job.left.row(y);
    let Some(s) = leaving else {
        for (x, col) in sb.colsum.chunks_exact_mut(nw).enumerate() {
            let (l, r) = (left[x], &row(y)[start(x)..]);
            for (i, c) in col.iter_mut().enumerate() {
                *c = c.wrapping_add(word(l.abs_diff(r[2 * i]), l.abs_diff(r[2 * i + 1])));
            }
        }
        return;
    };
    let gone = job.left.row(s);
    let differ = &mut sb.differ;
    let mut n = 0;
    differ[0] = 0;
    for ((c, a), b) in differ[1..].iter_mut().zip(row(y)).zip(row(s)) {
        n += (a != b) as u32;
        *c = n;
    }
    let ring = sb.sets.len();
    let (yi, si) = (y % ring, s % ring);
    for (x, col) in sb.colsum.chunks_exact_mut(nw).enumerate() {
        let (ln, lo, at) = (left[x], gone[x], start(x));
        if ln == lo && differ[at + 2 * nw] == differ[at] {
            continue;
        }
        let slots = (
            sb.sets[yi].slot(y, ln, row(y), tw),
            sb.sets[si].slot(s, lo, row(s), tw),
        );
        if let (Some(a), Some(b)) = slots {
            let tn = sb.sets[yi].lanes(a, tw, at, nw);
            let to = sb.sets[si].lanes(b, tw, at, nw);
            if let (Ok(c), Ok(n), Ok(o)) = (
                <&mut [u32; 16]>::try_from(&mut *col),
                <&[u32; 16]>::try_from(tn),
                <&[u32; 16]>::try_from(to),
            ) {
                add_sub(c, n, o);
            } else {
                add_sub(col, tn, to);
            }
        } else {
            let (rn, ro) = (&row(y)[at..], &row(s)[at..]);
            for (i, c) in col.iter_mut().enumerate() {
                let new = word(ln.abs_diff(rn[2 * i]), ln.abs_diff(rn[2 * i + 1]));
                let old = word(lo.abs_diff(ro[2 * i]), lo.abs_diff(ro[2 * i + 1]));
                *c = c.wrapping_sub(old).wrapping_add(new);
            }
        }
    }
}

/// `c += n − o`, a word at a time.
#[inline(always)]
fn add_sub(c: &mut [u32], n: &[u32], o: &[u32]) {
    let (n, o) = (&n[..c.len()], &o[..c.len()]);
    for i in 0..c.len() {
        c[i] = c[i].wrapping_add(n[i]).wrapping_sub(o[i]);
    }
}

/// Sizes `sb` for `job` (allocating only when it grows).
fn prepare(job: &Job, sb: &mut SwarBand) {
    let w = job.left.width();
    let nw = lanes(job.params.ndisp) / 2;
    let tw = job.stride / 2 + 1;
    sb.colsum.resize(w * nw, 0);
    sb.h.resize(nw, 0);
    sb.differ.resize(job.stride + 1, 0);
    let ring = job.params.block + 1;
    sb.sets.resize_with(ring, TableSet::default);
    for set in &mut sb.sets[..ring] {
        set.owner = usize::MAX;
        set.slot_of.clear();
        set.slot_of.resize(1 << job.params.gray_bits, NO_SLOT);
        set.values.clear();
        set.words.resize(2 * SLOTS * tw, 0);
    }
    sb.sets.truncate(ring);
}

/// `h += a − s` a word at a time, and the smallest of the first `valid`
/// lanes (`valid ≥ 1`) with its index, the lowest index winning ties.
#[inline(always)]
fn slide_argmin(h: &mut [u32], a: &[u32], s: &[u32], valid: usize) -> (usize, u16) {
    let n = h.len();
    let (a, s) = (&a[..n], &s[..n]);
    let (mut best, mut k) = (u32::MAX, 0usize);
    let full = valid / 2;
    for i in 0..full {
        let v = h[i].wrapping_add(a[i]).wrapping_sub(s[i]);
        h[i] = v;
        take_word(&mut best, &mut k, v, 2 * i);
    }
    for i in full..n {
        h[i] = h[i].wrapping_add(a[i]).wrapping_sub(s[i]);
    }
    if valid % 2 == 1 {
        let first = first_low(h[full]) << 16;
        if first < best {
            (best, k) = (first, valid - 1);
        }
    }
    (k, (best >> 16) as u16)
}

/// [`slide_argmin`] over 16 words, every lane valid: unrolled.
#[inline(always)]
fn slide_argmin_32(h: &mut [u32; 16], a: &[u32; 16], s: &[u32; 16]) -> (usize, u16) {
    let (mut best, mut k) = (u32::MAX, 0usize);
    for i in 0..16 {
        let v = h[i].wrapping_add(a[i]).wrapping_sub(s[i]);
        h[i] = v;
        take_word(&mut best, &mut k, v, 2 * i);
    }
    (k, (best >> 16) as u16)
}

/// The word `v` with its first lane (in memory order) in the low half.
#[inline(always)]
fn first_low(v: u32) -> u32 {
    if cfg!(target_endian = "little") {
        v
    } else {
        v.rotate_left(16)
    }
}

/// Takes the lanes of word `v` (lanes `i`, `i + 1`) into the running
/// minimum `best` (at `k`) where they are smaller.
///
/// `best` holds the smallest cost in its high half, the low half zero: a
/// word's high lane is smaller exactly when the word is, and its low lane
/// when the word shifted up is. The first lane is compared first, so
/// `best` is below `u32::MAX` for the second.
#[inline(always)]
fn take_word(best: &mut u32, k: &mut usize, v: u32, i: usize) {
    let u = first_low(v);
    if u << 16 < *best {
        (*best, *k) = (u << 16, i);
    }
    if u < *best {
        (*best, *k) = (u & 0xFFFF_0000, i + 1);
    }
}

/// The band loop of the SWAR kernel without a min filter and without the
/// right view's map: as [`super::band_with`] in that setting.
pub(super) fn band<T: Disparity>(job: &Job, sb: &mut SwarBand, out: &mut [T]) {
    let (w, h) = job.left.dims();
    let p = job.params;
    let (nw, r) = (lanes(p.ndisp) / 2, p.block as isize / 2);
    debug_assert!(p.min_filter <= 1);
    let clamp_y = |y: isize| y.clamp(0, h as isize - 1) as usize;
    let clamp_x = |x: isize| x.clamp(0, w as isize - 1) as usize;
    prepare(job, sb);
    sb.colsum.fill(0);
    let first = job.y0;
    for dy in -r..=r {
        accumulate_row(job, sb, clamp_y(first as isize + dy), None);
    }
    for (i, out_row) in out.chunks_exact_mut(w).enumerate() {
        let y = first + i;
        if i > 0 {
            let yc = y as isize;
            accumulate_row(job, sb, clamp_y(yc + r), Some(clamp_y(yc - r - 1)));
        }
        let (colsum, hs) = (&sb.colsum, &mut sb.h);
        let col = |x: isize| &colsum[clamp_x(x) * nw..][..nw];
        hs.fill(0);
        for dx in -r..=r {
            for (h, &c) in hs.iter_mut().zip(col(dx)) {
                *h = h.wrapping_add(c);
            }
        }
        for (x, d) in out_row.iter_mut().enumerate() {
            let xi = x as isize;
            // Disparities d_min.. up to x (none below d_min).
            let valid = (x + 1).saturating_sub(p.min_disp).min(p.ndisp);
            let best = if x == 0 {
                (valid > 0).then(|| {
                    let c = as_lanes(hs);
                    let k = (0..valid).min_by_key(|&k| (c[k], k)).expect("a valid lane");
                    (k, c[k])
                })
            } else {
                let (a, s) = (col(xi + r), col(xi - r - 1));
                if valid == 32 && nw == 16 {
                    let h16: &mut [u32; 16] = hs.as_mut_slice().try_into().expect("16 words");
                    let (a, s) = (a.try_into().expect("16"), s.try_into().expect("16"));
                    Some(slide_argmin_32(h16, a, s))
                } else if valid > 0 {
                    Some(slide_argmin(hs, a, s, valid))
                } else {
                    for ((h, &a), &s) in hs.iter_mut().zip(a).zip(s) {
                        *h = h.wrapping_add(a).wrapping_sub(s);
                    }
                    None
                }
            };
            *d = match best {
                Some(best) => T::winner(as_lanes(hs), valid, best, p),
                None => T::NONE,
            };
        }
    }
}
