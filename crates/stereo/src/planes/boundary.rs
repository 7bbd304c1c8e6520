//! Per-pixel plane choice near segment boundaries (step 6's refinement).
//!
//! A segment's edge need not be the depth edge: mean shift and the tiles
//! cut across objects, and a census window straddling a depth edge
//! favours the nearer surface, so the assignment leaves bands of pixels
//! with their segment's plane where a neighbouring segment's is right.
//! Each pixel within `radius` of another segment therefore chooses among
//! the planes of the segments in its `(2·radius + 1)²` neighbourhood the one
//! with the least adaptive-support cost (Yoon and Kweon, PAMI 2006, eq. 6):
//! `Σ_q w(p, q) · c(q, P(q)) / Σ_q w(p, q)` over a `(2·window + 1)²`
//! window, with `c` the assignment's truncated census and grey cost at the
//! plane's disparity at `q`, its census narrowed to a 5×3 window
//! ([`BoundaryParams::census`]) so that it reaches less far across the
//! depth edge being placed. The weights are their symmetric ones (eq. 5
//! without the proximity term): `w = exp(−ΔC(p, q) / σ) · exp(−ΔC(p', q') /
//! σ)`, `ΔC` the summed absolute RGB difference, in the left view and
//! between the matches `p'`, `q'` that the plane gives them in the right
//! view, so that only pixels like `p` on both sides of the match (probably
//! on its surface, and not occluded) vote. Another plane must beat the
//! pixel's own by a margin ([`BoundaryParams::margin`]).
//!
//! The map then holds planes per pixel, not per segment: the plane table
//! sent over the radio carries per-segment planes, so the sender's map
//! for the table is taken without this step.

use rayon::prelude::*;
use stereolink_image::{DisparityMap, Plane, Rgb, RgbImage};

use super::assign::{CensusPart, DataCost};
use super::DisparityPlane;

/// Parameters of the boundary refinement.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct BoundaryParams {
    /// Pixels within this distance (Chebyshev, px) of another segment
    /// choose their plane; 0 turns the step off. The figures behind each
    /// default of these parameters are in docs/tuning.md, “The per-pixel
    /// plane choice near segment boundaries”.
    pub radius: usize,
    /// Half side of the support window (px). A wider window gathers more
    /// like-coloured support, at a cost that grows with its area.
    pub window: usize,
    /// Colour scale σ of the support weights (summed absolute RGB
    /// difference), in both views (see the module doc).
    pub sigma: f32,
    /// Another plane replaces the pixel's own only when its cost is lower
    /// by more than this fraction of the own plane's: where colour does
    /// not follow depth the weights cannot tell the surfaces apart, and
    /// close costs are noise.
    pub margin: f32,
    /// A neighbouring plane is tried only when it puts the pixel more
    /// than this many px from every plane already tried (its own first):
    /// planes that nearly agree there choose alike, and skipping them
    /// saves time.
    pub distinct: f32,
    /// Width and height (odd, at most the census's 9×7) of the census
    /// window of the step's matching cost, and [`Self::census_weight`] the
    /// weight of each of its comparisons. A pixel near a depth edge has
    /// the other surface in its census window, which pulls it to that
    /// surface's disparity: the assignment's 9×7 census reaches 4 px, a
    /// 5×3 window 2 px. The weight keeps the census's share of the cost
    /// (14 comparisons instead of 62, against the grey difference and the
    /// truncation at 24); lighter census weights lose on the occluded
    /// pixels. Over a whole segment the wider census is worth more, so
    /// the assignment keeps its 9×7. Measured windows and weights:
    /// docs/tuning.md, “The boundary step's census: 5×3, weight 4”.
    pub census: [usize; 2],
    /// Weight of each census comparison in the step's cost (see
    /// [`Self::census`]).
    pub census_weight: f32,
}

