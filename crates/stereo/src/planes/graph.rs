//! Segments as a graph: the 4-connected components of a label map, each
//! with its pixels, and the adjacency of components with the length of
//! their shared boundary (the smoothness term's weight).
//!
//! Components, not labels, are the segments: a colour class of k-means or
//! of the thresholding methods spans many disconnected regions of different
//! depth. Ids follow the raster order of each component's first pixel, so
//! a receiver that decodes the same label map numbers them the same way.

use std::collections::HashMap;

use stereolink_image::segments::components;
use stereolink_image::{LabelMap, Plane};

/// The segments of a label map and their adjacency.
#[derive(Clone, Debug, PartialEq)]
pub struct SegmentGraph {
    /// Component id per pixel.
    pub ids: Plane<u32>,
    /// Pixels of segment `s`: `pixels[offsets[s]..offsets[s + 1]]`, raster order.
    offsets: Vec<usize>,
    pixels: Vec<u32>,
    /// Neighbours of `s` with the shared boundary length:
    /// `edges[edge_offsets[s]..edge_offsets[s + 1]]`.
    edge_offsets: Vec<usize>,
    edges: Vec<(u32, u32)>,
}

impl SegmentGraph {
    /// The graph of the connected components of `labels` cut into tiles of
    /// side `tile` ([`components`]).
    pub fn new(labels: &LabelMap, tile: usize) -> Self {
        let (ids, count) = components(labels, tile);
        Self::from_ids(ids, count)
    }

