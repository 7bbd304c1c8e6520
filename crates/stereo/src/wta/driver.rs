//! The driver of a [`WtaMatcher`] frame: the right view's reversed rows,
//! the split into row bands run in parallel, the choice of the band loop
//! (AVX2, SWAR or the general one in `portable`) and each band's scratch.
//! Its own module: the band loops share the job and scratch it defines.

use rayon::prelude::*;
use stereolink_image::{DisparityMap, Plane};

#[cfg(target_arch = "x86_64")]
use super::avx2;
#[cfg(target_arch = "x86_64")]
use super::portable::band_avx2;
use super::portable::band_scalar;
use super::swar;
use super::winner::{Disparity, Winner};
use super::{Kernel, Samples, WtaMatcher, WtaParams};
use crate::lanes::{Portable, Swar, LANES};

/// True where the target has no vector unit the portable loops could use.
const NO_VECTORS: bool = cfg!(all(target_arch = "arm", not(target_feature = "neon")));

/// Scratch of one row band.
#[derive(Default)]
pub(super) struct Band {
    pub(super) colsum: Vec<u16>,
    /// Per reversed-row index, how many of the entering and leaving right
    /// rows' samples before it differ (the SWAR kernel's skip test).
    pub(super) differ: Vec<u32>,
    /// The window sums of the last `min_filter` rows, `W × lanes` each.
    pub(super) ring: Vec<u16>,
    /// Their per-lane minimum over those rows (with the min filter on).
    pub(super) vmin: Vec<u16>,
    /// The min-filtered costs of one pixel.
    pub(super) cost: Vec<u16>,
    /// Per right pixel `xr` of the current row, at `W − 1 − xr`: the
    /// smallest cost seen so far and its lane (for the right view's map;
    /// the cost alone for the check of [`WtaMatcher::compute_checked_into`]).
    pub(super) right_best: Vec<u16>,
    pub(super) right_lane: Vec<u16>,
    /// Per left pixel of the current row, for that check.
    pub(super) winners: Vec<Winner>,
    /// The SWAR kernel's own scratch, in the board's setting (see [`swar`]).
    pub(super) swar: swar::SwarBand,
}

/// Fewest rows per parallel band: each band re-primes `block` rows.
const MIN_BAND_ROWS: usize = 32;

/// Cost lanes per pixel for `ndisp` disparities.
pub(super) fn lanes(ndisp: usize) -> usize {
    ndisp.next_multiple_of(LANES)
}

impl WtaMatcher {
    pub(super) fn compute<T: Disparity>(
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
            Kernel::Auto if stereolink_image::cpu::avx2() => Kernel::Auto,
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
                        // `stereolink_image::cpu::avx2`).
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

/// Fills `buf` with each right row padded on the left by replicating its
/// first pixel, then reversed, so that for a left column `x` the right pixels
/// `x − d_min − k` for `k = 0..lanes` are `buf[row][W + d_min − 1 − x + k]`:
/// contiguous in `k`.
pub(super) fn reversed_rows(right: &Samples, p: &WtaParams, buf: &mut Vec<u16>) {
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

pub(super) struct Job<'a> {
    pub(super) left: &'a Samples,
    pub(super) reversed: &'a [u16],
    pub(super) stride: usize,
    pub(super) params: &'a WtaParams,
    pub(super) y0: usize,
    /// Whether the band checks its winners against the right view's
    /// ([`WtaMatcher::compute_checked_into`]).
    pub(super) check: bool,
}

impl Job<'_> {
    /// Where the right pixels `x − d_min − k` of left column `x` start in
    /// a reversed row.
    pub(super) fn right_start(&self, x: usize) -> usize {
        self.left.width() + self.params.min_disp - 1 - x
    }

    /// Right row `y`, border-padded and reversed (see [`reversed_rows`]).
    pub(super) fn reversed_row(&self, y: usize) -> &[u16] {
        &self.reversed[y * self.stride..(y + 1) * self.stride]
    }

    /// The right pixels `x − d_min − k`, `k = 0..lanes`, of left column
    /// `x` in row `y`, contiguous in `k`.
    pub(super) fn right_of(&self, y: usize, x: usize) -> &[u16] {
        let start = self.right_start(x);
        &self.reversed_row(y)[start..start + lanes(self.params.ndisp)]
    }
}

/// What [`WtaMatcher::compute`] finds of the right view.
pub(super) enum Right<'a> {
    None,
    /// Its map.
    Map(&'a mut DisparityMap),
    /// Only whether each left winner is its match's winner too.
    Check,
}
