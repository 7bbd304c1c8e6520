//! The segments of a label map: its 4-connected components, optionally cut
//! by square tiles, numbered in the raster order of their first pixels.
//!
//! Components, not labels, are the segments of segment-based stereo: a
//! colour class of k-means or of the thresholding methods spans many
//! disconnected regions of different depth. The numbering depends on the
//! labels alone, so a receiver that decodes the same label map numbers the
//! segments the same way as the sender (the plane table relies on it), and
//! a pixel's upper and left neighbours lie in segments numbered no higher
//! than its own.
//!
//! Ids are `u32` whatever the labels' type, so a map may have as many
//! segments as pixels (a `u16` label map of noise has far more components
//! than labels); maps of 2³² pixels or more are beyond them.

use crate::{LabelMap, Plane};

/// The 4-connected components of `labels` within the tiles of side `tile`
/// (0: no tiles): an id per pixel, in raster order of the components'
/// first pixels, and the number of components.
pub fn components(labels: &LabelMap, tile: usize) -> (Plane<u32>, usize) {
    let (w, h) = labels.dims();
    // Whether column (row) i joins column (row) i − 1: not across a tile edge.
    let joins = |n: usize| -> Vec<bool> { (0..n).map(|i| tile == 0 || i % tile != 0).collect() };
    let (join_x, join_y) = (joins(w), joins(h));
    let labels = labels.as_slice();
    let mut ids = Plane::new(w, h, u32::MAX);
    let id = ids.as_mut_slice();
    let mut count = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if id[start] != u32::MAX {
            continue;
        }
        let label = labels[start];
        id[start] = count;
        stack.push(start);
        while let Some(p) = stack.pop() {
            let y = p / w;
            let x = p - y * w;
            let mut visit = |q: usize| {
                if id[q] == u32::MAX && labels[q] == label {
                    id[q] = count;
                    stack.push(q);
                }
            };
            if x > 0 && join_x[x] {
                visit(p - 1);
            }
            if x + 1 < w && join_x[x + 1] {
                visit(p + 1);
            }
            if y > 0 && join_y[y] {
                visit(p - w);
            }
            if y + 1 < h && join_y[y + 1] {
                visit(p + w);
            }
        }
        count += 1;
    }
    (ids, count as usize)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Union-find over 4-neighbours of one label within one tile: the
    /// number of components, by an independent route.
    fn count_by_union_find(labels: &LabelMap, tile: usize) -> usize {
        let (w, h) = labels.dims();
        let mut parent: Vec<usize> = (0..w * h).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        let same_tile = |p: usize, q: usize| {
            tile == 0 || (p % w / tile, p / w / tile) == (q % w / tile, q / w / tile)
        };
        for p in 0..w * h {
            for q in [
                (p % w + 1 < w).then_some(p + 1),
                (p + w < w * h).then_some(p + w),
            ] {
                let Some(q) = q else { continue };
                if labels.as_slice()[p] == labels.as_slice()[q] && same_tile(p, q) {
                    let (a, b) = (root(&mut parent, p), root(&mut parent, q));
                    parent[a] = b;
                }
            }
        }
        (0..w * h).filter(|&i| root(&mut parent, i) == i).count()
    }

    proptest! {
        /// Ids are numbered in raster order of first pixels, joined
        /// neighbours share an id, and there are as many ids as components.
        #[test]
        fn components_are_the_connected_regions_within_tiles(
            cells in proptest::collection::vec(0u16..3, 1..400),
            width in 1usize..25,
            tile in 0usize..7,
        ) {
            let h = cells.len().div_ceil(width);
            let labels = LabelMap::from_fn(width, h, |x, y| cells[(y * width + x) % cells.len()]);
            let (ids, count) = components(&labels, tile);
            let id = ids.as_slice();
            let mut next = 0;
            for &s in id {
                prop_assert!(s <= next);
                next = next.max(s + 1);
            }
            prop_assert_eq!(next as usize, count);
            prop_assert_eq!(count, count_by_union_find(&labels, tile));
            for p in 0..width * h {
                if p % width + 1 < width
                    && labels.as_slice()[p] == labels.as_slice()[p + 1]
                    && (tile == 0 || (p % width + 1) % tile != 0)
                {
                    prop_assert_eq!(id[p], id[p + 1]);
                }
                if p + width < width * h
                    && labels.as_slice()[p] == labels.as_slice()[p + width]
                    && (tile == 0 || (p / width + 1) % tile != 0)
                {
                    prop_assert_eq!(id[p], id[p + width]);
                }
            }
        }
    }
}
