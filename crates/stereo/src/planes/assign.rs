//! Plane set refinement and plane assignment (steps 4 and 5 of the four-step
//! method; AdaptingBP §2.4–2.5 use belief propagation for the latter).
//!
//! **Clustering**: segments are visited from the most to the fewest
//! reliable pixels; each joins the cluster of an adjacent segment whose
//! plane stays within `cluster_tolerance` px of its own over its bounding
//! box, or starts a cluster. Each cluster is then refitted (least squares
//! over the inliers) on the reliable pixels of all its segments.
//!
//! **Assignment**: every segment `s` takes one cluster plane `P_s`,
//! minimising `E = Σ_s D(s, P_s) + λ · Σ_(s,t) |∂(s,t)|_σ · [P_s ≠ P_t]`:
//! the data term `D` sums each pixel's census Hamming cost at the plane's
//! subpixel disparity plus `intensity` times its absolute grey difference
//! (capped at `intensity_cap`; census and intensity together, as
//! AD-Census, Mei et al. 2011, combines them), interpolated between whole
//! disparities and truncated at `truncation`, so that occluded pixels
//! cost a bounded amount whatever the plane (a match left of the right
//! view is taken at its first column, see [`DataCost::matching_with`]),
//! plus `agreement` per px of disagreement (capped at `agreement_cap`)
//! with the initial disparity where that passed the LR check;
//! the smoothness term charges `λ` per unit of boundary between two
//! segments that take different planes, each unit (a pair of
//! 4-neighbours `p`, `q`) weighed by colour contrast, `|∂(s,t)|_σ = Σ
//! exp(-|I_p - I_q|₁ / σ)`, as graph-cut segmentation (Boykov and Jolly,
//! ICCV 2001) weighs its boundary pairs: depth edges mostly follow colour
//! edges, and a cut through an even colour (a tile's, a split's, a
//! gradient's) is where planes should carry on. Chosen: greedy moves
//! (iterated conditional modes over segments, Gauss–Seidel in id order).
//! Each move gives one segment the best of its own and its neighbours'
//! planes. Group moves then let a set of segments that share a plane and
//! are joined by even colour (whom the smoothness term binds, so that no
//! one of them moves alone) take a neighbour's plane together. Moves never
//! raise `E`, so they stop. Segments without a plane of their own first
//! take the best of their neighbours' in breadth-first order from the
//! fitted ones. Cheaper than loopy BP
//! (no messages over thousands of labels) and deterministic.

use std::collections::VecDeque;

use rayon::prelude::*;
use stereolink_image::{DisparityMap, GrayImage, RgbImage};

use super::fit::{refit, samples, Sample};
use super::graph::SegmentGraph;
use super::{DisparityPlane, PlanesParams};

/// Which comparisons of the 9×7 census a matching cost counts (a smaller
/// window inside it: [`crate::census::census_mask`]), and the weight of each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct CensusPart {
    pub mask: u64,
    pub weight: f32,
}

impl CensusPart {
    /// The whole 9×7 window (`census_mask(9, 7)`), each comparison
    /// weighing 1.
    pub const FULL: CensusPart = CensusPart {
        mask: (1 << 62) - 1,
        weight: 1.0,
    };

    /// The centred `width × height` window, each comparison weighing
    /// `weight` (sides as [`crate::census::census_mask`] takes them).
    pub fn window([width, height]: [usize; 2], weight: f32) -> CensusPart {
        CensusPart {
            mask: crate::census::census_mask(width, height),
            weight,
        }
    }
}

/// The per-pixel data cost: the census Hamming distance (9×7, as SGM's) and
/// the weighted grey difference at the plane's disparity, truncated, plus
/// the disagreement with the initial map where a pixel is reliable.
pub struct DataCost<'a> {
    left: Vec<u64>,
    right: Vec<u64>,
    gray: (&'a [u8], &'a [u8]),
    reliable: &'a DisparityMap,
    width: usize,
    /// Disparities are clamped to this range before the cost is taken.
    range: (f32, f32),
    truncation: f32,
    intensity: f32,
    intensity_cap: f32,
    agreement: f32,
    agreement_cap: f32,
}

