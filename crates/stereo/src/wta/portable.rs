//! The general band loop of the WTA matcher, generic over the lane
//! operations (`crate::lanes`: portable, SWAR or AVX2): every setting, with
//! the min filter, the right view's map or the check in the pass. The
//! specialised loops of `avx2` and `swar` handle the default and the
//! board's settings and must give its results exactly.

use super::driver::{lanes, Band, Job};
use super::winner::{check_row, Disparity, Winner};
use crate::lanes::LaneOps;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn band_avx2<T: Disparity>(
    job: &Job,
    band: &mut Band,
    out: &mut [T],
    right: Option<&mut [f32]>,
) {
    // SAFETY: this function only runs where AVX2 is present.
    unsafe { band_with::<crate::lanes::Avx2, T>(job, band, out, right) }
}

pub(super) fn band_scalar<K: LaneOps, T: Disparity>(
    job: &Job,
    band: &mut Band,
    out: &mut [T],
    right: Option<&mut [f32]>,
) {
    // SAFETY: the portable and SWAR lane operations need no special instructions.
    unsafe { band_with::<K, T>(job, band, out, right) }
}

/// Processes the rows of one band with the lane operations `K`; `out`
/// (and `right`, the right view's map, when asked for) holds exactly those
/// rows.
///
/// Without a min filter, a row's window sums slide along it in one buffer
/// and are read at once. With one, the window sums of a row go into a ring
/// of `min_filter` cost rows; the min filter takes, per lane, the minimum
/// over the ring's rows and then over the neighbouring columns (both
/// clamped to the image).
///
/// # Safety
/// The CPU must have the instructions `K` uses.
#[inline(always)]
pub(super) unsafe fn band_with<K: LaneOps, T: Disparity>(
    job: &Job,
    band: &mut Band,
    out: &mut [T],
    mut right: Option<&mut [f32]>,
) {
    let (w, h) = job.left.dims();
    let p = job.params;
    let (nd, r) = (lanes(p.ndisp), p.block as isize / 2);
    let (m, mr) = (p.min_filter.max(1), p.min_filter.max(1) / 2);
    let clamp_y = |y: isize| y.clamp(0, h as isize - 1) as usize;
    let clamp_x = |x: isize| x.clamp(0, w as isize - 1) as usize;
    let colsum = &mut band.colsum[..w * nd];
    let differ = &mut band.differ[..];
    let ring = &mut band.ring[..if m > 1 { m * w * nd } else { 0 }];
    let vmin = &mut band.vmin[..if m > 1 { w * nd } else { 0 }];
    let cost = &mut band.cost[..nd];
    let (right_best, right_lane) = (&mut band.right_best, &mut band.right_lane);
    let winners = &mut band.winners;
    let rows = out.len() / w;
    // Cost rows `first..last` feed the band's output rows.
    let first = job.y0.saturating_sub(mr);
    let last = (job.y0 + rows + mr).min(h);
    // Prime the column sums with the window rows of the first cost row.
    colsum.fill(0);
    for dy in -r..=r {
        // SAFETY: forwarded from this function's contract.
        unsafe { accumulate_row::<K>(job, colsum, differ, clamp_y(first as isize + dy), None) };
    }
    let mut next = first;
    for (i, out_row) in out.chunks_exact_mut(w).enumerate() {
        let y = job.y0 + i;
        // Window sums of every cost row up to y + mr, each into its ring slot.
        while next < (y + mr + 1).min(last) {
            let yc = next as isize;
            if next > first {
                let (entering, leaving) = (clamp_y(yc + r), clamp_y(yc - r - 1));
                // SAFETY: as above.
                unsafe { accumulate_row::<K>(job, colsum, differ, entering, Some(leaving)) };
            }
            if m > 1 {
                let col = |x: isize| &colsum[clamp_x(x) * nd..][..nd];
                let slot = &mut ring[(next % m) * w * nd..][..w * nd];
                // Horizontal window sum at x = 0, then slide: each column's
                // sums are the previous column's plus the entering minus
                // the leaving column.
                slot[..nd].fill(0);
                for dx in -r..=r {
                    // SAFETY: as above.
                    unsafe { K::add_sub(&mut slot[..nd], col(dx), None) };
                }
                for x in 1..w {
                    let (done, rest) = slot.split_at_mut(x * nd);
                    let xi = x as isize;
                    let (prev, leaving) = (&done[(x - 1) * nd..], col(xi - r - 1));
                    // SAFETY: as above.
                    unsafe { K::add_sub_from(&mut rest[..nd], prev, col(xi + r), leaving) };
                }
            }
            next += 1;
        }
        // The column minima over the rows y − mr ..= y + mr (clamped).
        let costs: &[u16] = if m > 1 {
            let (lo, hi) = (y.saturating_sub(mr), (y + mr).min(h - 1));
            vmin.copy_from_slice(&ring[(lo % m) * w * nd..][..w * nd]);
            for yy in lo + 1..=hi {
                // SAFETY: as above.
                unsafe { K::min_assign(vmin, &ring[(yy % m) * w * nd..][..w * nd]) };
            }
            vmin
        } else {
            // Unused: the window sum slides along the row below.
            &[]
        };
        let col = |x: isize| &colsum[clamp_x(x) * nd..][..nd];
        if right.is_some() || job.check {
            right_best.fill(u16::MAX);
        }
        for (x, d) in out_row.iter_mut().enumerate() {
            let xi = x as isize;
            // Disparities d_min.. up to x (none below d_min).
            let valid = (x + 1).saturating_sub(p.min_disp).min(p.ndisp);
            // The smallest cost, when the slide below found it.
            let mut found = None;
            if m == 1 {
                // No min filter: the window sum slides along the row in
                // `cost` (no ring), the column x + r entering and x − r − 1
                // leaving.
                let (entering, leaving) = (col(xi + r), col(xi - r - 1));
                if x == 0 {
                    cost.fill(0);
                    for dx in -r..=r {
                        // SAFETY: as above.
                        unsafe { K::add_sub(cost, col(dx), None) };
                    }
                } else if valid > 0 {
                    // SAFETY: as above.
                    found = Some(unsafe { K::add_sub_argmin(cost, entering, leaving, valid) });
                } else {
                    // SAFETY: as above.
                    unsafe { K::add_sub(cost, entering, Some(leaving)) };
                }
            }
            if valid == 0 {
                *d = T::NONE;
                continue;
            }
            let at_col = |x: isize| &costs[clamp_x(x) * nd..][..nd];
            let cost: &[u16] = if m == 1 {
                cost
            } else {
                cost.copy_from_slice(at_col(xi - mr as isize));
                for dx in 1 - mr as isize..=mr as isize {
                    // SAFETY: as above.
                    unsafe { K::min_assign(cost, at_col(xi + dx)) };
                }
                cost
            };
            // SAFETY: as above.
            let best = found.unwrap_or_else(|| unsafe { K::argmin(cost, valid) });
            *d = T::winner(cost, valid, best, p);
            // Lane k is the right pixel x − d_min − k, at W − 1 − that.
            let at = w - 1 - (x - p.min_disp);
            if job.check {
                let (lane, cost_k) = (best.0, best.1);
                winners[x] = Winner {
                    lane: lane as u16,
                    cost: cost_k,
                    first: right_best[at + lane] > cost_k,
                };
                // SAFETY: as above.
                unsafe { K::min_first(&mut right_best[at..at + nd], cost, valid) };
            } else if right.is_some() {
                let (best, lane) = (&mut right_best[at..at + nd], &mut right_lane[at..at + nd]);
                // SAFETY: as above.
                unsafe { K::min_update(best, lane, cost, valid) };
            }
        }
        if job.check {
            check_row(out_row, winners, right_best, p.min_disp);
        }
        if let Some(right) = right.as_deref_mut() {
            let row = &mut right[i * w..(i + 1) * w];
            for (xr, d) in row.iter_mut().enumerate() {
                let at = w - 1 - xr;
                *d = if right_best[at] == u16::MAX {
                    f32::INFINITY
                } else {
                    (p.min_disp + right_lane[at] as usize) as f32
                };
            }
        }
    }
}

