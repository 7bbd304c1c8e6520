//! Region merging after mean shift clustering: the regions smaller than
//! the minimum size join their most similar neighbour. Its own module
//! because it works on any region map (a label per pixel, regions
//! 4-connected) and not on the filtering's modes.

use stereolink_image::{Plane, RgbImage};

/// Per root label: summed colour and pixel count.
pub(crate) fn region_sums(labels: &Plane<u32>, image: &RgbImage) -> Vec<([u64; 3], u64)> {
    let mut sums = vec![([0u64; 3], 0u64); labels.len()];
    for (&l, p) in labels.as_slice().iter().zip(image.as_slice()) {
        let e = &mut sums[l as usize];
        for k in 0..3 {
            e.0[k] += p[k] as u64;
        }
        e.1 += 1;
    }
    sums
}

/// Merges every region smaller than `min_region` into the adjacent region of
/// the closest mean colour, smallest regions first, until none is left.
pub(crate) fn merge_small_regions(labels: &mut Plane<u32>, image: &RgbImage, min_region: usize) {
    let (w, h) = labels.dims();
    for _ in 0..8 {
        let sums = region_sums(labels, image);
        let mean = |l: u32| {
            let (s, n) = sums[l as usize];
            s.map(|v| v as f64 / n.max(1) as f64)
        };
        let mut target: Vec<Option<(f64, u32)>> = vec![None; labels.len()];
        for y in 0..h {
            for x in 0..w {
                let a = labels.get(x, y);
                if sums[a as usize].1 as usize >= min_region {
                    continue;
                }
                for (nx, ny) in [
                    (x + 1, y),
                    (x, y + 1),
                    (x.wrapping_sub(1), y),
                    (x, y.wrapping_sub(1)),
                ] {
                    if nx >= w || ny >= h {
                        continue;
                    }
                    let b = labels.get(nx, ny);
                    if b == a {
                        continue;
                    }
                    let d: f64 = (0..3).map(|k| (mean(a)[k] - mean(b)[k]).powi(2)).sum();
                    if target[a as usize].is_none_or(|(bd, _)| d < bd) {
                        target[a as usize] = Some((d, b));
                    }
                }
            }
        }
        if target.iter().all(Option::is_none) {
            return;
        }
        for l in labels.as_mut_slice() {
            if let Some((_, b)) = target[*l as usize] {
                // Merge only into a region that is not itself moving this round.
                if target[b as usize].is_none() || sums[b as usize].1 > sums[*l as usize].1 {
                    *l = b;
                }
            }
        }
    }
}