impl<'a> DataCost<'a> {
    /// The cost from the two views' census transforms, their grey views
    /// and the LR-checked initial map `reliable` (all of one size), plane
    /// disparities clamped to `range`.
    pub fn new(
        (left, right): (Vec<u64>, Vec<u64>),
        gray: (&'a GrayImage, &'a GrayImage),
        reliable: &'a DisparityMap,
        range: (f32, f32),
        params: &PlanesParams,
    ) -> Self {
        DataCost {
            left,
            right,
            gray: (gray.0.as_slice(), gray.1.as_slice()),
            reliable,
            width: reliable.width(),
            range,
            truncation: params.truncation,
            intensity: params.intensity,
            intensity_cap: params.intensity_cap,
            agreement: params.agreement,
            agreement_cap: params.agreement_cap,
        }
    }

    /// The cost of pixel `p`, in column `x`, at disparity `d`.
    fn pixel(&self, p: usize, x: usize, d: f32) -> f32 {
        let d0 = self.reliable.as_slice()[p];
        let agreement = if d0.is_finite() {
            self.agreement * (d - d0).abs().min(self.agreement_cap)
        } else {
            0.0
        };
        agreement + self.matching(p, x, d)
    }

    /// The truncated census and grey cost of pixel `p`, in column `x`, at
    /// disparity `d`, interpolated between whole disparities.
    #[inline]
    pub(crate) fn matching(&self, p: usize, x: usize, d: f32) -> f32 {
        self.matching_with(p, x, d, CensusPart::FULL)
    }

    /// [`Self::matching`] with the census Hamming distance taken over the
    /// bits of `census` only, each weighing its weight.
    ///
    /// A match left of the right view (`x < d`, the strip the right camera
    /// does not see) is taken at the view's first column, as if its border
    /// went on, as the boundary step's right-view weights take it too: it
    /// costs what a mismatch costs, whatever the plane. Charging it the
    /// truncation made planes that keep the strip in view, the farther
    /// ones, cheaper there, and a fixed charge below the truncation makes
    /// near planes cheaper instead (docs/tuning.md, “The strip the right
    /// camera does not see”).
    #[inline]
    pub(crate) fn matching_with(&self, p: usize, x: usize, d: f32, census: CensusPart) -> f32 {
        let xr = (x as f32 - d).max(0.0);
        let i = xr as usize;
        let f = xr - i as f32;
        let row = p - x;
        let (i0, i1) = (row + i, row + (i + 1).min(self.width - 1));
        let c = self.left[p];
        let hamming = |r: u64| ((c ^ r) & census.mask).count_ones() as f32 * census.weight;
        let (h0, h1) = (hamming(self.right[i0]), hamming(self.right[i1]));
        let (g0, g1) = (f32::from(self.gray.1[i0]), f32::from(self.gray.1[i1]));
        let grey = (f32::from(self.gray.0[p]) - (g0 + f * (g1 - g0))).abs();
        let cost = h0 + f * (h1 - h0) + self.intensity * grey.min(self.intensity_cap);
        cost.min(self.truncation)
    }

    /// `D(s, plane)`: the summed cost of `pixels` under `plane`.
    pub fn segment(&self, pixels: &[u32], plane: &DisparityPlane) -> f32 {
        pixels
            .iter()
            .map(|&p| {
                let p = p as usize;
                let (x, y) = (p % self.width, p / self.width);
                self.pixel(p, x, plane.pixel(x, y, self.range))
            })
            .sum()
    }
}

/// The planes after clustering and the cluster of each fitted segment.
pub struct Clusters {
    /// One refitted plane per cluster.
    pub planes: Vec<DisparityPlane>,
    /// Cluster of each segment; `None` for segments without a plane.
    pub of_segment: Vec<Option<u32>>,
}