impl Default for BoundaryParams {
    fn default() -> Self {
        BoundaryParams {
            radius: 5,
            window: 8,
            sigma: 30.0,
            margin: 0.1,
            distinct: 0.5,
            census: [5, 3],
            census_weight: 4.0,
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
            || !(self.distinct.is_finite() && self.distinct >= 0.0)
        {
            return Err(crate::StereoError::Parameter(format!(
                "plane boundary radius and window must be at most {}, sigma finite and positive, margin in 0..1, distinct finite and >= 0: {self:?}",
                Self::MAX_SIDE
            )));
        }
        let [cw, ch] = self.census;
        if cw % 2 == 0 || cw > 9 || ch % 2 == 0 || ch > 7 {
            return Err(crate::StereoError::Parameter(format!(
                "plane boundary census window {cw}x{ch} must have odd sides of at most 9x7"
            )));
        }
        if !(self.census_weight.is_finite() && self.census_weight >= 0.0) {
            return Err(crate::StereoError::Parameter(format!(
                "plane boundary census weight {} must be finite and >= 0",
                self.census_weight
            )));
        }
        Ok(())
    }
}

/// Re-chooses the plane of every pixel near a segment boundary in
/// `disparity` (the rendering of `planes` over `ids`, clamped to `range`);
/// `views` are the left and right colour views.
pub fn refine(
    ids: &Plane<u32>,
    planes: &[DisparityPlane],
    cost: &DataCost,
    views: (&RgbImage, &RgbImage),
    range: (f32, f32),
    params: &BoundaryParams,
    disparity: &mut DisparityMap,
) {
    if params.radius == 0 || planes.is_empty() {
        return;
    }
    let (w, h) = ids.dims();
    let support = Support {
        // Indexed by the summed absolute RGB difference (0..=765).
        weight: (0..=3 * 255)
            .map(|d| (-(d as f32) / params.sigma).exp())
            .collect(),
        left: views.0.as_slice(),
        right: views.1.as_slice(),
        cost,
        census: CensusPart::window(params.census, params.census_weight),
        width: w,
        range,
    };
    let (r, win) = (params.radius, params.window);
    let side = 2 * win + 1;
    let id = ids.as_slice();
    disparity
        .as_mut_slice()
        .par_chunks_mut(w)
        .enumerate()
        .for_each_init(Scratch::default, |scratch, (y, row)| {
            let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
            let rows = y.saturating_sub(win)..=(y + win).min(h - 1);
            scratch.row.start(planes.len(), y);
            for (x, out) in row.iter_mut().enumerate() {
                let own_id = id[y * w + x];
                let Some(own) = planes.get(own_id as usize) else {
                    continue;
                };
                // The planes around p that put p more than `distinct` px
                // from those already taken (adjacent segments often share
                // a cluster's plane: then there is nothing to choose).
                let candidates = &mut scratch.candidates;
                candidates.clear();
                candidates.push((own_id, own.pixel(x, y, range)));
                let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                for yy in y0..=y1 {
                    let mut last = u32::MAX;
                    for &s in &id[yy * w + x0..=yy * w + x1] {
                        if s == last {
                            continue;
                        }
                        last = s;
                        if let Some(plane) = planes.get(s as usize) {
                            let d = plane.pixel(x, y, range);
                            if candidates.iter().all(|c| (c.1 - d).abs() > params.distinct) {
                                candidates.push((s, d));
                            }
                        }
                    }
                }
                if candidates.len() < 2 {
                    continue;
                }
                let columns = x.saturating_sub(win)..=(x + win).min(w - 1);
                let window = (rows.clone(), columns);
                support.window(x, y, window.clone(), side, &mut scratch.window);
                let mut best: Option<(f32, u32)> = None;
                for i in 0..scratch.candidates.len() {
                    let s = scratch.candidates[i].0;
                    let costs = scratch.row.of(s, side);
                    support.fill(&planes[s as usize], window.clone(), side, costs);
                    let c = support.cost(x, y, window.clone(), side, costs, &scratch.window);
                    // The own plane (first) wins unless beaten by the margin.
                    let c = if i == 0 { c * (1.0 - params.margin) } else { c };
                    if best.is_none_or(|(b, _)| c < b) {
                        best = Some((c, s));
                    }
                }
                if let Some((_, s)) = best {
                    *out = planes[s as usize].pixel(x, y, range);
                }
            }
        });
}

/// A pixel of the support window: where its plane's cost is in a
/// [`PlaneCosts`] (`column slot · side + row`), and its left-view weight
/// (which does not depend on the plane).
struct Sample {
    at: usize,
    weight: f32,
}

/// One plane's matching cost and right-view match for the window rows of
/// the current image row, over the last `side` columns asked for: column
/// `qx` is in slot `qx % side`, and the pixels of a row reuse the columns
/// their windows share.
#[derive(Default)]
struct PlaneCosts {
    /// The column in each slot (`usize::MAX`: none yet).
    columns: Vec<usize>,
    /// `(cost, right view's colour)` by `slot · side + row in the window`.
    values: Vec<(f32, Rgb)>,
}

/// A worker's buffers: the candidate segments of a pixel (with the
/// pixel's disparity under each plane), its window's samples, and the
/// plane costs of the current row.
#[derive(Default)]
struct Scratch {
    candidates: Vec<(u32, f32)>,
    window: Vec<Sample>,
    row: RowCosts,
}

/// The [`PlaneCosts`] of the segments' planes in the current row.
#[derive(Default)]
struct RowCosts {
    /// The row and index into `costs` of each segment's plane, when taken.
    of_segment: Vec<(usize, usize)>,
    costs: Vec<PlaneCosts>,
    used: usize,
    row: usize,
}

impl RowCosts {
    /// Forgets the costs of the previous row.
    fn start(&mut self, segments: usize, y: usize) {
        self.of_segment.resize(segments, (usize::MAX, 0));
        self.row = y;
        self.used = 0;
    }

