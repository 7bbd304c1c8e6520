//! From a pixel's cost lanes to its disparity: the uniqueness test, the
//! subpixel fit, the `f32` or integer output, and the left-right check done
//! in the pass. Shared by every band loop, so that all give the same
//! disparities.

use super::{WtaParams, NO_DISPARITY};

/// A left pixel's winner, for the check of
/// [`WtaMatcher::compute_checked_into`](super::WtaMatcher::compute_checked_into).
#[derive(Clone, Copy, Default)]
pub(super) struct Winner {
    /// Its lane and cost.
    pub(super) lane: u16,
    pub(super) cost: u16,
    /// Whether every earlier lane of its right pixel cost more.
    pub(super) first: bool,
}

/// The check of
/// [`WtaMatcher::compute_checked_into`](super::WtaMatcher::compute_checked_into)
/// on a row's `winners`, given the smallest cost of each right pixel `xr` at
/// `right_best[W − 1 − xr]`: a left pixel keeps its disparity if its
/// winner is its right pixel's first smallest cost. Pixels below `min_disp`
/// have no winner (and no disparity).
pub(super) fn check_row<T: Disparity>(
    out: &mut [T],
    winners: &[Winner],
    right_best: &[u16],
    min_disp: usize,
) {
    let w = out.len();
    for (x, d) in out.iter_mut().enumerate().skip(min_disp) {
        let Winner { lane, cost, first } = winners[x];
        let at = w - 1 - (x - min_disp) + lane as usize;
        if !(first && right_best[at] == cost) {
            *d = T::NONE;
        }
    }
}

/// A disparity as a band writes it: `f32` (with the subpixel fit) or an
/// integer level.
pub(super) trait Disparity: Copy + Send + Sync {
    /// A pixel without a disparity.
    const NONE: Self;
    /// The winning disparity among the first `valid` of `costs`, given the
    /// index `k` of their smallest cost and that cost (index `k` is
    /// disparity `d_min + k`), after the uniqueness test.
    fn winner(costs: &[u16], valid: usize, best: (usize, u16), p: &WtaParams) -> Self;
    /// The disparity of index `k`: [`Self::winner`] when `p` asks for
    /// neither the uniqueness test nor the subpixel fit, which then need
    /// no costs ([`plain`]).
    fn at(k: usize, p: &WtaParams) -> Self;
}

/// Whether `p` picks a winner from its index alone ([`Disparity::at`]);
/// only the AVX2 band asks.
#[cfg(target_arch = "x86_64")]
pub(super) fn plain(p: &WtaParams) -> bool {
    p.uniqueness == 0 && !p.subpixel
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
        let mut d = Self::at(k, p);
        if p.subpixel && k > 0 && k + 1 < costs.len() {
            d += crate::refine::parabola(costs[k - 1] as f32, best as f32, costs[k + 1] as f32);
        }
        d
    }

    #[inline(always)]
    fn at(k: usize, p: &WtaParams) -> f32 {
        (p.min_disp + k) as f32
    }
}

impl Disparity for u16 {
    const NONE: u16 = NO_DISPARITY;

    #[inline(always)]
    fn winner(costs: &[u16], valid: usize, (k, best): (usize, u16), p: &WtaParams) -> u16 {
        if ambiguous(&costs[..valid], (k, best), p) {
            NO_DISPARITY
        } else {
            Self::at(k, p)
        }
    }

    #[inline(always)]
    fn at(k: usize, p: &WtaParams) -> u16 {
        (p.min_disp + k) as u16
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
