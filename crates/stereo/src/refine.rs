//! Refinement usable after any matcher: left-right consistency check,
//! subpixel parabola fit (done inside the matchers, which hold the costs),
//! median filter, colour-weighted median, and hole filling so that the
//! output can be dense.
//!
//! Each default step lowers the bad-pixel rate on the Middlebury v2
//! scenes (`stereolink eval`; docs/tuning.md, “All matchers” and “WTA”).

use rayon::prelude::*;
use stereolink_image::{DisparityMap, Plane, RgbImage};

pub use crate::median::median;
pub use crate::weighted_median::{weighted_median, WeightedMedian, WeightedMedianGuide};
use crate::{Algorithm, MatchSpec};

/// Which refinement steps run, in this order: LR check, median, weighted
/// median, fill, weighted median again.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Refinement {
    /// Invalidate pixels whose left and right disparities differ by more than this.
    pub lr_check: Option<f32>,
    /// Fit a parabola through the winner's neighbouring costs.
    pub subpixel: bool,
    /// WTA uniqueness margin in percent (0 = off).
    pub uniqueness: u32,
    /// Median filter size over valid pixels (0 or 1 = off, else odd).
    pub median: usize,
    /// Colour-weighted median guided by the left view: once on the checked
    /// map and once after the fill (it cleans the fill's streaks). Before a
    /// fill, only the valid pixels next to a hole take the median (those
    /// whose values the fill spreads; the holes are the fill's), with the
    /// sparser window of [`WeightedMedian::before_fill`]; without one, all
    /// pixels take it, holes too (valid pixels vote, so it fills holes
    /// among similar colours).
    pub weighted_median: Option<WeightedMedian>,
    /// How invalid pixels are filled, if at all.
    pub fill: Option<HoleFill>,
}

/// Hole-filling strategies for a dense output.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum HoleFill {
    /// Each invalid run of a row takes the smaller (farther) of the valid
    /// disparities at its two ends: occlusions belong to the background.
    Row,
    /// Each invalid pixel takes the median of the nearest valid disparities
    /// along the 8 directions (Hirschmüller 2008, §3.4, as for mismatches);
    /// see docs/tuning.md, “Hole filling”, for how it compares with
    /// [`HoleFill::Row`].
    Directions,
}

impl std::str::FromStr for HoleFill {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "row" => Ok(HoleFill::Row),
            "directions" | "dirs" => Ok(HoleFill::Directions),
            _ => Err(format!("unknown hole fill {s:?} (row or directions)")),
        }
    }
}

impl Refinement {
    /// No refinement at all: the raw matcher output.
    pub const NONE: Refinement = Refinement {
        lr_check: None,
        subpixel: false,
        uniqueness: 0,
        median: 0,
        weighted_median: None,
        fill: None,
    };

    /// The defaults for an algorithm (dense output).
    ///
    /// The subpixel fit is off: on the Middlebury v2 scenes it raises the
    /// bad > 1 px rate, as Tsukuba's ground truth is whole pixels and a fit
    /// moves a winner one pixel off to beyond one. It is on where distances
    /// matter more than that score (the depth report of `send` and `demo`):
    /// a region's median disparity is then not rounded to whole pixels.
    /// See docs/tuning.md, “Subpixel fit”.
    pub fn default_for(algorithm: Algorithm) -> Refinement {
        match algorithm {
            // WTA: the LR check asks for equal disparities (tolerance 0.5
            // on whole pixels), then the colour-weighted median
            // (`WeightedMedian::DEFAULT`) before (valid pixels next to
            // holes only, the sparser `before_fill` window) and after the
            // fill. It beats the SSD+MF baseline on all four v2
            // scenes; a 5×5 median in its place (`--weighted-median 0
            // --median 5`) is a little faster but misses it on two
            // (docs/tuning.md, “The colour-weighted median as the default
            // refinement”).
            Algorithm::Wta => Refinement {
                lr_check: Some(0.5),
                subpixel: false,
                uniqueness: 0,
                median: 0,
                weighted_median: Some(WeightedMedian::DEFAULT),
                fill: Some(HoleFill::Directions),
            },
            Algorithm::Sgm => Refinement {
                lr_check: Some(1.0),
                subpixel: false,
                uniqueness: 0,
                median: 5,
                weighted_median: None,
                fill: Some(HoleFill::Directions),
            },
            // The planes give a dense subpixel map already; a small
            // colour-weighted median then snaps its depth edges to the
            // colour edges (`WeightedMedian::AFTER_PLANES`).
            Algorithm::Planes => Refinement {
                weighted_median: Some(WeightedMedian::AFTER_PLANES),
                ..Refinement::NONE
            },
            Algorithm::LineGrowing => Refinement {
                lr_check: None,
                subpixel: false,
                uniqueness: 0,
                median: 3,
                weighted_median: None,
                fill: Some(HoleFill::Row),
            },
        }
    }
}

