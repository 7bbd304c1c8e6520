//! Segment-based stereo with disparity planes: the paper's four steps
//! (Section III), as AdaptingBP (Klaus, Sormann, Karner, ICPR 2006) runs them.
//!
//! 1. **Segments**: the 4-connected components of the caller's label map
//!    of the left view, cut by square tiles ([`PlanesParams::tile`],
//!    [`graph`]); segmenting is the caller's business, so this crate
//!    imports nothing above `image`.
//! 2. **Initial disparity**: SGM on census costs (4 paths,
//!    [`INITIAL_PATHS`]) with the subpixel fit and the left-right check;
//!    only pixels that pass the check, and whose match is not at the right
//!    view's left border, vote.
//! 3. **Plane per segment** `d = a·x + b·y + c` by slant and offset voting
//!    with a least-squares refit ([`fit`]); segments with fewer than
//!    `min_reliable` reliable pixels get no plane of their own. Segments
//!    whose plane misses many of their reliable pixels are cut by tiles of
//!    half the side and fitted again ([`PlanesParams::split`]).
//! 4. **Plane set refinement and assignment** ([`assign`]): agreeing planes
//!    of adjacent segments are clustered and refitted, then each segment
//!    takes the plane that minimises a data term (truncated census cost and
//!    agreement with the reliable initial disparities) plus a
//!    boundary-length smoothness term, each boundary pair weighed by its
//!    colour contrast ([`PlanesParams::contrast`]), by greedy moves of one
//!    segment and of groups ([`PlanesParams::coupling`]). Each plane is then
//!    refitted over all the segments that took it, and the segments are
//!    assigned again ([`PlanesParams::refits`] rounds).
//!
//! The output is dense and subpixel: each pixel takes its segment's plane,
//! clamped to the search range, and pixels next to another segment then
//! choose among the nearby segments' planes ([`boundary`]). It is also a plane table, three numbers per
//! segment ([`PlaneMap::planes`]), that [`render`] turns back into the map
//! from the same label map (the map without the boundary step). When no pixel at all passes the check (e.g. a
//! textureless pair whose check fails everywhere) no plane exists and every
//! pixel is left invalid.
//!
//! Bad input: a label map of another size than the views is a
//! [`StereoError::LabelMapSize`]; segments of one pixel, segments without a
//! reliable pixel (they borrow a neighbour's plane) and any number of
//! segments are matched like any others. Segments are components, numbered
//! `u32` whatever the labels' type, and so are pixel indices: the only cap
//! is views of fewer than 2³² pixels (else a [`StereoError::Parameter`]).
//! Memory is linear in the pixels (the segment graph keeps only adjacent
//! pairs; step 2's SGM volumes hold pixels times disparities), and so is
//! the time with tiles: a segment then has at most `tile²` pixels and as
//! many neighbours, whose planes it tries. Without tiles (`tile` 0) a
//! segment around many others with planes of their own costs their number
//! squared.

pub mod assign;
pub mod boundary;
pub mod fit;
pub mod graph;

use stereolink_image::segments::components;
use stereolink_image::{DisparityMap, LabelMap, Plane, RgbImage};

use crate::refine::{self, Refinement};
use crate::{census, sgm, Algorithm, MatchSpec, StereoError};
use graph::SegmentGraph;

/// A disparity plane `d = a·x + b·y + c` over pixel coordinates.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct DisparityPlane {
    /// Horizontal slant.
    pub a: f32,
    /// Vertical slant.
    pub b: f32,
    /// Disparity at `(0, 0)`.
    pub c: f32,
}

impl DisparityPlane {
    /// The plane's disparity at `(x, y)`.
    #[inline]
    pub fn at(&self, x: f32, y: f32) -> f32 {
        self.a * x + self.b * y + self.c
    }

    /// The disparity at pixel `(x, y)`, clamped to `range`: what the dense
    /// map holds there.
    #[inline]
    pub fn pixel(&self, x: usize, y: usize, range: (f32, f32)) -> f32 {
        self.at(x as f32, y as f32).clamp(range.0, range.1)
    }
}

