//! Semi-global matching (Hirschmüller, "Stereo Processing by Semiglobal
//! Matching and Mutual Information", PAMI 2008), beyond the paper.
//!
//! * **Cost**: Hamming distance of 9×7 census transforms (62 bits), robust to
//!   the exposure differences of real cameras. `C(p, d)` lies in 0..=62;
//!   matches outside the right view cost [`OUTSIDE_COST`].
//! * **Aggregation** along 4 or 8 straight paths `r`:
//!   `L_r(p, d) = C(p, d) + min(L_r(p−r, d), L_r(p−r, d±1) + P1,
//!   min_k L_r(p−r, k) + P2(p)) − min_k L_r(p−r, k)`, summed into
//!   `S(p, d)` (`u16`). `P2` adapts to the intensity step along the path:
//!   `P2(p) = max(P1 + 1, P2 · γ / (γ + |I(p) − I(p−r)|))`, so depth may jump
//!   where the image has an edge.
//! * **Disparity**: winner-take-all on `S`, with a parabola fit when the
//!   refinement asks for it; the right view's map comes from the same `S`
//!   for the left-right check.
//!
//! Memory is the `u8` cost volume (census costs computed once for all
//! paths) and the `u16` sum volume, `3·W·H·D'` bytes with `D'` the
//! disparities padded to 32 lanes, plus a few rows of path costs (`u8`, see
//! `step`); both volumes are kept in [`SgmBuffers`] between frames
//! (measured peaks: docs/benchmarks.md, “Memory”).
//!
//! Aggregation is two sweeps, down and up, that run in parallel and each
//! add all their paths into a pixel's sums in one visit (see `sweep`); the
//! second sweep to visit a row picks its disparities while the sums are in
//! cache. Census, costs, path steps and the winner search have AVX2 kernels
//! (runtime-detected) with portable twins that give the same bits (tested).

use std::sync::Mutex;
use stereolink_image::{DisparityMap, GrayImage};

use crate::census::census_with;
use crate::refine::Raw;
use crate::{MatchSpec, StereoError};

use aggregate::sweep;
#[cfg(target_arch = "x86_64")]
use aggregate::sweep_avx2;
use cost::cost_volume;

mod aggregate;
mod cost;
mod select;
#[cfg(test)]
mod tests;

/// Cost of a match that falls outside the right view.
pub const OUTSIDE_COST: u16 = 62;
/// Path cost of the missing neighbours of `d_min` and `d_max`.
const SENTINEL: u8 = u8::MAX;
/// Largest `P2`: path costs must fit `u8` (see `step`).
pub const MAX_P2: u16 = 255 - OUTSIDE_COST;

/// SGM parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SgmParams {
    /// Penalty for a disparity change of one.
    pub p1: u16,
    /// Base penalty for larger disparity changes.
    pub p2: u16,
    /// Intensity scale γ of the adaptive P2 (larger: less adaptive).
    pub p2_gamma: u16,
    /// 4 or 8 paths.
    pub paths: u8,
}

impl Default for SgmParams {
    /// Chosen on the Middlebury v2 scenes with `stereolink eval`
    /// (docs/tuning.md, “P1 24, P2 90, γ 24, 8 paths”).
    fn default() -> Self {
        SgmParams {
            p1: 24,
            p2: 90,
            p2_gamma: 24,
            paths: 8,
        }
    }
}

impl SgmParams {
    pub(crate) fn validate(&self) -> Result<(), StereoError> {
        if self.paths != 4 && self.paths != 8 {
            return Err(StereoError::Parameter(format!(
                "SGM paths must be 4 or 8, not {}",
                self.paths
            )));
        }
        if self.p1 == 0 || self.p2 <= self.p1 || self.p2 > MAX_P2 || self.p2_gamma == 0 {
            return Err(StereoError::Parameter(format!(
                "SGM penalties need 0 < P1 < P2 <= {MAX_P2} and γ > 0 (got P1 {}, P2 {}, γ {})",
                self.p1, self.p2, self.p2_gamma
            )));
        }
        Ok(())
    }
}

struct Volume<'a> {
    w: usize,
    h: usize,
    nd: usize,
    /// Lanes per pixel: `nd` padded to a multiple of [`BLOCK`].
    np: usize,
    min_disp: usize,
    /// `C(x, y, d_min + k)` at `((y·W + x)·np + k)`; [`PAD`] for `k ≥ nd`.
    cost: &'a [u8],
    img: &'a GrayImage,
    p: SgmParams,
    /// `P2` by intensity step `|I(p) − I(p−r)|`.
    p2_by_step: [u8; 256],
    /// Fit a parabola to the winner's neighbouring sums.
    subpixel: bool,
}