/// A matcher's output before refinement: the left map and, where the
/// matcher can give it, the right view's map for the LR check.
pub struct Raw {
    /// Left-view disparity.
    pub disparity: DisparityMap,
    /// Right-view disparity (right `(x, y)` matches left `(x + d, y)`).
    pub right: Option<DisparityMap>,
}

/// The buffers of [`postprocess`], kept from one call to the next (the
/// weighted median's guide, a second map and the fill's lists): refining
/// frames of an unchanged size allocates only the map it returns.
#[derive(Default)]
pub struct RefineBuffers {
    guide: Option<WeightedMedianGuide>,
    spare: DisparityMap,
    fill: FillBuffers,
}

/// Runs the refinement steps of `spec` on a raw result; `guide` is the
/// left view (for the weighted median).
pub fn postprocess(
    raw: Raw,
    spec: &MatchSpec,
    guide: &RgbImage,
    buffers: &mut RefineBuffers,
) -> DisparityMap {
    let r = &spec.refine;
    let mut d = raw.disparity;
    if let (Some(tol), Some(right)) = (r.lr_check, &raw.right) {
        lr_check(&mut d, right, tol);
    }
    if r.median > 1 {
        d = median(&d, r.median);
    }
    // One guide serves both weighted-median passes (built for the first,
    // whose window is the wider); each filters from `d` into the spare
    // map, which then changes places with `d`.
    let RefineBuffers {
        guide: wm,
        spare,
        fill,
    } = buffers;
    if let Some(p) = r.weighted_median {
        // Holes left to the fill, and only the pixels next to them, which
        // the fill reads: after WTA this is more accurate, and cheaper,
        // than the median on all valid pixels or on the holes too
        // (docs/tuning.md, “The colour-weighted median as the default
        // refinement”).
        match r.fill {
            Some(_) => guide_for(wm, guide, &p.before_fill()).filter_borders(&d, spare),
            None => guide_for(wm, guide, &p).filter(&d, spare),
        }
        std::mem::swap(&mut d, spare);
    }
    match r.fill {
        Some(HoleFill::Row) => fill_holes(&mut d),
        Some(HoleFill::Directions) => fill_from_directions_with(&mut d, fill),
        None => {}
    }
    if let (Some(p), Some(wm)) = (r.weighted_median, wm.as_mut().filter(|_| r.fill.is_some())) {
        // The first pass's window is the wider: its guide serves.
        wm.set_window(&p);
        wm.filter(&d, spare);
        std::mem::swap(&mut d, spare);
    }
    d
}

/// The weighted median's guide of `guide` for `p`, in the buffers of
/// `kept` (built there on first use).
fn guide_for<'a>(
    kept: &'a mut Option<WeightedMedianGuide>,
    guide: &RgbImage,
    p: &WeightedMedian,
) -> &'a mut WeightedMedianGuide {
    match kept {
        Some(wm) => {
            wm.rebuild(guide, p);
            wm
        }
        None => kept.insert(WeightedMedianGuide::new(guide, p)),
    }
}

