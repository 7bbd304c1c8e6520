//! Winner-take-all on SAD, the paper's local method (its eq. 12):
//!
//! ```text
//! SAD(x, y, d) = Σ_{(i, j) ∈ n×n window} |I_L(x + i, y + j) − I_R(x + i − d, y + j)|
//! d*(x, y)     = argmin_{d ∈ [d_min, d_max]} SAD(x, y, d)
//! ```
//!
//! Aggregation is O(1) per pixel and disparity: per row band, a column sum
//! `colsum[x][d]` over the window's rows is updated incrementally (add the
//! entering row, subtract the leaving one) and a horizontal running sum over
//! the columns gives the window sum. The disparity axis is innermost and
//! contiguous, so every step is a straight loop over `u16` lanes that the
//! compiler vectorises; the same source is compiled twice, for AVX2 and
//! for the baseline, and the AVX2 copy is chosen at run time. Integer
//! arithmetic makes both copies bit-identical. Row bands run in parallel
//! (rayon). Window pixels outside the image replicate the border.
//!
//! A match outside the right view (`x − d < 0`) is not considered; pixels
//! with `x < d_min` get no disparity (`inf`).

use rayon::prelude::*;
use stereolink_image::{DisparityMap, GrayImage};

use crate::MatchSpec;

/// Parameters of [`WtaMatcher`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WtaParams {
    /// Smallest disparity searched.
    pub min_disp: usize,
    /// Number of disparities searched (`min_disp..min_disp + ndisp`).
    pub ndisp: usize,
    /// Odd window size n (n×n), at most 15 so sums fit in 16 bits.
    pub block: usize,
    /// Reject a winner unless every disparity more than 1 away costs at least
    /// `(100 + uniqueness) %` of it; 0 disables the test.
    pub uniqueness: u32,
    /// Refine the winner with a parabola through its neighbours' costs.
    pub subpixel: bool,
}

impl WtaParams {
    /// The WTA part of a [`MatchSpec`].
    pub fn from_spec(spec: &MatchSpec) -> Self {
        WtaParams {
            min_disp: spec.min_disp,
            ndisp: spec.ndisp(),
            block: spec.block,
            uniqueness: spec.refine.uniqueness,
            subpixel: spec.refine.subpixel,
        }
    }
}

/// Scratch of one row band.
#[derive(Default)]
struct Band {
    colsum: Vec<u16>,
    hsum: Vec<u16>,
}

/// A WTA-SAD matcher that keeps its buffers from one frame to the next, so
/// matching frames of an unchanged size allocates nothing after the first.
#[derive(Default)]
pub struct WtaMatcher {
    /// Each right row, border-padded and reversed (see [`reversed_rows`]).
    reversed: Vec<u8>,
    bands: Vec<Band>,
}

/// Rows per parallel band: bands re-prime `block` rows, so not too small.
const BAND_ROWS: usize = 32;

impl WtaMatcher {
    /// An empty matcher; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// Matches `left` against `right` (same size, checked by the caller) and
    /// writes the disparity of every left pixel into `out` (same size).
    ///
    /// # Panics
    /// If the sizes differ or `params` violates its documented ranges.
    pub fn compute_into(
        &mut self,
        left: &GrayImage,
        right: &GrayImage,
        params: &WtaParams,
        out: &mut DisparityMap,
    ) {
        assert_eq!(left.dims(), right.dims());
        assert_eq!(left.dims(), out.dims());
        assert!(params.block % 2 == 1 && params.block <= 15 && params.ndisp > 0);
        let (w, h) = left.dims();
        if w == 0 || h == 0 {
            return;
        }
        let stride = w + params.ndisp + params.min_disp;
        reversed_rows(right, params, &mut self.reversed);
        let n_bands = h.div_ceil(BAND_ROWS);
        self.bands
            .resize_with(n_bands.max(self.bands.len()), Band::default);
        let reversed = &self.reversed;
        let use_avx2 = avx2_available();
        out.as_mut_slice()
            .par_chunks_mut(w * BAND_ROWS)
            .zip(self.bands.par_iter_mut())
            .enumerate()
            .for_each(|(i, (rows, band))| {
                let job = Job {
                    left,
                    reversed,
                    stride,
                    params,
                    y0: i * BAND_ROWS,
                };
                band.colsum.resize(w * params.ndisp, 0);
                band.hsum.resize(params.ndisp, 0);
                if use_avx2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: only reached when the CPU reports AVX2 (checked in
                    // `avx2_available`); the function is the same safe code
                    // compiled with AVX2 enabled.
                    unsafe {
                        band_avx2(&job, band, rows)
                    }
                } else {
                    band_generic(&job, band, rows)
                }
            });
    }
}

