//! The weighted median by its definition, for the pixels the row pass
//! leaves unsettled: a bisection over the bins in `u16` lanes, a chunk of
//! pixels at a time.

use super::row::LANES;
use super::{weight, MapJob};

/// The weighted median bins of the windows of the `N` pixels from padded
/// index `p` on, by the definition: the smallest bin `b` where twice the
/// weight of the valid samples at or below `b` reaches the window's total
/// (no bin below `b` can: it is the first bin, ascending, where the running
/// sum of a histogram reaches half the total). Found bit by bit from the
/// top in `u16` lanes, as the number of bins that fall short: each step
/// sums the window's weights at or below a bin per lane, over the weights
/// and bins listed once in `samples` (scratch). A pixel without weight
/// gets some bin.
#[inline(always)]
pub(super) fn search<const N: usize>(
    job: &MapJob,
    p: usize,
    samples: &mut Vec<Sample>,
) -> [u16; N] {
    let guide = job.guide;
    let (invalid, reach, shift) = (job.invalid, guide.p.color_reach, guide.shift);
    let colours = |q: usize| -> [&[u8; N]; 3] {
        guide.planes.each_ref().map(|plane| {
            let lanes: &[u8; N] = plane[q..q + N].try_into().expect("N colours");
            lanes
        })
    };
    let centre = colours(p);
    let mut total = [0u16; N];
    samples.clear();
    for &offset in &guide.offsets {
        let q = p.wrapping_add_signed(offset);
        let bins: &[u16; N] = job.bin_pad[q..q + N].try_into().expect("N bins");
        let [r, g, b] = colours(q);
        let mut sample: Sample = [[0; LANES]; 2];
        for l in 0..N {
            let w = weight(
                [centre[0][l], centre[1][l], centre[2][l]],
                [r[l], g[l], b[l]],
                reach,
                shift,
            );
            let w = if bins[l] == invalid { 0 } else { w };
            sample[0][l] = bins[l];
            sample[1][l] = w;
            total[l] += w;
        }
        samples.push(sample);
    }
    // `2 · sum ≥ total` without overflow; the valid bins are `0..invalid`,
    // below 2¹⁵ (checked by the caller), so their bits are the low `bits`.
    let half = total.map(|t| t - t / 2);
    let bits = u16::BITS - (invalid.max(1) - 1).leading_zeros();
    let mut short = [0u16; N];
    for k in (0..bits).rev() {
        let step = 1u16 << k;
        // Is the sum at or below `short + step − 1` short of half?
        let top = short.map(|s| (s + step - 1) as i16);
        let mut sum = [0u16; N];
        // By index, with a bounds check LLVM keeps: without it, its loop
        // vectoriser takes this loop across samples (gathering each lane's
        // bins and weights) instead of leaving the lanes to one vector
        // each (checked in the disassembly), which is slower
        // (docs/benchmarks.md, “WTA's CPU time by stage”).
        #[allow(clippy::needless_range_loop)]
        for j in 0..guide.offsets.len() {
            let [bins, weights] = &samples[j];
            for l in 0..N {
                // A lane mask, as one vector comparison.
                let below = u16::from(bins[l] as i16 <= top[l]).wrapping_neg();
                sum[l] += weights[l] & below;
            }
        }
        for l in 0..N {
            short[l] += if sum[l] < half[l] { step } else { 0 };
        }
    }
    short
}

/// The bins and weights of one sample of a chunk's windows, a lane each
/// (the first `N` of [`search`]).
pub(super) type Sample = [[u16; LANES]; 2];