/// Sub-pixel offset of the minimum of the parabola through `(−1, c0)`,
/// `(0, c1)`, `(1, c2)`, in `[−0.5, 0.5]`; 0 when the costs are flat.
#[inline]
pub fn parabola(c0: f32, c1: f32, c2: f32) -> f32 {
    let denom = c0 + c2 - 2.0 * c1;
    if denom > 0.0 {
        ((c0 - c2) / (2.0 * denom)).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

/// Invalidates left pixels whose match in the right map disagrees by more
/// than `tol`; the match is the right pixel nearest to `x − d` (ties to the
/// right). Rows run in parallel.
pub fn lr_check(left: &mut DisparityMap, right: &DisparityMap, tol: f32) {
    let w = left.width();
    if w == 0 {
        return;
    }
    let rows = left.as_mut_slice().par_chunks_mut(w);
    rows.zip(right.as_slice().par_chunks(w))
        .for_each(|(row, rrow)| {
            // Pixels a group at a time: the matches' places in one loop
            // (branch-free, so that it vectorises), then the look-ups and
            // the test (a float-to-index conversion per pixel, with its
            // range checks, took three times as long).
            const GROUP: usize = 64;
            let mut at = [0i32; GROUP];
            for (g, ds) in row.chunks_mut(GROUP).enumerate() {
                let x0 = (g * GROUP) as f32;
                for ((i, a), &d) in at.iter_mut().enumerate().zip(ds.iter()) {
                    // Non-finite `d` gives a non-finite or negative `xr`:
                    // dropped (`-1`, outside, as for any `xr < 0`).
                    let xr = x0 + i as f32 - d + 0.5;
                    let inside = (xr >= 0.0) & (xr < w as f32);
                    *a = if inside { xr as i32 } else { -1 };
                }
                for (d, &a) in ds.iter_mut().zip(&at) {
                    let dr = rrow.get(a as usize).copied().unwrap_or(f32::NAN);
                    // NaN (no match) fails the test.
                    let ok = (dr - *d).abs() <= tol;
                    *d = if ok { *d } else { f32::INFINITY };
                }
            }
        });
}

/// Fills each invalid run of a row with the smaller of the valid disparities
/// at its two ends (occlusions belong to the background); rows without any
/// valid pixel take the nearest filled row above or below. Rows run in parallel.
pub fn fill_holes(map: &mut DisparityMap) {
    let (w, h) = map.dims();
    if w == 0 {
        return;
    }
    let filled: Vec<bool> = map.as_mut_slice().par_chunks_mut(w).map(fill_row).collect();
    for y in (0..h).filter(|&y| !filled[y]) {
        let source = (0..h).filter(|&r| filled[r]).min_by_key(|r| r.abs_diff(y));
        if let Some(src) = source {
            let copy = map.row(src).to_vec();
            map.row_mut(y).copy_from_slice(&copy);
        }
    }
}

/// [`fill_holes`] within one row; false if the row has no valid pixel.
fn fill_row(row: &mut [f32]) -> bool {
    let w = row.len();
    let mut x = 0;
    let mut any = false;
    while x < w {
        if row[x].is_finite() {
            any = true;
            x += 1;
            continue;
        }
        let start = x;
        while x < w && !row[x].is_finite() {
            x += 1;
        }
        let before = start.checked_sub(1).map(|i| row[i]);
        let after = (x < w).then(|| row[x]);
        let fill = match (before, after) {
            (Some(a), Some(b)) => a.min(b),
            (Some(a), None) => a,
            (None, Some(b)) => b,
            (None, None) => continue,
        };
        row[start..x].fill(fill);
    }
    any
}

/// [`HoleFill::Directions`]: each invalid pixel takes the median (the lower
/// one for an even count) of the nearest valid disparities along the 8
/// directions; pixels that see none are left to [`fill_holes`].
///
/// Two raster passes, O(W·H) whatever the holes, run in parallel: the
/// forward pass carries, per column, the nearest valid value from the north,
/// north-west and north-east from row to row (branch-free selects on whole
/// rows) and follows each row for the west; the backward pass does the same
/// from the south and east. Each writes its four values per invalid pixel
/// into lists in raster order (the backward pass from the end: the holes
/// are counted first), one list per direction, so that the medians of the
/// eight come from a sorting network run on [`LANES`] holes at once.
pub fn fill_from_directions(map: &mut DisparityMap) {
    fill_from_directions_with(map, &mut FillBuffers::default())
}

/// Holes whose medians one run of the sorting network takes.
const LANES: usize = 8;

/// Holes a parallel task of [`fill_from_directions_with`] takes the
/// medians of (a multiple of [`LANES`]).
const MEDIAN_RUN: usize = 64 * LANES;

/// The lists of [`fill_from_directions_with`], kept from one call to the
/// next.
#[derive(Default)]
pub struct FillBuffers {
    /// The holes' indices, in raster order.
    holes: Vec<usize>,
    /// Per direction, the nearest valid value of each hole, in raster
    /// order: west, north-west, north, north-east (the forward pass), then
    /// east, south-east, south, south-west (the backward one).
    near: [Vec<f32>; 8],
}

/// [`fill_from_directions`] in the lists of `buffers` (resized, storage
/// reused: no allocation, nor page faults, for maps of a size seen before).
pub fn fill_from_directions_with(map: &mut DisparityMap, buffers: &mut FillBuffers) {
    let w = map.width();
    if w == 0 {
        return;
    }
    let n = map
        .as_slice()
        .par_chunks(w)
        .map(|row| row.iter().filter(|&&d| !valid(d)).count())
        .sum::<usize>();
    let FillBuffers { holes, near } = buffers;
    holes.resize(n, 0);
    for list in near.iter_mut() {
        list.resize(n, f32::INFINITY);
    }
    let (forward, backward) = near.split_at_mut(4);
    rayon::join(
        || nearest_valid(map, false, forward, Some(holes)),
        || nearest_valid(map, true, backward, None),
    );
    // The medians, `LANES` holes at a time (the last run padded with
    // holes that see nothing), runs of them in parallel, into the west
    // list (each hole's median once its eight are read); then each to its
    // hole.
    let (west, others) = near.split_first_mut().expect("eight directions");
    let others = &*others;
    let unfilled = west
        .par_chunks_mut(MEDIAN_RUN)
        .enumerate()
        .map(|(run, out)| {
            let mut unfilled = false;
            for (k, out) in out.chunks_mut(LANES).enumerate() {
                let start = run * MEDIAN_RUN + k * LANES;
                let lanes = out.len();
                let mut v = [[f32::INFINITY; LANES]; 8];
                v[0][..lanes].copy_from_slice(out);
                for (v, list) in v[1..].iter_mut().zip(others) {
                    v[..lanes].copy_from_slice(&list[start..start + lanes]);
                }
                let medians = medians_of_valid(&mut v);
                out.copy_from_slice(&medians[..lanes]);
                unfilled |= medians[..lanes].iter().any(|&m| !valid(m));
            }
            unfilled
        })
        .reduce(|| false, |a, b| a | b);
    let values = map.as_mut_slice();
    for (&at, &m) in holes.iter().zip(west.iter()) {
        values[at] = m;
    }
    // Holes that see no valid pixel in any direction are the row fill's.
    if unfilled {
        fill_holes(map);
    }
}

/// Writes into `near` (each as long as the map has holes), for every
/// invalid pixel in raster order, the nearest valid values along the row
/// (west, or east when `backward`), its diagonal through the left
/// neighbour's row, straight, and the diagonal through the right; the rows
/// before it are those above (or below). With `holes`, the pixels' indices
/// too.
fn nearest_valid(
    map: &DisparityMap,
    backward: bool,
    near: &mut [Vec<f32>],
    holes: Option<&mut Vec<usize>>,
) {
    let (w, h) = map.dims();
    let [west, from_left, straight, from_right] = near else {
        unreachable!("four directions a pass")
    };
    // Slices, not the vectors: their pointers stay in registers.
    let (west, from_left) = (west.as_mut_slice(), from_left.as_mut_slice());
    let (straight, from_right) = (straight.as_mut_slice(), from_right.as_mut_slice());
    let mut holes = holes.map(|h| h.as_mut_slice());
    let n = west.len();
    // Holes listed so far.
    let mut k = 0;
    let mut pass = DirectionPass::new(w);
    for i in 0..h {
        let y = if backward { h - 1 - i } else { i };
        let row = map.row(y);
        pass.find_holes(row);
        let count = pass.holes.len();
        // The nearest valid value along the row: the neighbour's, or when
        // the neighbour is a hole too (the hole before in the list) that
        // hole's (a select, not a branch: holes are scattered).
        let mut along = f32::INFINITY;
        for j in 0..count {
            let (x, neighbour) = if backward {
                let x = pass.holes[count - 1 - j];
                (x, row.get(x + 1))
            } else {
                let x = pass.holes[j];
                (x, x.checked_sub(1).map(|n| &row[n]))
            };
            along = pick(neighbour.copied().unwrap_or(f32::INFINITY), along);
            let at = if backward { n - 1 - k } else { k };
            let [s, l, r] = pass.carried(x);
            (west[at], from_left[at], straight[at], from_right[at]) = (along, l, s, r);
            if let Some(holes) = holes.as_deref_mut() {
                holes[at] = y * w + x;
            }
            k += 1;
        }
        pass.advance(row);
    }
}

/// Whether `d` is a valid (finite, disparities are never NaN) disparity,
/// as one vector comparison.
#[inline(always)]
fn valid(d: f32) -> bool {
    d.abs() < f32::INFINITY
}

/// One raster pass of [`fill_from_directions`]: per column, the nearest
/// valid value straight above (or below), and on the diagonals through the
/// left and right neighbours, for the row being visited.
struct DirectionPass {
    carry: [Vec<f32>; 3],
    next: [Vec<f32>; 3],
    /// The invalid pixels of the row, ascending.
    holes: Vec<usize>,
}

impl DirectionPass {
    fn new(w: usize) -> Self {
        let none = vec![f32::INFINITY; w];
        DirectionPass {
            carry: [none.clone(), none.clone(), none.clone()],
            next: [none.clone(), none.clone(), none],
            holes: Vec::with_capacity(w),
        }
    }

    /// Lists the invalid pixels of `row`, ascending: a bit mask of 64
    /// pixels at a time ([`holes_mask`]), then its set bits.
    fn find_holes(&mut self, row: &[f32]) {
        self.holes.clear();
        for (c, chunk) in row.chunks(64).enumerate() {
            let mut bits = holes_mask(chunk);
            while bits != 0 {
                self.holes.push(64 * c + bits.trailing_zeros() as usize);
                bits &= bits - 1;
            }
        }
    }

    /// Straight, from-the-left and from-the-right values carried to column `x`.
    fn carried(&self, x: usize) -> [f32; 3] {
        [self.carry[0][x], self.carry[1][x], self.carry[2][x]]
    }

    /// Carries the values past `row` to the next row: a valid pixel starts
    /// its column's value, an invalid one passes on what reached it; the
    /// diagonals move one column.
    fn advance(&mut self, row: &[f32]) {
        fn pick_all(out: &mut [f32], row: &[f32], old: &[f32]) {
            for ((o, &d), &old) in out.iter_mut().zip(row).zip(old) {
                *o = pick(d, old);
            }
        }
        let w = row.len();
        let [straight, from_left, from_right] = &mut self.next;
        pick_all(straight, row, &self.carry[0]);
        from_left[0] = f32::INFINITY;
        pick_all(&mut from_left[1..], &row[..w - 1], &self.carry[1][..w - 1]);
        from_right[w - 1] = f32::INFINITY;
        pick_all(&mut from_right[..w - 1], &row[1..], &self.carry[2][1..]);
        std::mem::swap(&mut self.carry, &mut self.next);
    }
}

/// Bit `i` set where `chunk[i]` (at most 64) is invalid: on x86-64 four
/// pixels a compare and a `movmskps` (SSE2, always there), the portable
/// fold taking several instructions a pixel.
#[inline(always)]
fn holes_mask(chunk: &[f32]) -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        let mut quads = chunk.chunks_exact(4);
        let mut bits = 0u64;
        for (k, q) in (&mut quads).enumerate() {
            // SAFETY: SSE2 is part of x86-64; `q` holds four f32.
            let invalid = unsafe {
                let v = _mm_loadu_ps(q.as_ptr());
                let magnitude = _mm_andnot_ps(_mm_set1_ps(-0.0), v);
                // Not below infinity: unordered compare, true for NaN too.
                _mm_movemask_ps(_mm_cmpnlt_ps(magnitude, _mm_set1_ps(f32::INFINITY)))
            };
            bits |= (invalid as u64) << (4 * k);
        }
        let done = chunk.len() - quads.remainder().len();
        bits | holes_mask_portable(quads.remainder()) << done
    }
    #[cfg(not(target_arch = "x86_64"))]
    holes_mask_portable(chunk)
}

