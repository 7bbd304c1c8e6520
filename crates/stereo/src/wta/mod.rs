//! Winner-take-all on SAD, the paper's local method (its eq. 12):
//!
//! ```text
//! SAD(x, y, d) = Σ_{(i, j) ∈ n×n window} |I_L(x + i, y + j) − I_R(x + i − d, y + j)|
//! C(x, y, d)   = min_{(i, j) ∈ m×m} SAD(x + i, y + j, d)     (optional min filter)
//! d*(x, y)     = argmin_{d ∈ [d_min, d_max]} C(x, y, d)
//! ```
//!
//! `I` is gray luma in fixed point with [`WtaParams::gray_bits`] bits: 9
//! bits instead of the 8 of a gray image keep half a level of luma that
//! rounding would lose. The min filter (m×m, [`WtaParams::min_filter`]) is
//! the "shiftable window" of Scharstein & Szeliski's SSD+MF: a pixel takes,
//! per disparity, the best window among those that contain it, which keeps
//! windows from straddling a depth edge and so reduces edge fattening.
//!
//! Aggregation is O(1) per pixel and disparity: per row band, a column sum
//! `colsum[x][d]` over the window's rows is updated incrementally (add the
//! entering row, subtract the leaving one) and a horizontal running sum over
//! the columns gives the window sum. The disparity axis is innermost and
//! contiguous, padded to a whole number of `LANES`-wide blocks of `u16`
//! lanes; the lane operations come in three sets (`lanes` module, see
//! [`Kernel`]): AVX2 intrinsics chosen at run time where the CPU has them,
//! SWAR on a CPU without vector instructions (the ARM926 board), and
//! portable Rust elsewhere, which give bit-identical results (integer
//! arithmetic, the same tie rule: the smallest disparity wins). On the
//! SWAR kernel's general band loop (with a min filter or the right view's
//! map), a column whose entering and leaving rows agree (long runs of them
//! in a segmented pair) skips its update: the two cancel; the board's
//! setting has its own loop, with column sums from row tables (`swar`), and
//! so has the AVX2 kernel's default (no min filter, no right view's map),
//! with a pixel's costs and the check's minima in registers (`avx2`). Row
//! bands run in parallel (rayon). Window pixels outside the image
//! replicate the border.
//!
//! A match outside the right view (`x − d < 0`) is not considered; pixels
//! with `x < d_min` get no disparity (`inf`).

use stereolink_image::{DisparityMap, Plane};

use crate::{MatchSpec, StereoError};

use driver::{Band, Right};

#[cfg(target_arch = "x86_64")]
mod avx2;
mod driver;
mod luma;
mod portable;
mod swar;
#[cfg(test)]
mod tests;
mod winner;

pub use luma::{luma_labels_into, luma_samples, luma_samples_into};

/// Gray samples of a view, [`WtaParams::gray_bits`] bits each.
pub type Samples = Plane<u16>;

/// Integer disparities, as [`WtaMatcher::compute_levels_into`] writes them:
/// a CPU without an FPU keeps them as small integers until a caller needs
/// `f32` ([`levels_to_disparity`]).
pub type Levels = Plane<u16>;

/// The level of a pixel without a disparity (`inf` in a [`DisparityMap`]).
pub const NO_DISPARITY: u16 = u16::MAX;

/// The [`DisparityMap`] of `levels` ([`NO_DISPARITY`] becomes `inf`).
pub fn levels_to_disparity(levels: &Levels) -> DisparityMap {
    levels.map(|l| {
        if l == NO_DISPARITY {
            f32::INFINITY
        } else {
            l as f32
        }
    })
}

/// Parameters of [`WtaMatcher`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WtaParams {
    /// Smallest disparity searched.
    pub min_disp: usize,
    /// Number of disparities searched (`min_disp..min_disp + ndisp`).
    pub ndisp: usize,
    /// Odd window size n (n×n); sums must fit in 16 bits, so at most 15 for
    /// 8-bit gray, 11 for 9 bits and 7 for 10 ([`Self::max_block`]).
    pub block: usize,
    /// Bits per gray sample, 8..=10 (see [`luma_samples`]).
    pub gray_bits: u32,
    /// Side m of the min filter over the window sums (odd; 0 or 1 = off).
    pub min_filter: usize,
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
            gray_bits: spec.gray_bits,
            min_filter: spec.min_filter,
            uniqueness: spec.refine.uniqueness,
            subpixel: spec.refine.subpixel,
        }
    }

    /// The largest odd window whose sums of `bits`-bit differences fit in
    /// 16 bits (`block² · (2^bits − 1) ≤ 65535`), at most 15.
    pub fn max_block(bits: u32) -> usize {
        let top = (1usize << bits.min(16)) - 1;
        (1..=15)
            .step_by(2)
            .take_while(|b| b * b * top <= u16::MAX as usize)
            .last()
            .unwrap_or(1)
    }

    /// Checks the documented ranges (`ndisp` against the width is the caller's).
    pub fn validate(&self) -> Result<(), StereoError> {
        if !(8..=10).contains(&self.gray_bits) {
            return Err(StereoError::Parameter(format!(
                "gray bits {} must be 8, 9 or 10",
                self.gray_bits
            )));
        }
        if self.block == 0 || self.block % 2 == 0 || self.block > 15 {
            return Err(StereoError::BlockSize(self.block));
        }
        let max = Self::max_block(self.gray_bits);
        if self.block > max {
            return Err(StereoError::Parameter(format!(
                "block size {} is too large for {}-bit gray: at most {max} (window sums must fit in 16 bits)",
                self.block, self.gray_bits
            )));
        }
        if self.min_filter > 1 && (self.min_filter % 2 == 0 || self.min_filter > 15) {
            return Err(StereoError::Parameter(format!(
                "min filter size {} must be odd and at most 15 (0 or 1 = off)",
                self.min_filter
            )));
        }
        if self.ndisp == 0 {
            return Err(StereoError::Parameter("no disparity to search".into()));
        }
        Ok(())
    }
}

