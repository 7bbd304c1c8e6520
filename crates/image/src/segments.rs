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

use crate::{LabelMap, Plane};

/// The 4-connected components of `labels` within the tiles of side `tile`
/// (0: no tiles): an id per pixel, in raster order of the components'
/// first pixels, and the number of components.
pub fn components(labels: &LabelMap, tile: usize) -> (Plane<u32>, usize) {
    let tile_of = |p: usize, w: usize| match tile {
        0 => (0, 0),
        t => (p % w / t, p / w / t),
    };
    let (w, h) = labels.dims();
    let mut ids = Plane::new(w, h, u32::MAX);
    let mut count = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if ids.as_slice()[start] != u32::MAX {
            continue;
        }
        let (label, area) = (labels.as_slice()[start], tile_of(start, w));
        ids.as_mut_slice()[start] = count;
        stack.push(start);
        while let Some(p) = stack.pop() {
            let (x, y) = (p % w, p / w);
            let mut visit = |q: usize| {
                if ids.as_slice()[q] == u32::MAX
                    && labels.as_slice()[q] == label
                    && tile_of(q, w) == area
                {
                    ids.as_mut_slice()[q] = count;
                    stack.push(q);
                }
            };
            if x > 0 {
                visit(p - 1);
            }
            if x + 1 < w {
                visit(p + 1);
            }
            if y > 0 {
                visit(p - w);
            }
            if y + 1 < h {
                visit(p + w);
            }
        }
        count += 1;
    }
    (ids, count as usize)
}