/// True when the AVX2 copy of the kernel can run here.
pub fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Fills `buf` with each right row padded on the left by replicating its
/// first pixel, then reversed, so that for a left column `x` the right pixels
/// `x − d_min − k` for `k = 0..ndisp` are `buf[row][W + d_min − 1 − x + k]`:
/// contiguous in `k`.
fn reversed_rows(right: &GrayImage, p: &WtaParams, buf: &mut Vec<u8>) {
    let (w, h) = right.dims();
    let pad = p.ndisp + p.min_disp;
    let stride = w + pad;
    buf.resize(stride * h, 0);
    for (y, dst) in buf.chunks_exact_mut(stride).enumerate() {
        let row = right.row(y);
        for (u, v) in dst.iter_mut().enumerate() {
            let t = stride - 1 - u; // index into the padded row
            *v = row[t.saturating_sub(pad).min(w - 1)];
        }
    }
}

struct Job<'a> {
    left: &'a GrayImage,
    reversed: &'a [u8],
    stride: usize,
    params: &'a WtaParams,
    y0: usize,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn band_avx2(job: &Job, band: &mut Band, out: &mut [f32]) {
    band_generic(job, band, out)
}

/// Processes the rows of one band; `out` holds exactly those rows.
#[inline(always)]
fn band_generic(job: &Job, band: &mut Band, out: &mut [f32]) {
    let (w, h) = job.left.dims();
    let p = job.params;
    let (nd, r) = (p.ndisp, p.block / 2);
    let clamp_y = |y: isize| y.clamp(0, h as isize - 1) as usize;
    let rev_row = |y: usize| &job.reversed[y * job.stride..(y + 1) * job.stride];
    let rows = out.len() / w;
    let colsum = &mut band.colsum[..w * nd];
    let hsum = &mut band.hsum[..nd];
    // Prime the column sums with the window rows of the band's first row.
    colsum.fill(0);
    for dy in -(r as isize)..=r as isize {
        let y = clamp_y(job.y0 as isize + dy);
        accumulate_rows(colsum, job.left.row(y), rev_row(y), p, None);
    }
    for i in 0..rows {
        let y = job.y0 + i;
        if i > 0 {
            let (ya, ys) = (
                clamp_y(y as isize + r as isize),
                clamp_y(y as isize - r as isize - 1),
            );
            accumulate_rows(
                colsum,
                job.left.row(ya),
                rev_row(ya),
                p,
                Some((job.left.row(ys), rev_row(ys))),
            );
        }
        // Horizontal window sum at x = 0, then slide.
        hsum.fill(0);
        for dx in -(r as isize)..=r as isize {
            let x = dx.clamp(0, w as isize - 1) as usize;
            add_lanes(hsum, &colsum[x * nd..(x + 1) * nd]);
        }
        let out_row = &mut out[i * w..(i + 1) * w];
        for x in 0..w {
            if x > 0 {
                let xa = (x + r).min(w - 1);
                let xs = (x as isize - r as isize - 1).max(0) as usize;
                add_sub_lanes(
                    hsum,
                    &colsum[xa * nd..(xa + 1) * nd],
                    &colsum[xs * nd..(xs + 1) * nd],
                );
            }
            out_row[x] = if x < p.min_disp {
                f32::INFINITY
            } else {
                winner(&hsum[..nd.min(x - p.min_disp + 1)], p)
            };
        }
    }
}

/// Adds the absolute differences of one row (and subtracts those of a
/// leaving row) to every column sum: `colsum[x][k] += |L(x) − R(x − d_min − k)|`.
#[inline(always)]
fn accumulate_rows(
    colsum: &mut [u16],
    left: &[u8],
    rev: &[u8],
    p: &WtaParams,
    leaving: Option<(&[u8], &[u8])>,
) {
    let (w, nd) = (left.len(), p.ndisp);
    for x in 0..w {
        let base = w + p.min_disp - 1 - x;
        let col = &mut colsum[x * nd..(x + 1) * nd];
        let (l, r) = (left[x], &rev[base..base + nd]);
        match leaving {
            None => {
                for (c, &rv) in col.iter_mut().zip(r) {
                    *c = c.wrapping_add(l.abs_diff(rv) as u16);
                }
            }
            Some((sl, srev)) => {
                let (ls, rs) = (sl[x], &srev[base..base + nd]);
                for ((c, &rv), &sv) in col.iter_mut().zip(r).zip(rs) {
                    *c = c
                        .wrapping_add(l.abs_diff(rv) as u16)
                        .wrapping_sub(ls.abs_diff(sv) as u16);
                }
            }
        }
    }
}

#[inline(always)]
fn add_lanes(acc: &mut [u16], a: &[u16]) {
    for (s, &v) in acc.iter_mut().zip(a) {
        *s = s.wrapping_add(v);
    }
}

#[inline(always)]
fn add_sub_lanes(acc: &mut [u16], a: &[u16], s: &[u16]) {
    for ((h, &av), &sv) in acc.iter_mut().zip(a).zip(s) {
        *h = h.wrapping_add(av).wrapping_sub(sv);
    }
}

