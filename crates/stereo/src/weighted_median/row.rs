//! One row of the weighted median: which pixels take it, the chunks of
//! lanes that cover them, the vectorised sums that settle most pixels on
//! their candidate bin or a neighbour of it, and the hand-off of the rest to
//! [`search`].

use super::search::{search, Sample};
use super::{weight, MapJob};

/// [`filter_row`] compiled for AVX2 (a function of its own: LLVM does not
/// always inline a closure this large into
/// [`with_avx2`](super::with_avx2)'s).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn filter_row_avx2(
    job: &MapJob,
    y: usize,
    row: &mut [f32],
    scratch: &mut RowScratch,
) {
    filter_row(job, y, row, scratch)
}

/// Pixels whose sums [`settle`] keeps in registers together.
pub(super) const LANES: usize = 16;

/// A bin above every valid one and `invalid`: the pixel is left to
/// [`search`].
const HARD: u16 = u16::MAX;

/// [`WeightedMedianGuide::filter`](super::WeightedMedianGuide::filter)
/// for row `y` of the output, `row` (a copy of the map's).
#[inline(always)]
pub(super) fn filter_row(job: &MapJob, y: usize, row: &mut [f32], scratch: &mut RowScratch) {
    let (w, r) = (row.len(), job.guide.pad);
    let wp = w + 2 * r;
    let (lo, invalid) = (job.lo, job.invalid);
    let centre = (y + r) * wp + r;
    let own = &job.bin_pad[centre..centre + w];
    // The bin tested: a valid pixel's own; for an invalid one, that of the
    // nearest valid pixel to its left (else the row's first valid one),
    // the likeliest value of a hole amid one surface.
    let candidates = &mut scratch.candidates;
    candidates.clear();
    let first_valid = own.iter().copied().find(|&b| b != invalid);
    let mut left = first_valid.unwrap_or(invalid);
    candidates.extend(own.iter().map(|&b| {
        left = if b != invalid { b } else { left };
        left
    }));
    // The pixels that stay as they are: with `borders`, all but the valid
    // ones with an invalid pixel among their 8 neighbours (the padded
    // bins replicate the border as the window does).
    let stay = &mut scratch.stay;
    stay.clear();
    if job.borders {
        let near = &mut scratch.near_hole;
        let rows =
            [centre - wp - 1, centre - 1, centre + wp - 1].map(|s| &job.bin_pad[s..s + w + 2]);
        near.clear();
        near.extend(
            (rows[0].iter().zip(rows[1]).zip(rows[2]))
                .map(|((&a, &b), &c)| (a == invalid) | (b == invalid) | (c == invalid)),
        );
        stay.extend(
            own.iter()
                .zip(near.windows(3))
                .map(|(&b, n)| (b == invalid) | !(n[0] | n[1] | n[2])),
        );
    } else {
        stay.resize(w, false);
    }
    // Chunks of `LANES` over the pixels that do not stay ([`covering`]); a
    // narrower row pixel by pixel. The others need no sums: they stay
    // whatever their sums hold (those of an earlier row, or zero).
    let (candidates, stay) = (&scratch.candidates[..], &scratch.stay[..]);
    let s = &mut scratch.sums;
    for v in [
        &mut s.total,
        &mut s.below,
        &mut s.at,
        &mut s.lower,
        &mut s.upper,
    ] {
        v.resize(w, 0);
    }
    let n = if w >= LANES { LANES } else { 1 };
    for x in covering(stay, n, |&stays| !stays) {
        let at = x..x + n;
        let sums = [
            &mut s.total,
            &mut s.below,
            &mut s.at,
            &mut s.lower,
            &mut s.upper,
        ]
        .map(|v| &mut v[at.clone()]);
        if n == LANES {
            settle::<LANES>(job, centre + x, &candidates[at], sums);
        } else {
            settle::<1>(job, centre + x, &candidates[at], sums);
        }
    }
    // Which of `c`, `c − 1`, `c + 1` is the median, for the whole row at
    // once (branch-free selects, so that it vectorises): bin `c` is when
    // twice the sum below it is under the total and twice the sum up to
    // it is at least the total; `c − 1` and `c + 1` likewise. A pixel
    // that stays, or without weight, keeps its bin; those that none
    // settles are [`HARD`].
    let medians = &mut scratch.medians;
    medians.resize(w, 0);
    let lanes = (s.total.iter().zip(&s.below).zip(&s.at))
        .zip(s.lower.iter().zip(&s.upper))
        .zip(candidates.iter().zip(own).zip(stay));
    for (m, ((((&t, &b), &a), (&lw, &up)), ((&c, &own), &stay))) in medians.iter_mut().zip(lanes) {
        let (t, b, a) = (u32::from(t), u32::from(b), u32::from(a));
        let (lw, up) = (u32::from(lw), u32::from(up));
        // `c` is `invalid` only in a row without valid pixels; its sums
        // are then those of no bin.
        let known = c != invalid;
        let at_c = known & (2 * b < t) & (2 * (b + a) >= t);
        let at_lower = known & (2 * (b - lw) < t) & (2 * b >= t);
        let at_upper = known & (2 * (b + a) < t) & (2 * (b + a + up) >= t);
        let pick = if at_c {
            c
        } else if at_lower {
            c.wrapping_sub(1)
        } else {
            c.wrapping_add(1)
        };
        let pick = if at_c | at_lower | at_upper {
            pick
        } else {
            HARD
        };
        *m = if (t == 0) | stay { own } else { pick };
    }
    for ((d, &m), &b) in row.iter_mut().zip(medians.iter()).zip(own) {
        // `HARD` and `invalid` are above every valid bin.
        let take = u32::from((m != b) & (m < invalid)).wrapping_neg();
        // A select on the bits, storing every lane: as an `if`, LLVM
        // emits a masked store, slow on some CPUs (AMD's).
        let median = lo + f32::from(m);
        *d = f32::from_bits(median.to_bits() & take | d.to_bits() & !take);
    }
    // The rest, in chunks as above (a pixel of overlapping chunks may be
    // searched twice, to the same result).
    for x in covering(medians, n, |&m| m == HARD) {
        let at = x..x + n;
        let mut found = [0u16; LANES];
        if n == LANES {
            found = search::<LANES>(job, centre + x, &mut scratch.samples);
        } else {
            found[..1].copy_from_slice(&search::<1>(job, centre + x, &mut scratch.samples));
        }
        for (((d, &m), &b), &f) in row[at.clone()]
            .iter_mut()
            .zip(&medians[at.clone()])
            .zip(&own[at])
            .zip(&found)
        {
            // `HARD` pixels have weight (the others do not search).
            if (m == HARD) & (f != b) {
                *d = lo + f32::from(f);
            }
        }
    }
}

