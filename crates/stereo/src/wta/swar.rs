//! The band loop of the SWAR kernel for the board's setting (no min filter,
//! no right-view map): a CPU without vector instructions (the ARM926) does
//! per pixel and disparity only a few word operations on two `u16` lanes.
//!
//! - **Column sums from tables.** A segmented view's row holds few gray
//!   values. For a value `l` of a row, the table `|l − R(j)|` over the
//!   row's reversed right samples `j` is built once (both word alignments),
//!   so a column's update is `colsum += new − old` read a word at a time
//!   from two tables: a load, an add and a subtract per two lanes. Tables
//!   live in a ring of sets, one set per row of the window, with where
//!   each column of the row reads them: built as the row enters, they serve
//!   again when it leaves, so a column's update looks nothing up. A value
//!   without a table slot takes the direct path (absolute differences lane
//!   by lane). Columns whose rows agree are not skipped: in a k-means view
//!   few do, and the test cost more than it saved.
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

use std::mem::take;

use super::driver::{lanes, Job};
use super::winner::Disparity;
use crate::lanes::word;

/// Table slots per row: values beyond take the direct path.
const SLOTS: usize = 6;
/// A value without a table (all slots taken): its columns are updated
/// directly.
const DIRECT: u32 = u32::MAX - 1;
/// A value not yet seen in the row (in [`TableSet::base_of`]).
const UNSEEN: u32 = u32::MAX;

/// The scratch of one band for [`band`].
#[derive(Default)]
pub(super) struct SwarBand {
    /// Column sums, `W × lanes / 2` words.
    colsum: Vec<u32>,
    /// The sliding window sum of the current pixel.
    h: Vec<u32>,
    /// The tables of the window's rows, set `y % sets.len()` for row `y`.
    sets: Vec<TableSet>,
}

/// The tables of one right row, per left gray value with a slot, and
/// which table each column of the row reads.
#[derive(Default)]
struct TableSet {
    /// The row these tables belong to (`usize::MAX`: none).
    owner: usize,
    /// Per gray value, where its table starts in `words` (slot `k` at
    /// `2 k · tw`), or [`DIRECT`] or [`UNSEEN`].
    base_of: Vec<u32>,
    /// The values seen in the row, in order.
    values: Vec<u16>,
    /// Per slot, two tables of `tw` words: lanes `(2i, 2i + 1)` and
    /// `(2i + 1, 2i + 2)` of `|l − R(j)|` at word `i`.
    words: Vec<u32>,
    /// Per column of the row, the start of its value's table (or
    /// [`DIRECT`]): set as the row enters the window, read again as it
    /// leaves.
    at: Vec<u32>,
}

impl TableSet {
    /// Makes this set row `y`'s: the tables of its values (as far as slots
    /// go) and each column's. Nothing to do when it already is.
    fn enter(&mut self, job: &Job, y: usize) {
        if self.owner == y {
            return;
        }
        for &v in &self.values {
            self.base_of[v as usize] = UNSEEN;
        }
        self.values.clear();
        self.owner = y;
        let (w, stride) = (job.left.width(), job.stride);
        let rev = &job.reversed[y * stride..(y + 1) * stride];
        // Taken out while the row is read, so that the loop holds them
        // (`add` touches neither).
        let (mut ats, mut base_of) = (take(&mut self.at), take(&mut self.base_of));
        for (at, &l) in ats[..w].iter_mut().zip(job.left.row(y)) {
            let base = &mut base_of[l as usize];
            if *base == UNSEEN {
                *base = self.add(l, rev);
            }
            *at = *base;
        }
        (self.at, self.base_of) = (ats, base_of);
    }