/// [`holes_mask`] in portable Rust.
#[inline(always)]
fn holes_mask_portable(chunk: &[f32]) -> u64 {
    (chunk.iter().enumerate()).fold(0u64, |m, (i, &d)| m | u64::from(!valid(d)) << i)
}

/// `d` if it is valid, else `old`: a bit-mask select (as an `if`, LLVM
/// emits a branch per pixel).
#[inline(always)]
fn pick(d: f32, old: f32) -> f32 {
    let keep = u32::from(valid(d)).wrapping_neg();
    f32::from_bits(d.to_bits() & keep | old.to_bits() & !keep)
}

/// The optimal 19-comparator network sorting eight values.
#[rustfmt::skip]
const SORT8: [(usize, usize); 19] = [
    (0, 2), (1, 3), (4, 6), (5, 7),
    (0, 4), (1, 5), (2, 6), (3, 7),
    (0, 1), (2, 3), (4, 5), (6, 7),
    (2, 4), (3, 5),
    (1, 4), (3, 6),
    (1, 2), (3, 4), (5, 6),
];

/// Sorts eight NaN-free values by [`SORT8`], unrolled, for `N` sets of
/// them at once (`v[k]` the `k`-th value of each, in lanes that vectorise).
// By index: split borrows of the two rows compile to a slower loop
// (values spilled to the stack; checked in the disassembly).
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn sort8<const N: usize>(v: &mut [[f32; N]; 8]) {
    seq_macro::seq!(K in 0..19 {
        let (i, j) = SORT8[K];
        for l in 0..N {
            let (a, b) = (v[i][l], v[j][l]);
            (v[i][l], v[j][l]) = if b < a { (b, a) } else { (a, b) };
        }
    });
}