    /// The costs of segment `s`'s plane in the current row.
    fn of(&mut self, s: u32, side: usize) -> &mut PlaneCosts {
        let entry = &mut self.of_segment[s as usize];
        if entry.0 != self.row {
            *entry = (self.row, self.used);
            if self.used == self.costs.len() {
                self.costs.push(PlaneCosts::default());
            }
            let c = &mut self.costs[self.used];
            c.columns.clear();
            c.columns.resize(side, usize::MAX);
            c.values.resize(side * side, (0.0, [0; 3]));
            self.used += 1;
        }
        &mut self.costs[entry.1]
    }
}

type Window = (
    std::ops::RangeInclusive<usize>,
    std::ops::RangeInclusive<usize>,
);

/// The adaptive-support cost of a plane at a pixel.
struct Support<'a> {
    weight: Vec<f32>,
    left: &'a [Rgb],
    right: &'a [Rgb],
    cost: &'a DataCost<'a>,
    /// The part of the census that the step's matching cost counts.
    census: CensusPart,
    width: usize,
    range: (f32, f32),
}

impl Support<'_> {
    /// `exp(−ΔC / σ)` for the summed absolute RGB difference ΔC.
    #[inline]
    fn similarity(&self, a: Rgb, b: Rgb) -> f32 {
        let diff = |i: usize| usize::from(a[i].abs_diff(b[i]));
        self.weight[diff(0) + diff(1) + diff(2)]
    }

    /// The step's matching cost of pixel `q`, in column `qx`, at `d`.
    #[inline]
    fn matching(&self, q: usize, qx: usize, d: f32) -> f32 {
        self.cost.matching_with(q, qx, d, self.census)
    }

    /// The samples of `(x, y)`'s window, in raster order.
    fn window(
        &self,
        x: usize,
        y: usize,
        (rows, columns): Window,
        side: usize,
        out: &mut Vec<Sample>,
    ) {
        let colour = self.left[y * self.width + x];
        out.clear();
        for (i, qy) in rows.enumerate() {
            // Column qx's slot is qx % side, stepped rather than divided.
            let mut slot = columns.start() % side;
            for qx in columns.clone() {
                out.push(Sample {
                    at: slot * side + i,
                    weight: self.similarity(colour, self.left[qy * self.width + qx]),
                });
                slot = if slot + 1 == side { 0 } else { slot + 1 };
            }
        }
    }

    /// Computes the columns of `window` that `costs` lacks for `plane`: the
    /// truncated matching cost at the plane's disparity, and the right
    /// view's pixel it matches (the first column when the match falls
    /// outside).
    fn fill(
        &self,
        plane: &DisparityPlane,
        (rows, columns): Window,
        side: usize,
        costs: &mut PlaneCosts,
    ) {
        for qx in columns {
            let slot = qx % side;
            if costs.columns[slot] == qx {
                continue;
            }
            costs.columns[slot] = qx;
            for (i, qy) in rows.clone().enumerate() {
                let q = qy * self.width + qx;
                let d = plane
                    .at(qx as f32, qy as f32)
                    .clamp(self.range.0, self.range.1);
                let matched = self.right[q - qx + (qx as f32 - d + 0.5).max(0.0) as usize];
                costs.values[slot * side + i] = (self.matching(q, qx, d), matched);
            }
        }
    }

    /// `Σ_q w(p, q) · c(q, P(q)) / Σ_q w(p, q)` at `(x, y)` over `window`,
    /// from the plane's `costs`.
    fn cost(
        &self,
        x: usize,
        y: usize,
        (rows, _): Window,
        side: usize,
        costs: &PlaneCosts,
        window: &[Sample],
    ) -> f32 {
        let centre = costs.values[x % side * side + (y - rows.start())].1;
        let (mut total, mut norm) = (0.0, 0.0);
        for s in window {
            let (c, matched) = costs.values[s.at];
            let w = s.weight * self.similarity(centre, matched);
            total += w * c;
            norm += w;
        }
        // The centre's own weight is 1, so `norm` >= 1.
        total / norm
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planes::PlanesParams;
    use stereolink_image::color::rgb_to_gray;

    /// The cost by its definition, without the row's cache.
    fn direct(
        support: &Support,
        plane: &DisparityPlane,
        (x, y): (usize, usize),
        win: usize,
        h: usize,
    ) -> f32 {
        let (w, range) = (support.width, support.range);
        let at = |qx: usize, qy: usize| plane.at(qx as f32, qy as f32).clamp(range.0, range.1);
        let matched = |qx: usize, qy: usize| {
            support.right[qy * w + (qx as f32 - at(qx, qy) + 0.5).max(0.0) as usize]
        };
        let (colour, centre) = (support.left[y * w + x], matched(x, y));
        let (mut total, mut norm) = (0.0, 0.0);
        for qy in y.saturating_sub(win)..=(y + win).min(h - 1) {
            for qx in x.saturating_sub(win)..=(x + win).min(w - 1) {
                let q = qy * w + qx;
                let wq = support.similarity(colour, support.left[q])
                    * support.similarity(centre, matched(qx, qy));
                total += wq * support.matching(q, qx, at(qx, qy));
                norm += wq;
            }
        }
        total / norm
    }

    #[test]
    fn the_row_cache_gives_the_costs_of_the_definition() {
        let (w, h, win) = (37, 23, 3);
        let mut seed = 7u64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        // Colours close enough that every sample of a window weighs.
        let mut view =
            || RgbImage::from_fn(w, h, |_, _| [0u8; 3].map(|_| 100 + (next() % 24) as u8));
        let (left, right) = (view(), view());
        let (gl, gr) = (rgb_to_gray(&left), rgb_to_gray(&right));
        let reliable = DisparityMap::new(w, h, f32::INFINITY);
        let range = (0.0, 9.0);
        let census = (crate::census::census(&gl), crate::census::census(&gr));
        let cost = DataCost::new(
            census,
            (&gl, &gr),
            &reliable,
            range,
            &PlanesParams::default(),
        );
        let support = Support {
            weight: (0..=765).map(|d| (-(d as f32) / 30.0).exp()).collect(),
            left: left.as_slice(),
            right: right.as_slice(),
            cost: &cost,
            census: CensusPart::window([5, 3], 3.0),
            width: w,
            range,
        };
        let planes = [
            DisparityPlane {
                a: 0.1,
                b: -0.05,
                c: 3.3,
            },
            DisparityPlane {
                a: -0.2,
                b: 0.0,
                c: 8.0,
            },
            DisparityPlane {
                a: 0.0,
                b: 0.3,
                c: 1.0,
            },
        ];
        let side = 2 * win + 1;
        let mut scratch = Scratch::default();
        for y in 0..h {
            let rows = y.saturating_sub(win)..=(y + win).min(h - 1);
            scratch.row.start(planes.len(), y);
            // Planes asked for in a changing order, some pixels skipped.
            for x in (0..w).filter(|x| (x + y) % 5 != 0) {
                let window = (rows.clone(), x.saturating_sub(win)..=(x + win).min(w - 1));
                support.window(x, y, window.clone(), side, &mut scratch.window);
                // Plane 2 only around x = 15, in every row: its columns
                // of the row above must not be taken for this row's.
                let near = (15..17).contains(&x);
                for k in [(x + y) % 2, 1 - (x + y) % 2, 2]
                    .into_iter()
                    .filter(|&k| k < 2 || near)
                {
                    let costs = scratch.row.of(k as u32, side);
                    support.fill(&planes[k], window.clone(), side, costs);
                    let cached = support.cost(x, y, window.clone(), side, costs, &scratch.window);
                    let want = direct(&support, &planes[k], (x, y), win, h);
                    assert_eq!(cached, want, "({x}, {y}) plane {k}");
                }
            }
        }
    }
}