    /// Gives value `l` (first seen in the row whose reversed right samples
    /// are `rev`) a slot and builds its table, or [`DIRECT`] when full;
    /// returns its table's start, for [`TableSet::base_of`].
    #[cold]
    fn add(&mut self, l: u16, rev: &[u16]) -> u32 {
        let tw = rev.len() / 2 + 1;
        // The first SLOTS values have the slots.
        let s = self.values.len();
        self.values.push(l);
        if s >= SLOTS {
            DIRECT
        } else {
            let (t0, t1) = self.words[2 * s * tw..2 * (s + 1) * tw].split_at_mut(tw);
            build_table(l, rev, t0, t1);
            (2 * s * tw) as u32
        }
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

/// The words of `v` as `u16` lanes in memory order.
#[inline(always)]
fn as_lanes(v: &[u32]) -> &[u16] {
    // SAFETY: two u16 fit a u32 exactly, with no stricter alignment, and
    // every bit pattern is valid for both.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), 2 * v.len()) }
}

/// `v` as columns of `NW` words (a remainder left out).
#[inline(always)]
fn columns<const NW: usize>(v: &[u32]) -> &[[u32; NW]] {
    // SAFETY: `[u32; NW]` has the size of NW u32 and their alignment; the
    // length rounds down.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), v.len() / NW) }
}

/// [`columns`], mutable.
#[inline(always)]
fn columns_mut<const NW: usize>(v: &mut [u32]) -> &mut [[u32; NW]] {
    // SAFETY: as in `columns`, from a unique borrow.
    unsafe { std::slice::from_raw_parts_mut(v.as_mut_ptr().cast(), v.len() / NW) }
}

/// The words of `|l − R|` for one column: lanes `(2i, 2i + 1)` of the
/// right samples `r`.
#[inline(always)]
fn direct<const NW: usize>(l: u16, r: &[u16]) -> [u32; NW] {
    std::array::from_fn(|i| word(l.abs_diff(r[2 * i]), l.abs_diff(r[2 * i + 1])))
}

/// Adds the absolute differences of row `y` to the column sums (`NW` words
/// each) and subtracts those of row `leaving` when given, from the tables
/// where the values have them.
fn accumulate_row<const NW: usize>(job: &Job, sb: &mut SwarBand, y: usize, leaving: Option<usize>) {
    let ring = sb.sets.len();
    sb.sets[y % ring].enter(job, y);
    let w = job.left.width();
    let tw = job.stride / 2 + 1;
    // Column x reads its right pixels from reversed index `start(x)` on:
    // table word `start(x) / 2` of the table of that index's parity.
    let start = |x: usize| w + job.params.min_disp - 1 - x;
    let row = |y: usize| &job.reversed[y * job.stride..(y + 1) * job.stride];
    let cols = columns_mut::<NW>(&mut sb.colsum);
    let new = &sb.sets[y % ring];
    // Every table start is `2 k · tw` with k < SLOTS, and a column reads
    // `NW` words from `tw + start(x) / 2` past it at most: inside `words`.
    let last = (2 * SLOTS - 1) * tw + start(0) / 2 + NW;
    assert!(last <= new.words.len());
    let Some(s) = leaving else {
        for (x, (col, &a)) in cols.iter_mut().zip(&new.at[..w]).enumerate() {
            let j = start(x);
            let n = if a < DIRECT {
                new.words[a as usize + j / 2 + (j % 2) * tw..][..NW]
                    .try_into()
                    .expect("NW")
            } else {
                direct::<NW>(job.left.row(y)[x], &row(y)[j..])
            };
            for (c, n) in col.iter_mut().zip(n) {
                *c = c.wrapping_add(n);
            }
        }
        return;
    };
    // The leaving row entered at most `block` rows ago: its set is its own.
    let old = &sb.sets[s % ring];
    debug_assert_eq!(old.owner, s);
    assert!(last <= old.words.len());
    let columns = cols.iter_mut().zip(&new.at[..w]).zip(&old.at[..w]);
    for (x, ((col, &a), &b)) in columns.enumerate() {
        let j = start(x);
        let off = j / 2 + (j % 2) * tw;
        if a.max(b) < DIRECT {
            let (a, b) = (a as usize + off, b as usize + off);
            // SAFETY: `a` and `b` are table starts plus `off`, so
            // `a + NW` and `b + NW` are at most `last` (the assertion).
            let (tn, to) = unsafe {
                (
                    &*new.words.as_ptr().add(a).cast::<[u32; NW]>(),
                    &*old.words.as_ptr().add(b).cast::<[u32; NW]>(),
                )
            };
            add_sub(col, tn, to);
        } else {
            let (ln, lo) = (job.left.row(y)[x], job.left.row(s)[x]);
            let n = direct::<NW>(ln, &row(y)[j..]);
            let o = direct::<NW>(lo, &row(s)[j..]);
            add_sub(col, &n, &o);
        }
    }
}

/// Sizes `sb` for `job` (allocating only when it grows).
fn prepare(job: &Job, sb: &mut SwarBand) {
    let w = job.left.width();
    let nw = lanes(job.params.ndisp) / 2;
    let tw = job.stride / 2 + 1;
    sb.colsum.resize(w * nw, 0);
    sb.h.resize(nw, 0);
    let ring = job.params.block + 1;
    sb.sets.resize_with(ring, TableSet::default);
    for set in &mut sb.sets[..ring] {
        set.owner = usize::MAX;
        set.base_of.clear();
        set.base_of.resize(1 << job.params.gray_bits, UNSEEN);
        set.values.clear();
        set.words.resize(2 * SLOTS * tw, 0);
        set.at.resize(w, DIRECT);
    }
    sb.sets.truncate(ring);
}

/// `c += n − o`, a word at a time.
#[inline(always)]
fn add_sub<const NW: usize>(c: &mut [u32; NW], n: &[u32; NW], o: &[u32; NW]) {
    #[cfg(all(target_arch = "arm", target_endian = "little"))]
    if NW == 16 {
        // SAFETY: the three arrays hold 16 words each; the block reads
        // 64 bytes from `n` and `o` and reads and writes 64 at `c`.
        unsafe { arm::add_sub_16(c.as_mut_ptr(), n.as_ptr(), o.as_ptr()) };
        return;
    }
    for i in 0..NW {
        c[i] = c[i].wrapping_add(n[i]).wrapping_sub(o[i]);
    }
}

/// `h += a − s` a word at a time, and the smallest of the first `valid`
/// lanes (`valid ≥ 1`) with its index, the lowest index winning ties.
#[inline(always)]
fn slide_argmin<const NW: usize>(
    h: &mut [u32; NW],
    a: &[u32; NW],
    s: &[u32; NW],
    valid: usize,
) -> (usize, u16) {
    let (mut best, mut k) = (u32::MAX, 0usize);
    let full = valid / 2;
    for i in 0..NW {
        h[i] = h[i].wrapping_add(a[i]).wrapping_sub(s[i]);
        if i < full {
            take_word(&mut best, &mut k, h[i], 2 * i);
        }
    }
    if valid % 2 == 1 {
        let first = first_low(h[full]) << 16;
        if first < best {
            (best, k) = (first, valid - 1);
        }
    }
    (k, (best >> 16) as u16)
}

/// [`slide_argmin`] with every lane valid: unrolled.
#[inline(always)]
fn slide_argmin_all<const NW: usize>(
    h: &mut [u32; NW],
    a: &[u32; NW],
    s: &[u32; NW],
) -> (usize, u16) {
    #[cfg(all(target_arch = "arm", target_endian = "little"))]
    if NW == 16 {
        // SAFETY: the three arrays hold 16 words each; the block reads 64
        // bytes from `a` and `s` and reads and writes 64 at `h`.
        return unsafe { arm::slide_argmin_32(h.as_mut_ptr(), a.as_ptr(), s.as_ptr()) };
    }
    let (mut best, mut k) = (u32::MAX, 0usize);
    for i in 0..NW {
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
/// right view's map: as [`super::portable::band_with`] in that setting.
/// False (and nothing done) for more than 64 disparity lanes.
pub(super) fn band<T: Disparity>(job: &Job, sb: &mut SwarBand, out: &mut [T]) -> bool {
    match lanes(job.params.ndisp) / 2 {
        8 => band_words::<T, 8>(job, sb, out),
        16 => band_words::<T, 16>(job, sb, out),
        24 => band_words::<T, 24>(job, sb, out),
        32 => band_words::<T, 32>(job, sb, out),
        _ => return false,
    }
    true
}

/// [`band`] with `NW` words (`2 · NW` lanes) per column.
fn band_words<T: Disparity, const NW: usize>(job: &Job, sb: &mut SwarBand, out: &mut [T]) {
    let (w, h) = job.left.dims();
    let p = job.params;
    let r = p.block / 2;
    debug_assert!(p.min_filter <= 1);
    let clamp_y = |y: isize| y.clamp(0, h as isize - 1) as usize;
    prepare(job, sb);
    sb.colsum.fill(0);
    let first = job.y0;
    let ri = r as isize;
    for dy in -ri..=ri {
        accumulate_row::<NW>(job, sb, clamp_y(first as isize + dy), None);
    }
    // The first pixel whose lanes are all valid disparities.
    let all_valid = (p.ndisp == 2 * NW).then_some(p.min_disp + 2 * NW - 1);
    for (i, out_row) in out.chunks_exact_mut(w).enumerate() {
        let y = first + i;
        if i > 0 {
            let yc = y as isize;
            accumulate_row::<NW>(job, sb, clamp_y(yc + ri), Some(clamp_y(yc - ri - 1)));
        }
        let cols = columns::<NW>(&sb.colsum);
        let hs: &mut [u32; NW] = sb.h.as_mut_slice().try_into().expect("NW words");
        // The window sum at x = 0 (columns left of the image are column 0).
        hs.fill(0);
        for dx in 0..=2 * r {
            let c = &cols[dx.saturating_sub(r).min(w - 1)];
            for (h, &c) in hs.iter_mut().zip(c) {
                *h = h.wrapping_add(c);
            }
        }
        let valid = |x: usize| (x + 1).saturating_sub(p.min_disp).min(p.ndisp);
        out_row[0] = match valid(0) {
            0 => T::NONE,
            v => {
                let c = as_lanes(hs);
                let k = (0..v).min_by_key(|&k| (c[k], k)).expect("a valid lane");
                T::winner(c, v, (k, c[k]), p)
            }
        };
        // Then slide: column x + r enters, x − r − 1 leaves (clamped).
        let fast_from = all_valid.unwrap_or(w).clamp(1, w);
        for x in 1..fast_from {
            let (a, s) = (&cols[(x + r).min(w - 1)], &cols[x.saturating_sub(r + 1)]);
            out_row[x] = match valid(x) {
                0 => {
                    for ((h, &a), &s) in hs.iter_mut().zip(a).zip(s) {
                        *h = h.wrapping_add(a).wrapping_sub(s);
                    }
                    T::NONE
                }
                v => {
                    let best = slide_argmin(hs, a, s, v);
                    T::winner(as_lanes(hs), v, best, p)
                }
            };
        }
        // The columns `from..inner` slide without clamping: the entering
        // column x + r is inside, the leaving one x − r − 1 too; the
        // others clamp them.
        let inner = (w - r).max(fast_from).max(r + 1).min(w);
        let from = fast_from.max(r + 1).min(inner);
        let clamped = |x: usize| (&cols[(x + r).min(w - 1)], &cols[x.saturating_sub(r + 1)]);
        let mut pixel = |d: &mut T, (a, s): (&[u32; NW], &[u32; NW])| {
            let best = slide_argmin_all(hs, a, s);
            *d = T::winner(as_lanes(hs), 2 * NW, best, p);
        };
        for (x, d) in out_row.iter_mut().enumerate().take(from).skip(fast_from) {
            pixel(d, clamped(x));
        }
        if from < inner {
            let slide = cols[from + r..].iter().zip(&cols[from - r - 1..]);
            for (d, a_s) in out_row[from..inner].iter_mut().zip(slide) {
                pixel(d, a_s);
            }
        }
        for (x, d) in out_row.iter_mut().enumerate().skip(inner) {
            pixel(d, clamped(x));
        }
    }
}

/// The two hot loops for 16 words (32 lanes) in ARM assembly: the compiler
/// spills and does not pair the loads, while `ldm`/`stm` move two words
/// per instruction and the running minimum needs a mask in a register.
/// Same arithmetic as the portable loops; the SWAR tests run them under
/// `qemu-arm -cpu arm926` (`tools/arm926/board test`).
#[cfg(all(target_arch = "arm", target_endian = "little"))]
mod arm {
    use std::arch::asm;

    /// `c[i] += n[i] − o[i]` for 16 words.
    ///
    /// # Safety
    /// `c`, `n` and `o` must each point to 16 valid words, `c` writable.
    #[inline(always)]
    pub(super) unsafe fn add_sub_16(c: *mut u32, n: *const u32, o: *const u32) {
        // SAFETY: forwarded from the caller; the registers named are
        // declared clobbered, the pointers are consumed.
        unsafe {
            asm!(
                ".rept 8",
                "ldm {c}, {{r4, r5}}",
                "ldm {n}!, {{r8, r10}}",
                "add r4, r4, r8",
                "add r5, r5, r10",
                "ldm {o}!, {{r8, r10}}",
                "sub r4, r4, r8",
                "sub r5, r5, r10",
                "stm {c}!, {{r4, r5}}",
                ".endr",
                c = inout(reg) c => _,
                n = inout(reg) n => _,
                o = inout(reg) o => _,
                out("r4") _,
                out("r5") _,
                out("r8") _,
                out("r10") _,
                options(nostack, preserves_flags),
            );
        }
    }

    /// `h[i] += a[i] − s[i]` for 16 words, and the smallest of the 32
    /// lanes with its index (the lowest index winning ties), as
    /// `super::slide_argmin_all`.
    ///
    /// # Safety
    /// `h`, `a` and `s` must each point to 16 valid words, `h` writable.
    #[inline(always)]
    pub(super) unsafe fn slide_argmin_32(
        h: *mut u32,
        a: *const u32,
        s: *const u32,
    ) -> (usize, u16) {
        let (best, k): (u32, u32);
        // SAFETY: forwarded from the caller; the registers named are
        // declared clobbered, the pointers are consumed. Per word: its
        // low lane is compared shifted up (`cmp best, r4, lsl #16`), its
        // high lane as the word itself (`best` keeps its low half zero).
        unsafe {
            asm!(
                "mvn {best}, #0",
                "mov {k}, #0",
                ".irp j, 0, 1, 2, 3, 4, 5, 6, 7",
                "ldm {h}, {{r4, r5}}",
                "ldm {a}!, {{r8, r10}}",
                "add r4, r4, r8",
                "add r5, r5, r10",
                "ldm {s}!, {{r8, r10}}",
                "sub r4, r4, r8",
                "sub r5, r5, r10",
                "stm {h}!, {{r4, r5}}",
                "cmp {best}, r4, lsl #16",
                "movhi {best}, r4, lsl #16",
                "movhi {k}, #(4 * \\j)",
                "cmp r4, {best}",
                "andlo {best}, r4, {mask}",
                "movlo {k}, #(4 * \\j + 1)",
                "cmp {best}, r5, lsl #16",
                "movhi {best}, r5, lsl #16",
                "movhi {k}, #(4 * \\j + 2)",
                "cmp r5, {best}",
                "andlo {best}, r5, {mask}",
                "movlo {k}, #(4 * \\j + 3)",
                ".endr",
                h = inout(reg) h => _,
                a = inout(reg) a => _,
                s = inout(reg) s => _,
                mask = in(reg) 0xFFFF_0000u32,
                best = out(reg) best,
                k = out(reg) k,
                out("r4") _,
                out("r5") _,
                out("r8") _,
                out("r10") _,
                options(nostack),
            );
        }
        (k as usize, (best >> 16) as u16)
    }
}