    /// The graph of segments given by id per pixel (`0..count`, each
    /// segment 4-connected, ids in raster order of first pixels).
    pub fn from_ids(ids: Plane<u32>, count: usize) -> Self {
        let (w, h) = ids.dims();
        let id = ids.as_slice();
        // Pixel lists by counting sort: raster order within each segment.
        let mut offsets = vec![0usize; count + 1];
        for &s in id {
            offsets[s as usize + 1] += 1;
        }
        for s in 0..count {
            offsets[s + 1] += offsets[s];
        }
        let mut next = offsets.clone();
        let mut pixels = vec![0u32; id.len()];
        for (p, &s) in id.iter().enumerate() {
            pixels[next[s as usize]] = p as u32;
            next[s as usize] += 1;
        }
        // Boundary lengths: one unit per pair of 4-neighbours in two segments.
        let mut lengths: HashMap<(u32, u32), u32> = HashMap::new();
        let mut add = |a: u32, b: u32| {
            if a != b {
                *lengths.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        };
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                if x + 1 < w {
                    add(id[p], id[p + 1]);
                }
                if y + 1 < h {
                    add(id[p], id[p + w]);
                }
            }
        }
        let mut pairs: Vec<((u32, u32), u32)> = lengths.into_iter().collect();
        pairs.sort_unstable();
        let mut edge_offsets = vec![0usize; count + 1];
        for &((a, b), _) in &pairs {
            edge_offsets[a as usize + 1] += 1;
            edge_offsets[b as usize + 1] += 1;
        }
        for s in 0..count {
            edge_offsets[s + 1] += edge_offsets[s];
        }
        let mut next = edge_offsets.clone();
        let mut edges = vec![(0u32, 0u32); edge_offsets[count]];
        for &((a, b), len) in &pairs {
            edges[next[a as usize]] = (b, len);
            next[a as usize] += 1;
            edges[next[b as usize]] = (a, len);
            next[b as usize] += 1;
        }
        SegmentGraph {
            ids,
            offsets,
            pixels,
            edge_offsets,
            edges,
        }
    }

    /// Number of segments.
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// True when the map has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The pixel indices (`y · width + x`) of segment `s`, in raster order.
    pub fn pixels(&self, s: usize) -> &[u32] {
        &self.pixels[self.offsets[s]..self.offsets[s + 1]]
    }

    /// The neighbours of segment `s` and the length of each shared boundary.
    pub fn neighbours(&self, s: usize) -> &[(u32, u32)] {
        &self.edges[self.edge_offsets[s]..self.edge_offsets[s + 1]]
    }

    /// For each shared boundary, the sum of `weight(p, q)` over its pairs of
    /// 4-neighbours `p`, `q` (pixel indices), in the order of the edges: read
    /// a segment's with [`SegmentGraph::of_segment`].
    pub fn boundary_weights(&self, weight: impl Fn(usize, usize) -> f32) -> Vec<f32> {
        let (w, h) = self.ids.dims();
        let id = self.ids.as_slice();
        let mut out = vec![0.0f32; self.edges.len()];
        let mut add = |p: usize, q: usize| {
            let (a, b) = (id[p], id[q]);
            if a == b {
                return;
            }
            let v = weight(p, q);
            for (s, t) in [(a, b), (b, a)] {
                let list = self.neighbours(s as usize);
                let i = list.partition_point(|&(u, _)| u < t);
                out[self.edge_offsets[s as usize] + i] += v;
            }
        };
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                if x + 1 < w {
                    add(p, p + 1);
                }
                if y + 1 < h {
                    add(p, p + w);
                }
            }
        }
        out
    }

    /// Segment `s`'s part of a per-edge vector such as [`SegmentGraph::boundary_weights`]'s.
    pub fn of_segment<'a, T>(&self, s: usize, per_edge: &'a [T]) -> &'a [T] {
        &per_edge[self.edge_offsets[s]..self.edge_offsets[s + 1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disconnected_regions_of_one_label_are_separate_segments() {
        // 0 0 1 0
        // 1 1 1 0
        let labels = LabelMap::from_vec(4, 2, vec![0, 0, 1, 0, 1, 1, 1, 0]).unwrap();
        let g = SegmentGraph::new(&labels, 0);
        assert_eq!(g.len(), 3);
        assert_eq!(g.ids.as_slice(), &[0, 0, 1, 2, 1, 1, 1, 2]);
        assert_eq!(g.pixels(1), &[2, 4, 5, 6]);
        // Segment 0 touches segment 1 along x = 1..2 (down) and at (1, 0)–(2, 0).
        assert_eq!(g.neighbours(0), &[(1, 3)]);
        assert_eq!(g.neighbours(1), &[(0, 3), (2, 2)]);
        assert_eq!(g.neighbours(2), &[(1, 2)]);
    }

    #[test]
    fn boundary_weights_sum_each_pair_of_a_boundary() {
        // 0 0 1 2
        // 1 1 1 2   (the ids of the map above)
        let labels = LabelMap::from_vec(4, 2, vec![0, 0, 1, 0, 1, 1, 1, 0]).unwrap();
        let g = SegmentGraph::new(&labels, 0);
        let ones = g.boundary_weights(|_, _| 1.0);
        for s in 0..g.len() {
            let lengths: Vec<f32> = g.neighbours(s).iter().map(|&(_, n)| n as f32).collect();
            assert_eq!(g.of_segment(s, &ones), lengths.as_slice());
        }
        // 0–1: pairs (1, 2), (0, 4), (1, 5); 1–2: pairs (2, 3), (6, 7).
        let w = g.boundary_weights(|p, q| (10 * p + q) as f32);
        assert_eq!(g.of_segment(0, &w), &[12.0 + 4.0 + 15.0]);
        assert_eq!(g.of_segment(1, &w), &[31.0, 23.0 + 67.0]);
        assert_eq!(g.of_segment(2, &w), &[90.0]);
    }

    #[test]
    fn one_pixel_segments_and_empty_maps() {
        let labels = LabelMap::from_fn(5, 3, |x, y| (x + 5 * y) as u16);
        let g = SegmentGraph::new(&labels, 0);
        assert_eq!(g.len(), 15);
        assert!((0..15).all(|s| g.pixels(s) == [s as u32]));
        assert_eq!(g.neighbours(6).len(), 4);
        let g = SegmentGraph::new(&LabelMap::new(0, 0, 0), 0);
        assert!(g.is_empty());
    }

    #[test]
    fn tiles_cut_large_segments() {
        let labels = LabelMap::new(10, 6, 7);
        let g = SegmentGraph::new(&labels, 4);
        // Tiles of 4×4: three columns by two rows.
        assert_eq!(g.len(), 6);
        assert_eq!(g.ids.get(9, 5), 5);
        assert_eq!(g.pixels(2).len(), 2 * 4);
        assert_eq!(g.neighbours(0), &[(1, 4), (3, 4)]);
    }
}