impl Volume<'_> {
    #[inline(always)]
    fn p2(&self, a: u8, b: u8) -> u8 {
        self.p2_by_step[a.abs_diff(b) as usize]
    }
}

/// The adaptive `P2` for every intensity step (see the module doc).
fn p2_table(p: &SgmParams) -> [u8; 256] {
    let g = p.p2_gamma as u32;
    // P1 < P2 ≤ MAX_P2 (validated), so every value fits `u8`.
    std::array::from_fn(|step| ((p.p2 as u32 * g / (g + step as u32)) as u8).max(p.p1 as u8 + 1))
}

/// Lanes of one vector step along the disparity axis (one AVX2 register of `u8`).
const BLOCK: usize = 32;

/// Cost of the padding lanes past `d_max`: saturates every path cost there
/// to [`SENTINEL`], so they act as the missing neighbour of `d_max`.
const PAD: u8 = u8::MAX;

/// The cost and sum volumes, kept from one frame to the next: both are
/// entirely overwritten, so a frame of the same size neither allocates nor
/// clears them.
#[derive(Default)]
pub struct SgmBuffers {
    cost: Vec<u8>,
    sum: Vec<u16>,
}

/// Computes the raw SGM disparity (and the right view's map) of gray views.
pub fn sgm(left: &GrayImage, right: &GrayImage, spec: &MatchSpec, buffers: &mut SgmBuffers) -> Raw {
    sgm_with(left, right, spec, buffers, stereolink_image::cpu::avx2())
}

/// [`sgm`] with the AVX2 kernels (`use_avx2`, only if the CPU has it) or the
/// portable ones.
fn sgm_with(
    left: &GrayImage,
    right: &GrayImage,
    spec: &MatchSpec,
    buffers: &mut SgmBuffers,
    use_avx2: bool,
) -> Raw {
    let (w, h) = left.dims();
    let (cl, cr) = rayon::join(
        || census_with(left, use_avx2),
        || census_with(right, use_avx2),
    );
    let SgmBuffers { cost, sum } = buffers;
    let (nd, np) = (spec.ndisp(), spec.ndisp().next_multiple_of(BLOCK));
    cost_volume(&cl, &cr, w, (nd, np), spec.min_disp, cost, use_avx2);
    drop((cl, cr));
    let vol = Volume {
        w,
        h,
        nd,
        np,
        min_disp: spec.min_disp,
        cost,
        img: left,
        p: spec.sgm,
        p2_by_step: p2_table(&spec.sgm),
        subpixel: spec.refine.subpixel,
    };
    sum.resize(w * h * np, 0);
    let mut disparity = DisparityMap::new(w, h, f32::INFINITY);
    let mut right_map = DisparityMap::new(w, h, f32::INFINITY);
    let rows: Vec<Mutex<SumRow>> = sum
        .chunks_mut((w * np).max(1))
        .zip(disparity.as_mut_slice().chunks_mut(w.max(1)))
        .zip(right_map.as_mut_slice().chunks_mut(w.max(1)))
        .map(|((sums, left), right)| {
            Mutex::new(SumRow {
                sums,
                left,
                right,
                visited: false,
            })
        })
        .collect();
    let run = |downward: bool| {
        let eight = vol.p.paths == 8;
        #[cfg(target_arch = "x86_64")]
        if use_avx2 {
            // SAFETY: AVX2 and POPCNT presence was checked at run time.
            return unsafe {
                if eight {
                    sweep_avx2::<4>(&vol, &rows, downward)
                } else {
                    sweep_avx2::<2>(&vol, &rows, downward)
                }
            };
        }
        if eight {
            sweep::<4>(&vol, &rows, downward, false)
        } else {
            sweep::<2>(&vol, &rows, downward, false)
        }
    };
    rayon::join(|| run(true), || run(false));
    drop(rows);
    Raw {
        disparity,
        right: Some(right_map),
    }
}

/// A row of the sum volume and of both disparity maps, shared by the two
/// sweeps; whichever visits it second finds `visited` set and computes the
/// disparities while the sums are still in cache.
struct SumRow<'a> {
    sums: &'a mut [u16],
    left: &'a mut [f32],
    right: &'a mut [f32],
    visited: bool,
}