/// Adds the absolute differences of row `y` to every column sum, and
/// subtracts those of row `leaving` when given:
/// `colsum[x][k] += |L(x, y) − R(x − d_min − k, y)|`.
///
/// With [`LaneOps::SKIP_ALIKE_ROWS`], a column whose left sample and
/// right samples are the same in both rows is left as it is (what enters
/// equals what leaves); `differ` (one more than a reversed row long)
/// counts the differing right samples, so the test costs two loads.
///
/// # Safety
/// The CPU must have the instructions `K` uses.
#[inline(always)]
pub(super) unsafe fn accumulate_row<K: LaneOps>(
    job: &Job,
    colsum: &mut [u16],
    differ: &mut [u32],
    y: usize,
    leaving: Option<usize>,
) {
    let nd = lanes(job.params.ndisp);
    let left = job.left.row(y);
    let gone_left = leaving.map(|s| job.left.row(s));
    let skip = K::SKIP_ALIKE_ROWS && leaving.is_some();
    if let (true, Some(s)) = (skip, leaving) {
        let mut n = 0;
        differ[0] = 0;
        for ((c, a), b) in differ[1..]
            .iter_mut()
            .zip(job.reversed_row(y))
            .zip(job.reversed_row(s))
        {
            n += (a != b) as u32;
            *c = n;
        }
    }
    for (x, col) in colsum.chunks_exact_mut(nd).enumerate() {
        let gone = leaving
            .zip(gone_left)
            .map(|(s, l)| (l[x], job.right_of(s, x)));
        let start = job.right_start(x);
        if skip && gone.is_some_and(|(l, _)| l == left[x]) && differ[start + nd] == differ[start] {
            continue;
        }
        // SAFETY: forwarded from this function's contract.
        unsafe { K::accumulate(col, left[x], job.right_of(y, x), gone) };
    }
}