/// Clusters the fitted planes of adjacent segments that agree and refits
/// each cluster on `disparity`'s reliable pixels.
pub fn cluster(
    graph: &SegmentGraph,
    fitted: &[Option<DisparityPlane>],
    disparity: &DisparityMap,
    params: &PlanesParams,
) -> Clusters {
    let w = disparity.width();
    let mut order: Vec<usize> = (0..graph.len()).filter(|&s| fitted[s].is_some()).collect();
    let mut reliable = vec![0usize; graph.len()];
    for &s in &order {
        let d = disparity.as_slice();
        reliable[s] = graph
            .pixels(s)
            .iter()
            .filter(|&&p| d[p as usize].is_finite())
            .count();
    }
    order.sort_by_key(|&s| std::cmp::Reverse(reliable[s]));
    let mut of_segment: Vec<Option<u32>> = vec![None; graph.len()];
    let mut seeds: Vec<DisparityPlane> = Vec::new();
    for &s in &order {
        let own = fitted[s].expect("only fitted segments are ordered");
        let corners = bounding_corners(graph.pixels(s), w);
        let agrees = |q: &DisparityPlane| {
            corners
                .iter()
                .all(|&(x, y)| (own.at(x, y) - q.at(x, y)).abs() <= params.cluster_tolerance)
        };
        let joined = graph
            .neighbours(s)
            .iter()
            .filter_map(|&(t, _)| of_segment[t as usize])
            .find(|&k| agrees(&seeds[k as usize]));
        of_segment[s] = Some(joined.unwrap_or_else(|| {
            seeds.push(own);
            seeds.len() as u32 - 1
        }));
    }
    // Refit each cluster over its segments' reliable pixels.
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); seeds.len()];
    for (s, k) in of_segment.iter().enumerate() {
        if let Some(k) = k {
            members[*k as usize].push(s);
        }
    }
    let planes = refit_members(graph, &members, &seeds, disparity, params);
    Clusters { planes, of_segment }
}

/// Each plane of `planes` refitted over the reliable pixels of the segments
/// that `label` gives it (unchanged when none does, or the refit fails).
pub fn refit_taken(
    graph: &SegmentGraph,
    label: &[u32],
    planes: &[DisparityPlane],
    disparity: &DisparityMap,
    params: &PlanesParams,
) -> Vec<DisparityPlane> {
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); planes.len()];
    for (s, &k) in label.iter().enumerate() {
        members[k as usize].push(s);
    }
    refit_members(graph, &members, planes, disparity, params)
}

/// Each plane of `planes` refitted over the reliable pixels of its
/// `members` (kept when it has at most one member, whose plane it is, or
/// the refit fails).
fn refit_members(
    graph: &SegmentGraph,
    members: &[Vec<usize>],
    planes: &[DisparityPlane],
    disparity: &DisparityMap,
    params: &PlanesParams,
) -> Vec<DisparityPlane> {
    members
        .par_iter()
        .zip(planes)
        .map(|(segs, &plane)| {
            if segs.len() <= 1 {
                return plane;
            }
            let mut all: Vec<Sample> = Vec::new();
            let mut one = Vec::new();
            for &s in segs {
                samples(disparity, graph.pixels(s), &mut one);
                all.extend_from_slice(&one);
            }
            refit(&all, plane, params.fit.inlier).unwrap_or(plane)
        })
        .collect()
}