/// The winning disparity among `costs` (index `k` is disparity `d_min + k`).
#[inline(always)]
fn winner(costs: &[u16], p: &WtaParams) -> f32 {
    // Cost in the high half, index in the low half: one vectorisable minimum
    // gives the smallest cost and, among equal costs, the smallest disparity.
    let packed = costs
        .iter()
        .zip(0u32..)
        .map(|(&c, k)| (c as u32) << 16 | k)
        .min()
        .expect("at least one disparity");
    let (best, k) = ((packed >> 16) as u16, (packed & 0xFFFF) as usize);
    if p.uniqueness > 0 {
        let limit = best as u32 * (100 + p.uniqueness);
        let ambiguous = costs
            .iter()
            .enumerate()
            .any(|(j, &c)| j.abs_diff(k) > 1 && (c as u32) * 100 < limit);
        if ambiguous {
            return f32::INFINITY;
        }
    }
    let mut d = (p.min_disp + k) as f32;
    if p.subpixel && k > 0 && k + 1 < costs.len() {
        d += crate::refine::parabola(costs[k - 1] as f32, best as f32, costs[k + 1] as f32);
    }
    d
}

/// Straightforward O(n²) per pixel SAD, the reference the fast path is tested against.
#[cfg(test)]
pub(crate) fn reference(left: &GrayImage, right: &GrayImage, p: &WtaParams) -> DisparityMap {
    let (w, h) = left.dims();
    let r = (p.block / 2) as isize;
    let at = |img: &GrayImage, x: isize, y: isize| {
        img.get(
            x.clamp(0, w as isize - 1) as usize,
            y.clamp(0, h as isize - 1) as usize,
        )
    };
    DisparityMap::from_fn(w, h, |x, y| {
        if x < p.min_disp {
            return f32::INFINITY;
        }
        let costs: Vec<u16> = (0..p.ndisp.min(x - p.min_disp + 1))
            .map(|k| {
                let d = (p.min_disp + k) as isize;
                let mut s = 0u32;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (xx, yy) = (x as isize + dx, y as isize + dy);
                        // Border replication applies to the left column first,
                        // then the right pixel is taken at (clamped x) − d.
                        let xl = xx.clamp(0, w as isize - 1);
                        s += at(left, xl, yy).abs_diff(at(right, (xl - d).max(0), yy)) as u32;
                    }
                }
                s as u16
            })
            .collect();
        winner(&costs, p)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn image(w: usize, h: usize, seed: u64) -> GrayImage {
        let mut s = seed | 1;
        GrayImage::from_fn(w, h, |_, _| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 24) as u8
        })
    }

    #[test]
    fn shifted_noise_is_recovered_exactly() {
        let right = image(80, 40, 7);
        let left = GrayImage::from_fn(80, 40, |x, y| right.get(x.saturating_sub(6), y));
        let p = WtaParams {
            min_disp: 0,
            ndisp: 16,
            block: 5,
            uniqueness: 0,
            subpixel: false,
        };
        let mut out = DisparityMap::new(80, 40, 0.0);
        WtaMatcher::new().compute_into(&left, &right, &p, &mut out);
        for y in 0..40 {
            for x in 12..76 {
                assert_eq!(out.get(x, y), 6.0, "({x}, {y})");
            }
        }
    }

    #[test]
    fn reused_matcher_gives_identical_results() {
        let (l, r) = (image(50, 70, 1), image(50, 70, 2));
        let p = WtaParams {
            min_disp: 2,
            ndisp: 9,
            block: 3,
            uniqueness: 0,
            subpixel: true,
        };
        let mut m = WtaMatcher::new();
        let mut a = DisparityMap::new(50, 70, 0.0);
        let mut b = DisparityMap::new(50, 70, 0.0);
        m.compute_into(&l, &r, &p, &mut a);
        m.compute_into(&l, &r, &p, &mut b);
        assert_eq!(a, b);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// The fast path (AVX2 where present) equals the naive definition.
        #[test]
        fn fast_equals_reference(
            w in 1usize..40, h in 1usize..40, seed in any::<u64>(),
            min_disp in 0usize..4, ndisp in 1usize..12, half in 0usize..4,
            subpixel in any::<bool>(), uniqueness in prop_oneof![Just(0u32), Just(15u32)],
        ) {
            let (l, r) = (image(w, h, seed), image(w, h, seed ^ 0xABCD));
            let p = WtaParams { min_disp, ndisp, block: 2 * half + 1, uniqueness, subpixel };
            let mut fast = DisparityMap::new(w, h, 0.0);
            WtaMatcher::new().compute_into(&l, &r, &p, &mut fast);
            let slow = reference(&l, &r, &p);
            let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            prop_assert_eq!(bits(&fast), bits(&slow));
        }
    }
}
