//! Per-pixel plane choice near segment boundaries (step 6's refinement).
//!
//! A segment's edge need not be the depth edge: mean shift and the tiles
//! cut across objects, and a census window straddling a depth edge
//! favours the nearer surface, so the assignment leaves bands of pixels
//! with their segment's plane where a neighbouring segment's is right.
//! Each pixel within `radius` of another segment therefore chooses among
//! the planes of the segments in its `(2·radius + 1)²` neighbourhood the one
//! with the least adaptive-support cost (Yoon and Kweon, PAMI 2006):
//! `Σ_q w(p, q) · c(q, P(q))` over a `(2·window + 1)²` window, with
//! `w = exp(−|I_p − I_q| / σ)` on the grey view, so that only pixels like
//! `p` (probably on its surface) vote, and `c` the assignment's truncated
//! census and grey cost at the plane's disparity at `q`. Another plane
//! must beat the pixel's own by a margin ([`BoundaryParams::margin`]).
//!
//! The map then holds planes per pixel, not per segment: the plane table
//! sent over the radio carries per-segment planes, so the sender's map
//! for the table is taken without this step.

use rayon::prelude::*;
use stereolink_image::{DisparityMap, Plane};

use super::assign::DataCost;
use super::DisparityPlane;

/// Parameters of the boundary refinement.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct BoundaryParams {
    /// Pixels within this distance (Chebyshev, px) of another segment
    /// choose their plane; 0 turns the step off.
    pub radius: usize,
    /// Half side of the support window (px).
    pub window: usize,
    /// Grey-level scale σ of the support weights.
    pub sigma: f32,
    /// Another plane replaces the pixel's own only when its cost is lower
    /// by more than this fraction of the own plane's. Where colour does
    /// not follow depth the weights cannot tell the surfaces apart, and
    /// close costs are noise: on the built-in synthetic scene (`synth
    /// --seed 5`, 160×120) planes give 0.74 / 0.64 / 0.54 / 0.38 % bad
    /// pixels (over 1 px) with margins 0 / 0.05 / 0.1 / 0.2 (0.09 without
    /// the step), and the 20 shared scenes 10.40 / 10.38 / 10.41 / 10.49 %.
    pub margin: f32,
}

impl Default for BoundaryParams {
    fn default() -> Self {
        BoundaryParams {
            radius: 1,
            window: 5,
            sigma: 10.0,
            margin: 0.2,
        }
    }
}

impl BoundaryParams {
    /// Largest `radius` and `window` accepted: beyond them the step's cost
    /// (`(2·radius + 1)²` neighbours, `(2·window + 1)²` samples per
    /// candidate) grows without measured gain.
    pub const MAX_SIDE: usize = 8;

    pub(crate) fn validate(&self) -> Result<(), crate::StereoError> {
        if self.radius > Self::MAX_SIDE
            || self.window > Self::MAX_SIDE
            || !(self.sigma.is_finite() && self.sigma > 0.0)
            || !(0.0..1.0).contains(&self.margin)
        {
            return Err(crate::StereoError::Parameter(format!(
                "plane boundary radius and window must be at most {}, sigma finite and positive, margin in 0..1: {self:?}",
                Self::MAX_SIDE
            )));
        }
        Ok(())
    }
}

/// Re-chooses the plane of every pixel near a segment boundary in
/// `disparity` (the rendering of `planes` over `ids`, clamped to `range`).
pub fn refine(
    ids: &Plane<u32>,
    planes: &[DisparityPlane],
    cost: &DataCost,
    gray: &[u8],
    range: (f32, f32),
    params: &BoundaryParams,
    disparity: &mut DisparityMap,
) {
    if params.radius == 0 || planes.is_empty() {
        return;
    }
    let (w, h) = ids.dims();
    let weight: Vec<f32> = (0..256)
        .map(|d| (-(d as f32) / params.sigma).exp())
        .collect();
    let (r, win) = (params.radius, params.window);
    let id = ids.as_slice();
    disparity
        .as_mut_slice()
        .par_chunks_mut(w)
        .enumerate()
        .for_each_init(
            Vec::new,
            |candidates: &mut Vec<DisparityPlane>, (y, row)| {
                let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
                for (x, out) in row.iter_mut().enumerate() {
                    let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                    // The distinct planes around p (adjacent segments often
                    // share a cluster's plane: then there is nothing to choose).
                    candidates.clear();
                    for yy in y0..=y1 {
                        for &s in &id[yy * w + x0..=yy * w + x1] {
                            if let Some(plane) = planes.get(s as usize) {
                                if !candidates.contains(plane) {
                                    candidates.push(*plane);
                                }
                            }
                        }
                    }
                    if candidates.len() < 2 {
                        continue;
                    }
                    let g = gray[y * w + x];
                    let support = |plane: &DisparityPlane| -> f32 {
                        let mut total = 0.0;
                        for qy in y.saturating_sub(win)..=(y + win).min(h - 1) {
                            for qx in x.saturating_sub(win)..=(x + win).min(w - 1) {
                                let q = qy * w + qx;
                                let wq = weight[usize::from(g.abs_diff(gray[q]))];
                                total += wq * cost.matching(q, plane.pixel(qx, qy, range));
                            }
                        }
                        total
                    };
                    let Some(own) = planes.get(id[y * w + x] as usize) else {
                        continue;
                    };
                    let mut best: (f32, &DisparityPlane) =
                        (support(own) * (1.0 - params.margin), own);
                    for plane in candidates.iter() {
                        if plane == own {
                            continue;
                        }
                        let c = support(plane);
                        if c < best.0 {
                            best = (c, plane);
                        }
                    }
                    *out = best.1.pixel(x, y, range);
                }
            },
        );
}