/// Parameters of the plane matcher. Each default, and the figures behind
/// it, is in docs/tuning.md, “Planes”.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct PlanesParams {
    /// LR-check tolerance (px) of the initial SGM map.
    pub lr_check: f32,
    /// Side of the tiles that cut large segments (px, 0: no cut), so that an
    /// under-segmented region spanning several depths gets several planes;
    /// clustering joins the tiles' planes again where they agree.
    pub tile: usize,
    /// Fewest reliable pixels for a segment's own plane.
    pub min_reliable: usize,
    /// A segment whose own plane leaves more than this fraction of its
    /// reliable pixels off by more than `fit.inlier` is not planar (a
    /// curved or folded surface, or two surfaces), and is cut again by
    /// tiles of half the side before the planes are fitted anew (0: never).
    /// A curved surface so gets several planes (docs/tuning.md,
    /// “Splitting badly fitted segments”).
    pub split: f32,
    /// The plane fit's voting and refit tolerances.
    pub fit: fit::FitParams,
    /// Largest disagreement (px over a segment's bounding box) of planes
    /// that are clustered.
    pub cluster_tolerance: f32,
    /// Truncation of the per-pixel matching cost (census Hamming bits plus
    /// the weighted grey difference).
    pub truncation: f32,
    /// Weight of the absolute grey difference in the data term (per grey
    /// level; 0: census alone). The grey difference separates planes
    /// where census is ambiguous (low texture, fine periodic noise), as in
    /// AD-Census (docs/tuning.md, “The grey difference in the data term”).
    pub intensity: f32,
    /// Largest grey difference counted (levels).
    pub intensity_cap: f32,
    /// Weight of the data term's disagreement with a reliable initial
    /// disparity (per px of difference); docs/tuning.md, “The agreement
    /// weight: 8”.
    pub agreement: f32,
    /// Largest disagreement counted (px).
    pub agreement_cap: f32,
    /// Smoothness λ: cost per unit of boundary between segments that take
    /// different planes, where the two sides have the same colour.
    pub smoothness: f32,
    /// Colour contrast σ of the smoothness term: a pair of 4-neighbours on
    /// a boundary weighs `exp(-Δ/σ)`, with `Δ` their summed absolute RGB
    /// difference, so cutting along a colour edge costs little and cutting
    /// through an even colour (a tile's or a split's cut, a gradient) costs
    /// `λ` per pair (`inf`: every pair weighs 1, the plain boundary
    /// length). Measured pairs of σ and λ: docs/tuning.md, “The smoothness
    /// term's colour contrast”.
    pub contrast: f32,
    /// Most sweeps of greedy moves.
    pub sweeps: usize,
    /// Group moves ([`assign::coupled_groups`]): segments that share a
    /// plane and are joined by boundaries weighing at least this per unit
    /// of length (an even colour across them: see `contrast`) move
    /// together to a neighbour's plane when that lowers the energy (`inf`:
    /// no group moves). See docs/tuning.md, “Group moves”.
    pub coupling: f32,
    /// Rounds of plane refinement after the assignment, as AdaptingBP
    /// iterates its fit and assignment: each plane is refitted over the
    /// reliable pixels of all the segments that took it, and the segments
    /// are assigned again from where they were (docs/tuning.md,
    /// “Refitting rounds”).
    pub refits: usize,
    /// The per-pixel plane choice near segment boundaries ([`boundary`]),
    /// which places depth edges that the segments' edges miss. It takes
    /// most of the matcher's time (docs/tuning.md, “The per-pixel plane
    /// choice near segment boundaries”).
    pub boundary: boundary::BoundaryParams,
}

impl Default for PlanesParams {
    fn default() -> Self {
        PlanesParams {
            lr_check: 1.0,
            tile: 48,
            min_reliable: 10,
            split: 0.5,
            fit: fit::FitParams::default(),
            cluster_tolerance: 1.0,
            truncation: 24.0,
            intensity: 1.0,
            intensity_cap: 20.0,
            agreement: 8.0,
            agreement_cap: 2.0,
            smoothness: 192.0,
            contrast: 5.0,
            sweeps: 10,
            coupling: 0.1,
            refits: 2,
            boundary: boundary::BoundaryParams::default(),
        }
    }
}

impl PlanesParams {
    pub(crate) fn validate(&self) -> Result<(), StereoError> {
        let positive = [
            self.lr_check,
            self.fit.slant_bandwidth,
            self.fit.offset_bandwidth,
            self.fit.inlier,
            self.cluster_tolerance,
            self.truncation,
            self.agreement_cap,
            self.intensity_cap,
        ];
        let fraction = self.split.is_finite() && (0.0..=1.0).contains(&self.split);
        if positive.iter().any(|v| !(v.is_finite() && *v > 0.0))
            || self.contrast.is_nan()
            || self.coupling.is_nan()
            || self.coupling < 0.0
            || self.contrast <= 0.0
            || !(self.smoothness.is_finite() && self.smoothness >= 0.0)
            || !(self.agreement.is_finite() && self.agreement >= 0.0)
            || !(self.intensity.is_finite() && self.intensity >= 0.0)
            || !fraction
        {
            return Err(StereoError::Parameter(format!(
                "plane matcher tolerances must be finite and positive, contrast > 0 and coupling >= 0 (inf allowed), smoothness, agreement and intensity >= 0, split in 0..=1: {self:?}"
            )));
        }
        self.boundary.validate()
    }
}