/// The lane operations a [`WtaMatcher`] runs; all give the same disparities.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Kernel {
    /// AVX2 where the CPU has it; else SWAR on a CPU without vector
    /// instructions (32-bit ARM without NEON), portable loops elsewhere.
    #[default]
    Auto,
    /// Plain loops, which the compiler vectorises where the CPU has vectors.
    Portable,
    /// Two `u16` lanes per `u32` word, and alike rows skipped: for a CPU
    /// without vector instructions.
    Swar,
}

/// A WTA-SAD matcher that keeps its buffers from one frame to the next, so
/// matching frames of an unchanged size allocates nothing after the first.
#[derive(Default)]
pub struct WtaMatcher {
    /// Each right row, border-padded and reversed (see
    /// [`reversed_rows`](driver::reversed_rows)).
    reversed: Vec<u16>,
    bands: Vec<Band>,
    kernel: Kernel,
}

impl WtaMatcher {
    /// An empty matcher; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// A matcher that always runs the portable kernel (no AVX2): same
    /// results, for testing and measuring.
    pub fn portable() -> Self {
        Self::with_kernel(Kernel::Portable)
    }

    /// A matcher that runs `kernel`: same results, for testing and measuring.
    pub fn with_kernel(kernel: Kernel) -> Self {
        WtaMatcher {
            kernel,
            ..Self::default()
        }
    }

    /// Matches `left` against `right` (same size, checked by the caller) and
    /// writes the disparity of every left pixel into `out` (same size).
    ///
    /// # Panics
    /// If the sizes differ or `params` violates its documented ranges.
    pub fn compute_into(
        &mut self,
        left: &Samples,
        right: &Samples,
        params: &WtaParams,
        out: &mut DisparityMap,
    ) {
        self.compute(left, right, params, out, Right::None);
    }

    /// As [`compute_into`](Self::compute_into), with integer disparities:
    /// the same winners, without an integer-to-float conversion per pixel
    /// (a software routine on a CPU without an FPU).
    ///
    /// # Panics
    /// As [`compute_into`](Self::compute_into), and if `params` asks for
    /// subpixel refinement or a disparity reaches [`NO_DISPARITY`].
    pub fn compute_levels_into(
        &mut self,
        left: &Samples,
        right: &Samples,
        params: &WtaParams,
        out: &mut Levels,
    ) {
        assert!(!params.subpixel, "integer levels have no subpixel part");
        assert!(params.min_disp + params.ndisp <= NO_DISPARITY as usize);
        self.compute(left, right, params, out, Right::None);
    }

    /// As [`compute_into`](Self::compute_into), then the left-right check
    /// at a tolerance below one pixel ([`crate::refine::lr_check`] with
    /// `tol` in `0..1` against the map of [`Self::compute_both_into`]):
    /// a pixel keeps its disparity if the right pixel it matches has the
    /// same winner. Done in the pass, without the right view's map: the
    /// right pixel `xr`'s winner is the smallest cost along its diagonal
    /// of the left pixels' costs, the smallest disparity winning ties, so
    /// the left pixel `xr + d` is that winner exactly when the running
    /// minimum of `xr`'s costs before its lane `d` is above its cost and
    /// the minimum of all of them, at the end of the row, equals it. A
    /// running minimum per right pixel is all it keeps (no lane, no map to
    /// write and look up), which is faster than checking against the right
    /// view's map (docs/tuning.md, “LR check inside the matching pass”).
    ///
    /// # Panics
    /// As [`compute_into`](Self::compute_into), and if `params` asks for
    /// subpixel refinement (whose disparities the check does not take).
    pub fn compute_checked_into(
        &mut self,
        left: &Samples,
        right: &Samples,
        params: &WtaParams,
        out: &mut DisparityMap,
    ) {
        assert!(!params.subpixel, "the check takes whole disparities");
        self.compute(left, right, params, out, Right::Check);
    }

    /// As [`compute_into`](Self::compute_into), and also writes the right
    /// view's integer disparity map (right `(x, y)` matches left
    /// `(x + d, y)`, the left-right check's input) into `right_out`.
    ///
    /// The right view's costs are the same window sums: the right pixel
    /// `x − d` at disparity `d` costs what the left pixel `x` does, so both
    /// maps come from one pass (a running minimum per right pixel, the
    /// smallest disparity winning ties). The windows are the left pixel's,
    /// so near the image's left and right borders the right map can differ
    /// from matching the mirrored pair.
    pub fn compute_both_into(
        &mut self,
        left: &Samples,
        right: &Samples,
        params: &WtaParams,
        out: &mut DisparityMap,
        right_out: &mut DisparityMap,
    ) {
        assert_eq!(left.dims(), right_out.dims());
        self.compute(left, right, params, out, Right::Map(right_out));
    }
}

/// True when the AVX2 kernels can run here (the SGM kernels also use
/// POPCNT, which every AVX2 CPU has; both are checked): the project's one
/// detection, [`stereolink_image::cpu::avx2_available`].
pub fn avx2_available() -> bool {
    stereolink_image::cpu::avx2_available()
}
