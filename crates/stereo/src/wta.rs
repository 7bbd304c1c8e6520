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

use rayon::prelude::*;
use stereolink_image::{DisparityMap, LabelMap, Plane, Rgb, RgbImage};

use crate::lanes::{LaneOps, Portable, Swar, LANES};
use crate::{MatchSpec, StereoError};

#[cfg(target_arch = "x86_64")]
mod avx2;
mod swar;

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

/// Writes the luma of `img` into `out` (resized, storage reused) in fixed
/// point with `bits` bits (8..=10): BT.601 weights `(77 R + 150 G + 29 B) / 256`
/// scaled by `2^(bits − 8)` and rounded; 8 bits equal
/// [`stereolink_image::color::luma`].
pub fn luma_samples_into(img: &RgbImage, bits: u32, out: &mut Samples) {
    // Every sample is written below: a plane of the size is not cleared.
    if out.dims() != img.dims() {
        out.reset(img.width(), img.height(), 0);
    }
    #[cfg(target_arch = "x86_64")]
    if avx2_available() {
        // SAFETY: the CPU has AVX2.
        return unsafe { luma_avx2(img.as_slice(), bits, out.as_mut_slice()) };
    }
    luma(img.as_slice(), bits, out.as_mut_slice());
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn luma_avx2(pixels: &[Rgb], bits: u32, out: &mut [u16]) {
    luma(pixels, bits, out)
}

/// [`luma_samples_into`]'s loop: one per precision, with the shift a
/// constant, so that it vectorises (the pixels' bytes are spread apart by
/// shuffles; AVX2 has the wider ones).
#[inline(always)]
fn luma(pixels: &[Rgb], bits: u32, out: &mut [u16]) {
    #[inline(always)]
    fn shifted<const SHIFT: u32>(pixels: &[Rgb], out: &mut [u16]) {
        // 77 · 255 + 150 · 255 + 29 · 255 + 128 < 2¹⁶: 16-bit lanes suffice.
        for (o, p) in out.iter_mut().zip(pixels) {
            let sum = 77 * p[0] as u16 + 150 * p[1] as u16 + 29 * p[2] as u16;
            *o = (sum + (1 << (SHIFT - 1))) >> SHIFT;
        }
    }
    match bits.clamp(8, 10) {
        8 => shifted::<8>(pixels, out),
        9 => shifted::<7>(pixels, out),
        _ => shifted::<6>(pixels, out),
    }
}

/// [`luma_samples_into`] for a label map and its palette (each label
/// indexing it): the luma of each colour once, then a lookup per pixel.
/// `lut` is scratch (resized, storage reused).
///
/// # Panics
/// If a label does not index `palette`.
pub fn luma_labels_into(
    labels: &LabelMap,
    palette: &[Rgb],
    bits: u32,
    lut: &mut Vec<u16>,
    out: &mut Samples,
) {
    // A lookup for every u16 label (no bounds check per pixel): the
    // palette's luma, then NOT_IN_PALETTE (above every luma, 10 bits at most).
    const NOT_IN_PALETTE: u16 = u16::MAX;
    let n = palette.len();
    lut.clear();
    lut.resize(n.max(1 << 16), NOT_IN_PALETTE);
    luma(palette, bits, &mut lut[..n]);
    let lut: &[u16; 1 << 16] = lut[..1 << 16].try_into().expect("65 536 entries");
    // Every sample is written below: a plane of the size is not cleared.
    if out.dims() != labels.dims() {
        out.reset(labels.width(), labels.height(), 0);
    }
    // Four pixels a step (the loop's own work shared).
    let (out, labels) = (out.as_mut_slice(), labels.as_slice());
    let mut seen = 0;
    let (mut o4, mut l4) = (out.chunks_exact_mut(4), labels.chunks_exact(4));
    for (o, l) in (&mut o4).zip(&mut l4) {
        let v = [
            lut[l[0] as usize],
            lut[l[1] as usize],
            lut[l[2] as usize],
            lut[l[3] as usize],
        ];
        seen |= v[0] | v[1] | v[2] | v[3];
        o.copy_from_slice(&v);
    }
    for (o, &l) in o4.into_remainder().iter_mut().zip(l4.remainder()) {
        *o = lut[l as usize];
        seen |= *o;
    }
    assert!(seen != NOT_IN_PALETTE, "a label beyond its palette of {n}");
}

/// [`luma_samples_into`] into a new image.
pub fn luma_samples(img: &RgbImage, bits: u32) -> Samples {
    let mut out = Samples::default();
    luma_samples_into(img, bits, &mut out);
    out
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

/// True where the target has no vector unit the portable loops could use.
const NO_VECTORS: bool = cfg!(all(target_arch = "arm", not(target_feature = "neon")));

/// Scratch of one row band.
#[derive(Default)]
struct Band {
    colsum: Vec<u16>,
    /// Per reversed-row index, how many of the entering and leaving right
    /// rows' samples before it differ (the SWAR kernel's skip test).
    differ: Vec<u32>,
    /// The window sums of the last `min_filter` rows, `W × lanes` each.
    ring: Vec<u16>,
    /// Their per-lane minimum over those rows (with the min filter on).
    vmin: Vec<u16>,
    /// The min-filtered costs of one pixel.
    cost: Vec<u16>,
    /// Per right pixel `xr` of the current row, at `W − 1 − xr`: the
    /// smallest cost seen so far and its lane (for the right view's map;
    /// the cost alone for the check of [`WtaMatcher::compute_checked_into`]).
    right_best: Vec<u16>,
    right_lane: Vec<u16>,
    /// Per left pixel of the current row, for that check.
    winners: Vec<Winner>,
    /// The SWAR kernel's own scratch, in the board's setting (see [`swar`]).
    swar: swar::SwarBand,
}

/// A WTA-SAD matcher that keeps its buffers from one frame to the next, so
/// matching frames of an unchanged size allocates nothing after the first.
#[derive(Default)]
pub struct WtaMatcher {
    /// Each right row, border-padded and reversed (see [`reversed_rows`]).
    reversed: Vec<u16>,
    bands: Vec<Band>,
    kernel: Kernel,
}

/// Fewest rows per parallel band: each band re-primes `block` rows.
const MIN_BAND_ROWS: usize = 32;

/// Cost lanes per pixel for `ndisp` disparities.
fn lanes(ndisp: usize) -> usize {
    ndisp.next_multiple_of(LANES)
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
    /// write and look up): on Cones, one thread, matching and check took
    /// 4.74 against 5.38 ms of CPU time a frame.
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

    fn compute<T: Disparity>(
        &mut self,
        left: &Samples,
        right: &Samples,
        params: &WtaParams,
        out: &mut Plane<T>,
        right_view: Right,
    ) {
        use rayon::iter::Either;
        assert_eq!(left.dims(), right.dims());
        assert_eq!(left.dims(), out.dims());
        if let Err(e) = params.validate() {
            panic!("{e}");
        }
        let (w, h) = left.dims();
        if w == 0 || h == 0 {
            return;
        }
        let nl = lanes(params.ndisp);
        let stride = w + nl + params.min_disp;
        reversed_rows(right, params, &mut self.reversed);
        // Two bands per worker balance the load; one worker (the embedded
        // board) gets one band and primes the window once.
        let band_rows = match rayon::current_num_threads() {
            1 => h,
            n => h.div_ceil(2 * n).max(MIN_BAND_ROWS),
        };
        let n_bands = h.div_ceil(band_rows);
        self.bands
            .resize_with(n_bands.max(self.bands.len()), Band::default);
        let reversed = &self.reversed;
        let kernel = match self.kernel {
            Kernel::Auto if avx2_available() => Kernel::Auto,
            Kernel::Auto if NO_VECTORS => Kernel::Swar,
            Kernel::Auto => Kernel::Portable,
            k => k,
        };
        let check = matches!(right_view, Right::Check);
        let right_rows = match right_view {
            Right::Map(r) => Either::Left(r.as_mut_slice().par_chunks_mut(w * band_rows).map(Some)),
            _ => Either::Right((0..n_bands).into_par_iter().map(|_| None)),
        };
        out.as_mut_slice()
            .par_chunks_mut(w * band_rows)
            .zip(right_rows)
            .zip(self.bands.par_iter_mut())
            .enumerate()
            .for_each(|(i, ((rows, right_rows), band))| {
                let job = Job {
                    left,
                    reversed,
                    stride,
                    params,
                    y0: i * band_rows,
                    check,
                };
                let m = params.min_filter.max(1);
                if kernel == Kernel::Swar
                    && m == 1
                    && right_rows.is_none()
                    && !check
                    && swar::band(&job, &mut band.swar, rows)
                {
                    return;
                }
                band.colsum.resize(w * nl, 0);
                if kernel == Kernel::Swar {
                    band.differ.resize(stride + 1, 0);
                }
                band.ring.resize(if m > 1 { m * w * nl } else { 0 }, 0);
                band.vmin.resize(if m > 1 { w * nl } else { 0 }, 0);
                band.cost.resize(nl, 0);
                if right_rows.is_some() || check {
                    band.right_best.resize(w + nl, 0);
                }
                if right_rows.is_some() {
                    band.right_lane.resize(w + nl, 0);
                }
                if check {
                    band.winners.resize(w, Winner::default());
                }
                match kernel {
                    // Auto stands for AVX2 here.
                    Kernel::Auto => {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: only reached when the CPU reports AVX2 (checked in
                        // `avx2_available`).
                        unsafe {
                            // The default setting has a loop of its own.
                            let plain = m == 1 && right_rows.is_none();
                            if !(plain && avx2::band(&job, band, rows)) {
                                band_avx2(&job, band, rows, right_rows)
                            }
                        }
                    }
                    Kernel::Portable => band_scalar::<Portable, T>(&job, band, rows, right_rows),
                    Kernel::Swar => band_scalar::<Swar, T>(&job, band, rows, right_rows),
                }
            });
    }
}

/// True when the AVX2 kernels can run here (the SGM kernels also use
/// POPCNT, which every AVX2 CPU has; both are checked).
pub fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("popcnt")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Fills `buf` with each right row padded on the left by replicating its
/// first pixel, then reversed, so that for a left column `x` the right pixels
/// `x − d_min − k` for `k = 0..lanes` are `buf[row][W + d_min − 1 − x + k]`:
/// contiguous in `k`.
fn reversed_rows(right: &Samples, p: &WtaParams, buf: &mut Vec<u16>) {
    let (w, h) = right.dims();
    let pad = lanes(p.ndisp) + p.min_disp;
    let stride = w + pad;
    buf.resize(stride * h, 0);
    // Rows in parallel, each a reversed copy and a fill (both vectorise).
    buf.par_chunks_exact_mut(stride)
        .enumerate()
        .for_each(|(y, dst)| {
            let row = right.row(y);
            let (reversed, padding) = dst.split_at_mut(w);
            reversed
                .iter_mut()
                .zip(row.iter().rev())
                .for_each(|(v, &s)| *v = s);
            padding.fill(row[0]);
        });
}

struct Job<'a> {
    left: &'a Samples,
    reversed: &'a [u16],
    stride: usize,
    params: &'a WtaParams,
    y0: usize,
    /// Whether the band checks its winners against the right view's
    /// ([`WtaMatcher::compute_checked_into`]).
    check: bool,
}

impl Job<'_> {
    /// Where the right pixels `x − d_min − k` of left column `x` start in
    /// a reversed row.
    fn right_start(&self, x: usize) -> usize {
        self.left.width() + self.params.min_disp - 1 - x
    }

    /// Right row `y`, border-padded and reversed (see [`reversed_rows`]).
    fn reversed_row(&self, y: usize) -> &[u16] {
        &self.reversed[y * self.stride..(y + 1) * self.stride]
    }

    /// The right pixels `x − d_min − k`, `k = 0..lanes`, of left column
    /// `x` in row `y`, contiguous in `k`.
    fn right_of(&self, y: usize, x: usize) -> &[u16] {
        let start = self.right_start(x);
        &self.reversed_row(y)[start..start + lanes(self.params.ndisp)]
    }
}

/// What [`WtaMatcher::compute`] finds of the right view.
enum Right<'a> {
    None,
    /// Its map.
    Map(&'a mut DisparityMap),
    /// Only whether each left winner is its match's winner too.
    Check,
}

/// A left pixel's winner, for the check of [`WtaMatcher::compute_checked_into`].
#[derive(Clone, Copy, Default)]
struct Winner {
    /// Its lane and cost.
    lane: u16,
    cost: u16,
    /// Whether every earlier lane of its right pixel cost more.
    first: bool,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn band_avx2<T: Disparity>(
    job: &Job,
    band: &mut Band,
    out: &mut [T],
    right: Option<&mut [f32]>,
) {
    // SAFETY: this function only runs where AVX2 is present.
    unsafe { band_with::<crate::lanes::Avx2, T>(job, band, out, right) }
}

fn band_scalar<K: LaneOps, T: Disparity>(
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
unsafe fn band_with<K: LaneOps, T: Disparity>(
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

/// The check of [`WtaMatcher::compute_checked_into`] on a row's
/// `winners`, given the smallest cost of each right pixel `xr` at
/// `right_best[W − 1 − xr]`: a left pixel keeps its disparity if its
/// winner is its right pixel's first smallest cost. Pixels below `min_disp`
/// have no winner (and no disparity).
fn check_row<T: Disparity>(out: &mut [T], winners: &[Winner], right_best: &[u16], min_disp: usize) {
    let w = out.len();
    for (x, d) in out.iter_mut().enumerate().skip(min_disp) {
        let Winner { lane, cost, first } = winners[x];
        let at = w - 1 - (x - min_disp) + lane as usize;
        if !(first && right_best[at] == cost) {
            *d = T::NONE;
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
unsafe fn accumulate_row<K: LaneOps>(
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

/// A disparity as a band writes it: `f32` (with the subpixel fit) or an
/// integer level.
trait Disparity: Copy + Send + Sync {
    /// A pixel without a disparity.
    const NONE: Self;
    /// The winning disparity among the first `valid` of `costs`, given the
    /// index `k` of their smallest cost and that cost (index `k` is
    /// disparity `d_min + k`), after the uniqueness test.
    fn winner(costs: &[u16], valid: usize, best: (usize, u16), p: &WtaParams) -> Self;
}

impl Disparity for f32 {
    const NONE: f32 = f32::INFINITY;

    /// Also applies the subpixel fit.
    #[inline(always)]
    fn winner(costs: &[u16], valid: usize, (k, best): (usize, u16), p: &WtaParams) -> f32 {
        let costs = &costs[..valid];
        if ambiguous(costs, (k, best), p) {
            return f32::INFINITY;
        }
        let mut d = (p.min_disp + k) as f32;
        if p.subpixel && k > 0 && k + 1 < costs.len() {
            d += crate::refine::parabola(costs[k - 1] as f32, best as f32, costs[k + 1] as f32);
        }
        d
    }
}

impl Disparity for u16 {
    const NONE: u16 = NO_DISPARITY;

    #[inline(always)]
    fn winner(costs: &[u16], valid: usize, (k, best): (usize, u16), p: &WtaParams) -> u16 {
        if ambiguous(&costs[..valid], (k, best), p) {
            NO_DISPARITY
        } else {
            (p.min_disp + k) as u16
        }
    }
}

/// The uniqueness test: true when a disparity more than 1 away from the
/// winner `k` costs less than `(100 + uniqueness) %` of its cost `best`.
#[inline(always)]
fn ambiguous(costs: &[u16], (k, best): (usize, u16), p: &WtaParams) -> bool {
    let limit = best as u32 * (100 + p.uniqueness);
    p.uniqueness > 0
        && costs
            .iter()
            .enumerate()
            .any(|(j, &c)| j.abs_diff(k) > 1 && (c as u32) * 100 < limit)
}

/// Straightforward per pixel SAD and min filter (O(n²·m²) per pixel and
/// disparity), the reference the fast path is tested against.
#[cfg(test)]
pub(crate) fn reference(left: &Samples, right: &Samples, p: &WtaParams) -> DisparityMap {
    let (w, h) = left.dims();
    let (r, mr) = ((p.block / 2) as isize, (p.min_filter.max(1) / 2) as isize);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1);
    let at =
        |img: &Samples, x: isize, y: isize| img.get(clamp(x, w) as usize, clamp(y, h) as usize);
    // Eq. 12 at an image pixel and disparity index k. Border replication
    // applies to the left column first, then the right pixel is taken at
    // (clamped x) − d.
    let sad = |x: isize, y: isize, k: usize| {
        let d = (p.min_disp + k) as isize;
        let mut s = 0u32;
        for dy in -r..=r {
            for dx in -r..=r {
                let xl = clamp(x + dx, w);
                s += at(left, xl, y + dy).abs_diff(at(right, (xl - d).max(0), y + dy)) as u32;
            }
        }
        s as u16
    };
    DisparityMap::from_fn(w, h, |x, y| {
        if x < p.min_disp {
            return f32::INFINITY;
        }
        let (x, y) = (x as isize, y as isize);
        let costs: Vec<u16> = (0..p.ndisp.min(x as usize - p.min_disp + 1))
            .map(|k| {
                let around = (-mr..=mr).flat_map(|dy| (-mr..=mr).map(move |dx| (dx, dy)));
                around
                    .map(|(dx, dy)| sad(clamp(x + dx, w), clamp(y + dy, h), k))
                    .min()
                    .unwrap()
            })
            .collect();
        let k = (0..costs.len()).min_by_key(|&k| (costs[k], k)).unwrap();
        f32::winner(&costs, costs.len(), (k, costs[k]), p)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const KERNELS: [Kernel; 3] = [Kernel::Auto, Kernel::Portable, Kernel::Swar];

    /// Noise with `bits`-bit samples.
    fn noise(w: usize, h: usize, seed: u64, bits: u32) -> Samples {
        let mut s = seed | 1;
        Samples::from_fn(w, h, |_, _| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 24) as u16 & ((1 << bits) - 1)
        })
    }

    fn image(w: usize, h: usize, seed: u64) -> Samples {
        noise(w, h, seed, 8)
    }

    #[test]
    fn luma_samples_refine_the_8_bit_luma() {
        let img = RgbImage::from_fn(16, 16, |x, y| [(x * 16) as u8, (y * 16) as u8, 255]);
        let (g8, g9) = (luma_samples(&img, 8), luma_samples(&img, 9));
        for (x, y) in [(0, 0), (3, 5), (15, 15)] {
            let p = img.get(x, y);
            assert_eq!(g8.get(x, y), stereolink_image::color::luma(p) as u16);
            assert!(g9.get(x, y).abs_diff(2 * g8.get(x, y)) <= 1);
        }
        assert_eq!(
            luma_samples(&RgbImage::new(1, 1, [255; 3]), 10).get(0, 0),
            1020
        );
        // The loop without AVX2 gives the same samples (33 pixels: a
        // vector tail too).
        let img = RgbImage::from_fn(33, 7, |x, y| {
            [(x * 37 + y) as u8, (y * 91) as u8, (x ^ y) as u8]
        });
        for bits in 8..=10 {
            let mut portable = vec![0; 33 * 7];
            luma(img.as_slice(), bits, &mut portable);
            assert_eq!(luma_samples(&img, bits).as_slice(), portable.as_slice());
        }
    }

    /// Luma through the palette equals the luma of the expanded view.
    #[test]
    fn luma_of_labels_equals_luma_of_their_colours() {
        let palette: Vec<Rgb> = (0..7u8)
            .map(|i| [i * 37, 255 - i * 29, i * i * 5])
            .collect();
        let labels = LabelMap::from_fn(23, 9, |x, y| ((x * 3 + y * 5) % 7) as u16);
        let rgb = labels.map(|l| palette[l as usize]);
        let (mut lut, mut out) = (Vec::new(), Samples::default());
        for bits in 8..=10 {
            luma_labels_into(&labels, &palette, bits, &mut lut, &mut out);
            assert_eq!(out, luma_samples(&rgb, bits), "{bits} bits");
        }
    }

    #[test]
    #[should_panic(expected = "beyond its palette")]
    fn a_label_beyond_the_palette_panics() {
        let labels = LabelMap::from_fn(5, 3, |x, _| x as u16);
        let (mut lut, mut out) = (Vec::new(), Samples::default());
        luma_labels_into(&labels, &[[9; 3]; 4], 8, &mut lut, &mut out);
    }

    #[test]
    fn parameters_out_of_range_are_errors() {
        let ok = WtaParams {
            min_disp: 0,
            ndisp: 8,
            block: 11,
            gray_bits: 9,
            min_filter: 5,
            uniqueness: 0,
            subpixel: false,
        };
        assert_eq!(ok.validate(), Ok(()));
        assert_eq!(
            [8, 9, 10].map(WtaParams::max_block),
            [15, 11, 7],
            "sums of the largest windows fit in u16"
        );
        for bad in [
            WtaParams { block: 13, ..ok },
            WtaParams { block: 4, ..ok },
            WtaParams { block: 0, ..ok },
            WtaParams {
                gray_bits: 11,
                ..ok
            },
            WtaParams { gray_bits: 7, ..ok },
            WtaParams {
                min_filter: 4,
                ..ok
            },
            WtaParams {
                min_filter: 17,
                ..ok
            },
            WtaParams { ndisp: 0, ..ok },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }

    #[test]
    fn shifted_noise_is_recovered_exactly() {
        let right = image(80, 40, 7);
        let left = Samples::from_fn(80, 40, |x, y| right.get(x.saturating_sub(6), y));
        let p = WtaParams {
            min_disp: 0,
            ndisp: 16,
            block: 5,
            gray_bits: 8,
            min_filter: 0,
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
            gray_bits: 8,
            min_filter: 3,
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

    #[test]
    fn right_map_equals_matching_the_mirrored_pair_inside() {
        let (w, h) = (90, 30);
        let right = image(w, h, 3);
        let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(5 + y % 3), y));
        let p = WtaParams {
            min_disp: 1,
            ndisp: 20,
            block: 5,
            gray_bits: 8,
            min_filter: 0,
            uniqueness: 0,
            subpixel: false,
        };
        let mirrored = {
            let (fl, fr) = (crate::refine::flip(&right), crate::refine::flip(&left));
            let mut d = DisparityMap::new(w, h, 0.0);
            WtaMatcher::new().compute_into(&fl, &fr, &p, &mut d);
            crate::refine::flip(&d)
        };
        for mut matcher in KERNELS.map(WtaMatcher::with_kernel) {
            let (mut l, mut r) = (DisparityMap::new(w, h, 0.0), DisparityMap::new(w, h, 0.0));
            matcher.compute_both_into(&left, &right, &p, &mut l, &mut r);
            let mut plain = DisparityMap::new(w, h, 0.0);
            matcher.compute_into(&left, &right, &p, &mut plain);
            assert_eq!(l, plain);
            // Windows that stay inside both views on both sides agree.
            for y in 0..h {
                for x in 3..w - 3 - 21 {
                    assert_eq!(r.get(x, y), mirrored.get(x, y), "({x}, {y})");
                }
                // No left pixel lies right of the last right columns' match.
                assert_eq!(r.get(w - 1, y), f32::INFINITY);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// The check inside the pass equals the right view's map and
        /// `refine::lr_check` at tolerances below one pixel, with every
        /// kernel, min filter and uniqueness test; on pairs with few gray
        /// levels (ties between disparities are frequent).
        #[test]
        fn the_check_in_the_pass_equals_the_lr_check(
            w in 1usize..70, h in 1usize..12, seed in any::<u64>(), shift in 0usize..9,
            min_disp in 0usize..4, ndisp in 1usize..40, half in 0usize..4,
            min_filter in prop_oneof![Just(0usize), Just(3)],
            uniqueness in prop_oneof![Just(0u32), Just(15u32)], tol in 0f32..1.0,
        ) {
            let right = levels_view(w, h, seed, 4);
            let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift + y % 2), y));
            let p = WtaParams {
                min_disp, ndisp, block: 2 * half + 1, gray_bits: 8, min_filter,
                uniqueness, subpixel: false,
            };
            for mut matcher in KERNELS.map(WtaMatcher::with_kernel) {
                let (mut want, mut r) = (DisparityMap::new(w, h, 0.0), DisparityMap::new(w, h, 0.0));
                matcher.compute_both_into(&left, &right, &p, &mut want, &mut r);
                crate::refine::lr_check(&mut want, &r, tol);
                let mut got = DisparityMap::new(w, h, 0.0);
                matcher.compute_checked_into(&left, &right, &p, &mut got);
                prop_assert_eq!(&got, &want);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// The AVX2 loop of the default setting (no min filter, no right
        /// map; its own up to 96 lanes) equals the general loop of the
        /// portable kernel, with and without the check in the pass, on
        /// pairs with few gray levels (frequent ties) at every width
        /// against the lanes.
        #[test]
        fn avx2_default_loop_equals_the_general_loop(
            w in 1usize..140, h in 1usize..10, seed in any::<u64>(), shift in 0usize..40,
            min_disp in 0usize..5, ndisp in 1usize..97, half in 0usize..6,
            uniqueness in prop_oneof![Just(0u32), Just(15u32)], subpixel in any::<bool>(),
        ) {
            let right = levels_view(w, h, seed, 5);
            let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift + y % 3), y));
            let p = WtaParams {
                min_disp, ndisp, block: 2 * half + 1, gray_bits: 8, min_filter: 0,
                uniqueness, subpixel,
            };
            let (mut fast, mut general) = (WtaMatcher::new(), WtaMatcher::portable());
            let run = |m: &mut WtaMatcher, checked: bool| {
                let mut out = DisparityMap::new(w, h, 0.0);
                if checked {
                    m.compute_checked_into(&left, &right, &p, &mut out);
                } else {
                    m.compute_into(&left, &right, &p, &mut out);
                }
                out.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            };
            prop_assert_eq!(run(&mut fast, false), run(&mut general, false));
            if !subpixel {
                prop_assert_eq!(run(&mut fast, true), run(&mut general, true));
            }
        }
    }

    /// A segmented-looking view: three gray levels in blocks, so that
    /// rows repeat and the SWAR kernel's general band loop skips the
    /// columns they leave alike.
    fn blocks(w: usize, h: usize, seed: u64) -> Samples {
        Samples::from_fn(w, h, |x, y| {
            let v = ((x / 5) as u64 * 31 + (y / 7) as u64 * 17) ^ seed;
            [20, 130, 240][(v.wrapping_mul(0x9E37_79B9) >> 9) as usize % 3]
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Every kernel equals the naive definition on blocky pairs: the
        /// SWAR kernel's board loop (no min filter) and its general loop,
        /// where the skipping of alike rows takes part (with one).
        #[test]
        fn kernels_equal_reference_on_blocks(
            w in 1usize..60, h in 1usize..40, seed in any::<u64>(), shift in 0usize..6,
            min_disp in 0usize..3, ndisp in 1usize..20, half in 0usize..5,
            min_filter in prop_oneof![Just(0usize), Just(3)],
        ) {
            let right = blocks(w, h, seed);
            let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift), y));
            let p = WtaParams {
                min_disp, ndisp, block: 2 * half + 1, gray_bits: 8, min_filter,
                uniqueness: 0, subpixel: false,
            };
            let slow = reference(&left, &right, &p);
            for kernel in KERNELS {
                let mut levels = Levels::new(w, h, 0);
                WtaMatcher::with_kernel(kernel).compute_levels_into(&left, &right, &p, &mut levels);
                prop_assert_eq!(&levels_to_disparity(&levels), &slow, "{:?}", kernel);
            }
        }
    }

    /// A segmented-looking view of `levels` gray values (8 bits) in
    /// blocks of random sizes.
    fn levels_view(w: usize, h: usize, seed: u64, levels: u16) -> Samples {
        let (bw, bh) = (2 + seed as usize % 9, 1 + (seed >> 8) as usize % 6);
        Samples::from_fn(w, h, |x, y| {
            let v = ((x / bw) as u64 * 0x9E37_79B9) ^ ((y / bh) as u64 * 0x85EB_CA6B) ^ seed;
            let l = (v.wrapping_mul(0xC2B2_AE35) >> 13) as u16 % levels;
            l * (255 / levels.max(2)) + (seed >> 20) as u16 % 7
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        /// The SWAR kernel in the board's setting (no min filter, 16 or 32
        /// disparities, few gray levels: its column sums come from tables,
        /// and from the direct path when a row has more values than table
        /// slots) equals the naive definition.
        #[test]
        fn swar_board_setting_equals_reference(
            w in 33usize..110, h in 1usize..30, seed in any::<u64>(), shift in 0usize..12,
            min_disp in 0usize..3, wide in any::<bool>(), half in 0usize..8,
            levels in 1u16..12, subpixel in any::<bool>(),
        ) {
            let right = levels_view(w, h, seed, levels);
            let left = Samples::from_fn(w, h, |x, y| right.get(x.saturating_sub(shift + y % 2), y));
            let p = WtaParams {
                min_disp, ndisp: if wide { 32 } else { 16 }, block: 2 * half + 1, gray_bits: 8,
                min_filter: 0, uniqueness: 0, subpixel,
            };
            let slow = reference(&left, &right, &p);
            let mut matcher = WtaMatcher::with_kernel(Kernel::Swar);
            let mut fast = DisparityMap::new(w, h, 0.0);
            matcher.compute_into(&left, &right, &p, &mut fast);
            let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            prop_assert_eq!(bits(&fast), bits(&slow));
            if !subpixel {
                let mut levels = Levels::new(w, h, 0);
                matcher.compute_levels_into(&left, &right, &p, &mut levels);
                prop_assert_eq!(&levels_to_disparity(&levels), &slow);
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]
        /// Both kernels (AVX2 where present, and portable) equal the naive
        /// definition, at every gray precision and min filter size.
        #[test]
        fn fast_equals_reference(
            w in 1usize..40, h in 1usize..40, seed in any::<u64>(),
            min_disp in 0usize..4, ndisp in 1usize..12, half in 0usize..8,
            gray_bits in 8u32..=10, min_filter in prop_oneof![Just(0usize), Just(1), Just(3), Just(5)],
            subpixel in any::<bool>(), uniqueness in prop_oneof![Just(0u32), Just(15u32)],
        ) {
            let (l, r) = (noise(w, h, seed, gray_bits), noise(w, h, seed ^ 0xABCD, gray_bits));
            let block = (2 * half + 1).min(WtaParams::max_block(gray_bits));
            let p = WtaParams { min_disp, ndisp, block, gray_bits, min_filter, uniqueness, subpixel };
            let slow = reference(&l, &r, &p);
            let bits = |m: &DisparityMap| m.as_slice().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            for mut matcher in KERNELS.map(WtaMatcher::with_kernel) {
                let mut fast = DisparityMap::new(w, h, 0.0);
                matcher.compute_into(&l, &r, &p, &mut fast);
                prop_assert_eq!(bits(&fast), bits(&slow));
                if !subpixel {
                    let mut levels = Levels::new(w, h, 0);
                    matcher.compute_levels_into(&l, &r, &p, &mut levels);
                    prop_assert_eq!(bits(&levels_to_disparity(&levels)), bits(&slow));
                }
            }
        }
    }
}