/// The result of [`match_planes`]: the segments, their planes and the dense map.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaneMap {
    /// The segments (connected components of the label map).
    pub graph: SegmentGraph,
    /// The plane of each segment, by segment id; empty when none exists.
    pub planes: Vec<DisparityPlane>,
    /// The dense disparity map: the planes rendered, then the boundary step.
    pub disparity: DisparityMap,
}

/// Matches a pair with the plane matcher over the segments of `labels`
/// (the left view's label map), in `spec`'s disparity range with
/// `spec.planes`.
pub fn match_planes(
    left: &RgbImage,
    right: &RgbImage,
    labels: &LabelMap,
    spec: &MatchSpec,
) -> Result<PlaneMap, StereoError> {
    match_planes_with(left, right, labels, spec, &mut sgm::SgmBuffers::default())
}

/// [`match_planes`] with the SGM buffers of a [`crate::Matcher`].
pub(crate) fn match_planes_with(
    left: &RgbImage,
    right: &RgbImage,
    labels: &LabelMap,
    spec: &MatchSpec,
    buffers: &mut sgm::SgmBuffers,
) -> Result<PlaneMap, StereoError> {
    crate::check_pair(left, right)?;
    spec.validate(left.width(), left.height())?;
    spec.planes.validate()?;
    if left.len() >= u32::MAX as usize {
        return Err(StereoError::Parameter(format!(
            "the plane matcher numbers pixels in 32 bits: {}x{} views are too large",
            left.width(),
            left.height()
        )));
    }
    if labels.dims() != left.dims() {
        return Err(StereoError::LabelMapSize {
            labels: labels.dims(),
            image: left.dims(),
        });
    }
    let params = &spec.planes;
    let (gl, gr) = crate::gray_pair(left, right, spec.ripple);
    let reliable = initial_disparity(&gl, &gr, spec, buffers);
    let graph = SegmentGraph::new(labels, params.tile);
    let fitted = fit_segments(&graph, &reliable, params);
    let (graph, fitted) = match split_bent(labels, &graph, &fitted, &reliable, params) {
        Some(split) => {
            let fitted = fit_segments(&split, &reliable, params);
            (split, fitted)
        }
        None => (graph, fitted),
    };
    let clusters = assign::cluster(&graph, &fitted, &reliable, params);
    let (cl, cr) = rayon::join(|| census::census(&gl), || census::census(&gr));
    let range = (spec.min_disp as f32, spec.max_disp as f32);
    let cost = assign::DataCost::new((cl, cr), (&gl, &gr), &reliable, range, params);
    let mut set = clusters.planes;
    let weights = assign::boundary_weights(&graph, left, params.contrast);
    let mut labels = assign::assign(&graph, &cost, &set, &clusters.of_segment, &weights, params);
    for _ in 0..params.refits {
        let Some(taken) = &labels else { break };
        set = assign::refit_taken(&graph, taken, &set, &reliable, params);
        let from: Vec<Option<u32>> = taken.iter().map(|&k| Some(k)).collect();
        labels = assign::assign(&graph, &cost, &set, &from, &weights, params);
    }
    let planes: Vec<DisparityPlane> = labels
        .map(|k| k.iter().map(|&k| set[k as usize]).collect())
        .unwrap_or_default();
    let mut disparity = render(&graph.ids, &planes, range);
    boundary::refine(
        &graph.ids,
        &planes,
        &cost,
        (left, right),
        range,
        &params.boundary,
        &mut disparity,
    );
    Ok(PlaneMap {
        graph,
        planes,
        disparity,
    })
}

/// The graph with each segment of `graph` that is not planar cut by tiles
/// of half the side; `None` when no segment is cut (or `params.split` or
/// the tiles are off). A segment is not planar when its own plane leaves
/// more than the fraction `params.split` of its reliable pixels more than
/// `fit.inlier` off.
pub fn split_bent(
    labels: &LabelMap,
    graph: &SegmentGraph,
    fitted: &[Option<DisparityPlane>],
    reliable: &DisparityMap,
    params: &PlanesParams,
) -> Option<SegmentGraph> {
    if params.split <= 0.0 || params.tile < 4 {
        return None;
    }
    let mut buf = Vec::new();
    let bent: Vec<bool> = (0..graph.len())
        .map(|s| {
            let Some(plane) = fitted[s] else { return false };
            fit::samples(reliable, graph.pixels(s), &mut buf);
            let off = buf
                .iter()
                .filter(|q| (plane.at(q.x, q.y) - q.d).abs() > params.fit.inlier)
                .count();
            off as f32 > params.split * buf.len() as f32
        })
        .collect();
    if !bent.contains(&true) {
        return None;
    }
    // The half-side tiles refine the tiles, so each fine component lies in
    // one segment. Fine ids go above the segments' own, then all are
    // renumbered by first pixel in raster order.
    let (fine, fine_count) = components(labels, params.tile / 2);
    let base = graph.len();
    let mut renumber = vec![u32::MAX; base + fine_count];
    let mut count = 0u32;
    let mut ids = graph.ids.clone();
    for (id, &f) in ids.as_mut_slice().iter_mut().zip(fine.as_slice()) {
        let raw = if bent[*id as usize] {
            base + f as usize
        } else {
            *id as usize
        };
        if renumber[raw] == u32::MAX {
            renumber[raw] = count;
            count += 1;
        }
        *id = renumber[raw];
    }
    Some(SegmentGraph::from_ids(ids, count as usize))
}