/// The starts of chunks of `n` pixels of `row` (at least `n` long) that
/// cover every pixel where `flagged` holds, as few as can: each starts at
/// the first flagged pixel not yet covered (moved back to end with the
/// row at the latest). Flagged pixels cluster (at holes' borders, at
/// disparity edges), so that this takes fewer chunks than a fixed grid.
fn covering<'a, T>(
    row: &'a [T],
    n: usize,
    flagged: impl Fn(&T) -> bool + 'a,
) -> impl Iterator<Item = usize> + 'a {
    let mut next = 0;
    std::iter::from_fn(move || {
        let x = next + row.get(next..)?.iter().position(&flagged)?;
        let start = x.min(row.len() - n);
        next = start + n;
        Some(start)
    })
}

/// Per pixel, the weights of the valid samples in all, below `c`, in `c`,
/// in `c − 1` and in `c + 1` for the candidate bin `c` (apart, so that
/// the decisions over a row vectorise).
#[derive(Default)]
struct Sums {
    total: Vec<u16>,
    below: Vec<u16>,
    at: Vec<u16>,
    lower: Vec<u16>,
    upper: Vec<u16>,
}

/// The [`Sums`] of the `N` pixels from padded index `p` on, with candidate
/// bins `candidates`, into `sums` (slices of `N`), in `u16` lanes kept in
/// registers for the whole window: branch-free selects on bins relative
/// to `c`, as `i16`.
#[inline(always)]
fn settle<const N: usize>(job: &MapJob, p: usize, candidates: &[u16], sums: [&mut [u16]; 5]) {
    let guide = job.guide;
    let (invalid, reach, shift) = (job.invalid, guide.p.color_reach, guide.shift);
    let c: &[u16; N] = candidates.try_into().expect("N candidates");
    let colours = |q: usize| -> [&[u8; N]; 3] {
        guide.planes.each_ref().map(|plane| {
            let lanes: &[u8; N] = plane[q..q + N].try_into().expect("N colours");
            lanes
        })
    };
    let centre = colours(p);
    let (mut total, mut below, mut at) = ([0u16; N], [0u16; N], [0u16; N]);
    let (mut lower, mut upper) = ([0u16; N], [0u16; N]);
    for &offset in &guide.offsets {
        let q = p.wrapping_add_signed(offset);
        let bins: &[u16; N] = job.bin_pad[q..q + N].try_into().expect("N bins");
        let [r, g, b] = colours(q);
        for l in 0..N {
            let sample = [r[l], g[l], b[l]];
            let w = weight(
                [centre[0][l], centre[1][l], centre[2][l]],
                sample,
                reach,
                shift,
            );
            let w = if bins[l] == invalid { 0 } else { w };
            // Bins and `invalid` are below 2¹⁵ (checked by the caller).
            let rel = (bins[l] as i16).wrapping_sub(c[l] as i16);
            total[l] += w;
            below[l] += if rel < 0 { w } else { 0 };
            at[l] += if rel == 0 { w } else { 0 };
            lower[l] += if rel == -1 { w } else { 0 };
            upper[l] += if rel == 1 { w } else { 0 };
        }
    }
    for (out, lanes) in sums.into_iter().zip([total, below, at, lower, upper]) {
        out.copy_from_slice(&lanes);
    }
}

/// Per-row buffers of
/// [`WeightedMedianGuide::filter`](super::WeightedMedianGuide::filter).
#[derive(Default)]
pub(super) struct RowScratch {
    /// The bins tested for the row's pixels.
    candidates: Vec<u16>,
    /// The [`settle`] sums of the row's pixels.
    sums: Sums,
    /// The bin each pixel of the row takes, as its sums settle it.
    medians: Vec<u16>,
    /// Whether each pixel of the row stays as it is.
    stay: Vec<bool>,
    /// Whether each column from −1 to `w` has a hole in the rows `y − 1`,
    /// `y`, `y + 1`.
    near_hole: Vec<bool>,
    /// For [`search`], the bins and weights of a chunk's samples.
    samples: Vec<Sample>,
}