/// The four corners of the bounding box of `pixels` (non-empty, raster order).
fn bounding_corners(pixels: &[u32], w: usize) -> [(f32, f32); 4] {
    let (y0, y1) = (
        pixels[0] as usize / w,
        pixels[pixels.len() - 1] as usize / w,
    );
    let (x0, x1) = pixels.iter().fold((usize::MAX, 0), |(lo, hi), &p| {
        let x = p as usize % w;
        (lo.min(x), hi.max(x))
    });
    let (x0, x1, y0, y1) = (x0 as f32, x1 as f32, y0 as f32, y1 as f32);
    [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
}

/// The smoothness weight of each boundary of `graph` (in the order of its
/// edges): the sum over its pairs of 4-neighbours of `exp(-Δ/contrast)`,
/// `Δ` the pair's summed absolute RGB difference in `left`.
pub fn boundary_weights(graph: &SegmentGraph, left: &RgbImage, contrast: f32) -> Vec<f32> {
    let rgb = left.as_slice();
    graph.boundary_weights(|p, q| {
        let delta: u32 = (0..3)
            .map(|c| u32::from(rgb[p][c].abs_diff(rgb[q][c])))
            .sum();
        (-(delta as f32) / contrast).exp()
    })
}

/// Data costs of a segment for the planes tried so far.
type Tried = Vec<(u32, f32)>;

/// The plane of each segment (an index into `planes`), from the clusters'
/// `initial` choice; `None` when no segment has a plane (nothing reliable).
/// `weights` are the boundaries' smoothness weights ([`boundary_weights`]).
///
/// Segments without a plane first take the best of their neighbours', in
/// breadth-first order from the fitted ones. Then sweeps of one-segment
/// moves alternate with group moves ([`PlanesParams::coupling`]) until
/// neither lowers the energy (at most `sweeps` sweeps in a row, and
/// [`GROUP_ROUNDS`] rounds of group moves).
pub fn assign(
    graph: &SegmentGraph,
    cost: &DataCost,
    planes: &[DisparityPlane],
    initial: &[Option<u32>],
    weights: &[f32],
    params: &PlanesParams,
) -> Option<Vec<u32>> {
    let mut moves = Moves {
        graph,
        cost,
        planes,
        weights,
        params,
        tried: vec![Vec::new(); graph.len()],
    };
    let mut label: Vec<Option<u32>> = initial.to_vec();
    let mut queue: VecDeque<usize> = (0..graph.len()).filter(|&s| label[s].is_some()).collect();
    if queue.is_empty() {
        return None;
    }
    while let Some(s) = queue.pop_front() {
        for &(t, _) in graph.neighbours(s) {
            let t = t as usize;
            if label[t].is_none() {
                label[t] = moves.best(t, &label);
                queue.push_back(t);
            }
        }
    }
    // The graph of a grid is connected, so the search reached every segment.
    let mut label: Vec<u32> = label.into_iter().collect::<Option<_>>()?;
    moves.sweeps(&mut label);
    for _ in 0..GROUP_ROUNDS {
        if !moves.group_moves(&mut label) {
            break;
        }
        moves.sweeps(&mut label);
    }
    Some(label)
}

/// Most rounds of group moves, each followed by sweeps of one-segment moves.
pub const GROUP_ROUNDS: usize = 3;

/// The energy's terms for the moves, with the data costs computed so far.
struct Moves<'a> {
    graph: &'a SegmentGraph,
    cost: &'a DataCost<'a>,
    planes: &'a [DisparityPlane],
    weights: &'a [f32],
    params: &'a PlanesParams,
    tried: Vec<Tried>,
}