/// SGM's paths for the initial map of the plane matcher (where
/// [`MatchSpec::new`] puts them; SGM alone takes 8). P1 and P2 stay
/// SGM's. Why 4 paths do better here than 8 is not established; the
/// figures are in docs/tuning.md, “4 paths for the plane matcher's initial
/// map”.
pub const INITIAL_PATHS: u8 = 4;

/// The LR-checked subpixel SGM map: finite where a pixel may vote (not
/// where its match is at the right view's left border, see
/// [`drop_border_matches`]).
pub fn initial_disparity(
    left: &stereolink_image::GrayImage,
    right: &stereolink_image::GrayImage,
    spec: &MatchSpec,
    buffers: &mut sgm::SgmBuffers,
) -> DisparityMap {
    let initial = MatchSpec {
        algorithm: Algorithm::Sgm,
        refine: Refinement {
            lr_check: Some(spec.planes.lr_check),
            subpixel: true,
            ..Refinement::NONE
        },
        ..spec.clone()
    };
    let raw = sgm::sgm(left, right, &initial, buffers);
    // No refinement step uses the guide without a weighted median.
    let no_buffers = &mut refine::RefineBuffers::default();
    let mut map = refine::postprocess(raw, &initial, &RgbImage::new(0, 0, [0; 3]), no_buffers);
    drop_border_matches(&mut map);
    map
}

/// Invalidates the pixels of `map` whose match lies in the right view's
/// first column or left of it (`x − d < 1`). SGM picks a pixel's winner
/// among the disparities that keep its match in view, so a pixel of the
/// strip the right camera does not see takes one of them, often its
/// match in the first column, and the LR check can pass it: those pixels
/// then fit planes of slope 1 (`d = x`) there. See docs/tuning.md, “The
/// strip the right camera does not see”.
fn drop_border_matches(map: &mut DisparityMap) {
    let w = map.width().max(1);
    for row in map.as_mut_slice().chunks_mut(w) {
        for (x, d) in row.iter_mut().enumerate() {
            if x as f32 - *d < 1.0 {
                *d = f32::INFINITY;
            }
        }
    }
}

/// Each segment's own plane from its reliable pixels (`None` with fewer
/// than `min_reliable`). Fallback: when no segment has that many (e.g.
/// segments of one pixel), every segment with a reliable pixel fits its own.
pub fn fit_segments(
    graph: &SegmentGraph,
    reliable: &DisparityMap,
    params: &PlanesParams,
) -> Vec<Option<DisparityPlane>> {
    let fit_all = |least: usize| -> Vec<Option<DisparityPlane>> {
        use rayon::prelude::*;
        (0..graph.len())
            .into_par_iter()
            .map_init(Vec::new, |buf, s| {
                fit::samples(reliable, graph.pixels(s), buf);
                if buf.len() < least {
                    return None;
                }
                fit::fit_plane(buf, &params.fit)
            })
            .collect()
    };
    let fitted = fit_all(params.min_reliable.max(1));
    if fitted.iter().all(Option::is_none) {
        fit_all(1)
    } else {
        fitted
    }
}

/// The dense map of `planes` (one per segment id of `ids`), clamped to
/// `range`; invalid where a segment has no plane (everywhere when `planes`
/// is empty).
pub fn render(ids: &Plane<u32>, planes: &[DisparityPlane], range: (f32, f32)) -> DisparityMap {
    let w = ids.width();
    let mut out = DisparityMap::new(w, ids.height(), f32::INFINITY);
    for (p, (&s, d)) in ids.as_slice().iter().zip(out.as_mut_slice()).enumerate() {
        if let Some(plane) = planes.get(s as usize) {
            *d = plane.pixel(p % w, p / w, range);
        }
    }
    out
}

#[cfg(test)]
mod tests;