/// The lower median of the finite values of each of the `N` sets of eight
/// in `v` (as [`sort8`] takes them); `inf` for a set without any.
#[inline(always)]
fn medians_of_valid<const N: usize>(v: &mut [[f32; N]; 8]) -> [f32; N] {
    sort8(v);
    // Lane by lane, as vectors: the count of finite values, then the
    // median's index (at most 3) by selects rather than a lookup.
    let mut count = [0u32; N];
    for v in v.iter() {
        for (c, &d) in count.iter_mut().zip(v) {
            *c += u32::from(valid(d));
        }
    }
    let mut median = v[0];
    for (k, v) in v.iter().enumerate().take(4).skip(1) {
        for ((m, &d), &c) in median.iter_mut().zip(v).zip(&count) {
            *m = if c.saturating_sub(1) / 2 == k as u32 {
                d
            } else {
                *m
            };
        }
    }
    median
}

/// Mirrors a plane left-right: matching mirrored (right, left) as (left, right)
/// gives the right view's disparity map, mirrored.
pub fn flip<T: Copy>(img: &Plane<T>) -> Plane<T> {
    Plane::from_fn(img.width(), img.height(), |x, y| {
        img.get(img.width() - 1 - x, y)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const INF: f32 = f32::INFINITY;

    #[test]
    fn parabola_finds_the_vertex() {
        assert_eq!(parabola(1.0, 0.0, 1.0), 0.0);
        assert!((parabola(4.0, 1.0, 0.0) - 0.5).abs() < 1e-6);
        assert!((parabola(2.0, 1.0, 2.5) + 0.1).abs() < 1e-6);
        assert_eq!(parabola(1.0, 1.0, 1.0), 0.0);
    }

    #[test]
    fn lr_check_drops_inconsistent_pixels() {
        let mut left = Plane::from_vec(4, 1, vec![0.0, 1.0, 1.0, 3.0]).unwrap();
        let right = Plane::from_vec(4, 1, vec![1.0, 1.0, 0.0, 0.0]).unwrap();
        lr_check(&mut left, &right, 0.5);
        // x=0: d0 → xr 0: dr 1 ≠ 0 → drop; x=1: xr 0 → dr 1 ok; x=2: xr 1 → 1 ok; x=3: xr 0 → 1 ≠ 3 drop.
        assert_eq!(left.as_slice(), &[INF, 1.0, 1.0, INF]);
    }

    /// By the 0/1 principle a comparator network sorts iff it sorts every
    /// input of zeros and ones.
    #[test]
    fn the_eight_value_network_sorts() {
        for bits in 0u32..256 {
            let mut v: [[f32; 1]; 8] = std::array::from_fn(|k| [(bits >> k & 1) as f32]);
            sort8(&mut v);
            assert!(v.windows(2).all(|p| p[0] <= p[1]), "{bits:08b}");
        }
        // Two sets at once, each its own median.
        let sets = [[INF, 3.0, INF, 1.0, 2.0, INF, 9.0, INF], [INF; 8]];
        let mut v = std::array::from_fn(|k| [sets[0][k], sets[1][k]]);
        assert_eq!(medians_of_valid(&mut v), [2.0, INF]);
    }

    #[test]
    fn directional_fill_takes_the_median_of_the_eight_nearest() {
        // The hole at (2, 2) sees 1, 2, 3 on the row above, 4 and 5 beside
        // it and 6, 7, 9 below; the median of eight is the lower one, 4.
        #[rustfmt::skip]
        let mut m = Plane::from_vec(5, 5, vec![
            INF, INF, INF, INF, INF,
            INF, 1.0, 2.0, 3.0, INF,
            INF, 4.0, INF, 5.0, INF,
            INF, 6.0, 7.0, 9.0, INF,
            INF, INF, INF, INF, INF,
        ]).unwrap();
        fill_from_directions(&mut m);
        assert_eq!(m.get(2, 2), 4.0);
        // The corner (0, 0) sees only 1, along its diagonal.
        assert_eq!(m.get(0, 0), 1.0);
        // (0, 2) sees east 4, north-east 1 (at (1, 1)), south-east 6: median 4.
        assert_eq!(m.get(0, 2), 4.0);
        assert!(m.as_slice().iter().all(|v| v.is_finite()));
        // Nothing valid at all: stays invalid, no panic.
        let mut empty = Plane::from_vec(3, 2, vec![INF; 6]).unwrap();
        fill_from_directions(&mut empty);
        assert!(empty.as_slice().iter().all(|v| !v.is_finite()));
    }

    proptest::proptest! {
        /// The two passes equal walking from each hole in the 8 directions
        /// (on rows of several 64-pixel masks too).
        #[test]
        fn directional_fill_equals_walking(
            w in 1usize..150, h in 1usize..16, seed in proptest::prelude::any::<u64>(),
            holes in 0u64..100,
        ) {
            let mut s = seed | 1;
            let mut next = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s };
            let map = DisparityMap::from_fn(w, h, |_, _| {
                let v = next();
                if v % 100 < holes { INF } else { (v >> 40) as f32 % 32.0 * 0.5 }
            });
            let mut want = map.clone();
            for y in 0..h {
                for x in 0..w {
                    if map.get(x, y).is_finite() {
                        continue;
                    }
                    let mut near = [INF; 8];
                    for (k, (dx, dy)) in [(-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1)]
                        .into_iter()
                        .enumerate()
                    {
                        let (mut cx, mut cy) = (x as isize + dx, y as isize + dy);
                        while (0..w as isize).contains(&cx) && (0..h as isize).contains(&cy) {
                            let v = map.get(cx as usize, cy as usize);
                            if v.is_finite() {
                                near[k] = v;
                                break;
                            }
                            (cx, cy) = (cx + dx, cy + dy);
                        }
                    }
                    let mut valid: Vec<f32> = near.into_iter().filter(|v| v.is_finite()).collect();
                    valid.sort_by(f32::total_cmp);
                    if !valid.is_empty() {
                        want.set(x, y, valid[(valid.len() - 1) / 2]);
                    }
                }
            }
            fill_holes(&mut want);
            let mut got = map.clone();
            fill_from_directions(&mut got);
            proptest::prop_assert_eq!(got.as_slice(), want.as_slice());
        }
    }

    #[test]
    fn fill_takes_the_background_side_and_empty_rows_copy_neighbours() {
        let mut m =
            Plane::from_vec(5, 2, vec![INF, 4.0, INF, INF, 2.0, INF, INF, INF, INF, INF]).unwrap();
        fill_holes(&mut m);
        assert_eq!(m.row(0), &[4.0, 4.0, 2.0, 2.0, 2.0]);
        assert_eq!(m.row(1), m.row(0).to_vec().as_slice());
    }
}