impl Moves<'_> {
    /// `D(s, planes[k])`, computed once.
    fn data(&mut self, s: usize, k: u32) -> f32 {
        data(self.graph, self.cost, self.planes, s, k, &mut self.tried[s])
    }

    /// The best of segment `s`'s own and its neighbours' planes, given the
    /// neighbours' labels (`None` when no neighbour nor `s` has one).
    fn best(&mut self, s: usize, label: &[Option<u32>]) -> Option<u32> {
        let graph = self.graph;
        let mut candidates: Vec<u32> = label[s].into_iter().collect();
        for &(t, _) in graph.neighbours(s) {
            if let Some(k) = label[t as usize] {
                if !candidates.contains(&k) {
                    candidates.push(k);
                }
            }
        }
        let mut pick: Option<(u32, f32)> = None;
        for k in candidates {
            let cut: f32 = graph
                .neighbours(s)
                .iter()
                .zip(graph.of_segment(s, self.weights))
                .filter(|(&(t, _), _)| label[t as usize].is_some_and(|j| j != k))
                .map(|(_, &w)| w)
                .sum();
            let e = self.data(s, k) + self.params.smoothness * cut;
            if pick.is_none_or(|(_, b)| e < b) {
                pick = Some((k, e));
            }
        }
        pick.map(|(k, _)| k)
    }

    /// Sweeps of one-segment moves (iterated conditional modes, in id
    /// order) until none changes a label, at most `sweeps`.
    fn sweeps(&mut self, label: &mut [u32]) {
        let mut current: Vec<Option<u32>> = label.iter().map(|&k| Some(k)).collect();
        for _ in 0..self.params.sweeps {
            // The data costs of the current candidates, in parallel; the
            // moves below then mostly find them computed.
            let (graph, cost, planes, snapshot) = (self.graph, self.cost, self.planes, &current);
            self.tried
                .par_iter_mut()
                .enumerate()
                .for_each(|(s, tried)| {
                    let own = snapshot[s].into_iter();
                    let around = graph
                        .neighbours(s)
                        .iter()
                        .filter_map(|&(t, _)| snapshot[t as usize]);
                    for k in own.chain(around) {
                        data(graph, cost, planes, s, k, tried);
                    }
                });
            let mut changed = false;
            for s in 0..current.len() {
                let k = self.best(s, &current);
                if k != current[s] {
                    current[s] = k;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        for (l, k) in label.iter_mut().zip(current) {
            *l = k.expect("every segment keeps a label");
        }
    }

    /// One pass of group moves: each group of segments that share a plane
    /// and are joined by boundaries weighing at least `coupling` per unit
    /// ([`coupled_groups`]) takes, as a whole, the plane of a segment
    /// around it that lowers the energy most, if any does. A surface cut
    /// into several segments of one colour (tiles, splits, gradients) is
    /// held together by the smoothness term, so that one-segment moves
    /// cannot move it. True when a group moved.
    fn group_moves(&mut self, label: &mut [u32]) -> bool {
        let graph = self.graph;
        let (group, groups) = coupled_groups(graph, self.weights, label, self.params.coupling);
        let mut moved = false;
        for (g, members) in groups.iter().enumerate() {
            let from = label[members[0]];
            let outside = |t: u32| group[t as usize] != g;
            let mut candidates: Vec<u32> = Vec::new();
            for &s in members {
                for &(t, _) in graph.neighbours(s) {
                    let k = label[t as usize];
                    if outside(t) && k != from && !candidates.contains(&k) {
                        candidates.push(k);
                    }
                }
            }
            let mut pick: Option<(u32, f32)> = None;
            for k in candidates {
                let mut change = 0.0;
                for &s in members {
                    change += self.data(s, k) - self.data(s, from);
                    let around = graph
                        .neighbours(s)
                        .iter()
                        .zip(graph.of_segment(s, self.weights));
                    for (&(t, _), &w) in around.filter(|((t, _), _)| outside(*t)) {
                        let j = label[t as usize];
                        let cut = f32::from(u8::from(j != k)) - f32::from(u8::from(j != from));
                        change += self.params.smoothness * w * cut;
                    }
                }
                if change < pick.map_or(0.0, |(_, c)| c) {
                    pick = Some((k, change));
                }
            }
            if let Some((k, _)) = pick {
                members.iter().for_each(|&s| label[s] = k);
                moved = true;
            }
        }
        moved
    }
}

/// `D(s, planes[k])` from the costs `tried` so far for `s`, computing and
/// keeping it when new.
fn data(
    graph: &SegmentGraph,
    cost: &DataCost,
    planes: &[DisparityPlane],
    s: usize,
    k: u32,
    tried: &mut Tried,
) -> f32 {
    if let Some(&(_, c)) = tried.iter().find(|(j, _)| *j == k) {
        return c;
    }
    let c = cost.segment(graph.pixels(s), &planes[k as usize]);
    tried.push((k, c));
    c
}

/// The groups of segments joined, through neighbours of the same `label`,
/// by boundaries whose weight is at least `coupling` per unit of length:
/// the group of each segment and the members of each group of two or more
/// (single segments' groups are listed as `usize::MAX`).
pub fn coupled_groups(
    graph: &SegmentGraph,
    weights: &[f32],
    label: &[u32],
    coupling: f32,
) -> (Vec<usize>, Vec<Vec<usize>>) {
    let mut group = vec![usize::MAX; graph.len()];
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for s in 0..graph.len() {
        if group[s] != usize::MAX {
            continue;
        }
        let g = groups.len();
        group[s] = g;
        let mut members = vec![s];
        let mut next = 0;
        while let Some(&u) = members.get(next) {
            next += 1;
            let around = graph.neighbours(u).iter().zip(graph.of_segment(u, weights));
            for (&(t, len), &w) in around {
                let t = t as usize;
                if group[t] == usize::MAX && label[t] == label[u] && w >= coupling * len as f32 {
                    group[t] = g;
                    members.push(t);
                }
            }
        }
        if members.len() == 1 {
            group[s] = usize::MAX;
        } else {
            groups.push(members);
        }
    }
    (group, groups)
}
