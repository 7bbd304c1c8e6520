//! Region merging after mean shift clustering. Its own module because it
//! works on any region map (a label per pixel, each region 4-connected),
//! not on the filtering's modes.
//!
//! Two reasons merge regions: regions smaller than the minimum size
//! ([`merge_small_regions`]), and the number of regions a label map can
//! number ([`cap_regions`]): labels are `u16` ([`stereolink_image::LabelMap`])
//! and a frame's palette holds at most [`crate::MAX_LABELS`] colours. The
//! cap merges the smallest regions into their most similar neighbours
//! rather than widening the label type, which the lossless label coding,
//! the frame format and the board's display all share; the matcher's
//! segments (components of a label map, numbered `u32`) have no cap. Only
//! images with more regions than labels change: pixel noise, which the
//! minimum size does not merge (see [`merge_small_regions`]). Every round
//! is one pass over the pixels, and the rounds halve what is left to
//! merge, so the time is `O(n log n)` and the memory `O(n)` in the pixels.

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

/// Merges regions smaller than `min_region` into the adjacent region of the
/// closest mean colour, in at most 8 rounds.
///
/// A small region merges only into a larger one or one that does not move
/// itself, so equal regions that pick each other stay: the one-pixel
/// regions of pixel noise, and some small regions of real scenes. The
/// minimum is a target, not a guarantee. Merging them all (in
/// [`merge_round`]s until none is left) was measured to cost the plane
/// matcher's over-segmentation (`h_r` 5, 30 px) 0.73 points of bad > 1 px
/// over the 20 shared scenes (8.45 → 9.18 %, Vintage 14.85 → 26.70 %), and
/// on pixel-noise pairs 0.53–0.61 % against 0.15–0.18 % with the regions
/// capped instead: small segments carry detail the planes use.
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

/// Merges the smallest regions into their most similar neighbours until at
/// most `cap` are left: each round, the regions beyond the cap (the
/// smallest, ties to the higher label) take a [`merge_round`], which
/// merges at least half of them, so few rounds run.
pub(crate) fn cap_regions(labels: &mut Plane<u32>, image: &RgbImage, cap: usize) {
    loop {
        let sums = region_sums(labels, image);
        let mut present: Vec<(u64, std::cmp::Reverse<u32>)> = sums
            .iter()
            .enumerate()
            .filter(|(_, s)| s.1 > 0)
            .map(|(l, s)| (s.1, std::cmp::Reverse(l as u32)))
            .collect();
        if present.len() <= cap {
            return;
        }
        let excess = present.len() - cap;
        let last = *present.select_nth_unstable(excess - 1).1;
        let picked = |l: u32, n: u64| (n, std::cmp::Reverse(l)) <= last;
        if !merge_round(labels, image, picked) {
            return;
        }
    }
}

/// One round of merges, all at once: each region that `picks` chooses (by
/// label and pixel count) joins the adjacent region of the closest mean
/// colour (ties to the lower label); chains and pairs that chose each
/// other become one region, labelled by their lowest label. False when no
/// chosen region has a neighbour (nothing merged).
///
/// Each chosen region ends up merged, and as the closest-colour choices
/// (ties broken by label) form no cycle longer than a pair, the regions
/// decrease by at least half the chosen ones.
fn merge_round(
    labels: &mut Plane<u32>,
    image: &RgbImage,
    picks: impl Fn(u32, u64) -> bool,
) -> bool {
    let w = labels.width();
    let sums = region_sums(labels, image);
    let mean = |l: u32| {
        let (s, n) = sums[l as usize];
        s.map(|v| v as f64 / n.max(1) as f64)
    };
    let mut target: Vec<Option<(f64, u32)>> = vec![None; labels.len()];
    let mut consider = |a: u32, b: u32| {
        if a == b || !picks(a, sums[a as usize].1) {
            return;
        }
        let (ma, mb) = (mean(a), mean(b));
        let d: f64 = (0..3).map(|k| (ma[k] - mb[k]).powi(2)).sum();
        let t = &mut target[a as usize];
        if t.is_none_or(|(bd, bl)| d < bd || (d == bd && b < bl)) {
            *t = Some((d, b));
        }
    };
    let id = labels.as_slice();
    for p in 0..id.len() {
        if (p + 1) % w != 0 {
            consider(id[p], id[p + 1]);
            consider(id[p + 1], id[p]);
        }
        if p + w < id.len() {
            consider(id[p], id[p + w]);
            consider(id[p + w], id[p]);
        }
    }
    let mut parent: Vec<u32> = (0..labels.len() as u32).collect();
    let mut merged = false;
    for (a, t) in target.iter().enumerate() {
        if let Some((_, b)) = *t {
            let (ra, rb) = (find(&mut parent, a as u32), find(&mut parent, b));
            if ra != rb {
                parent[ra.max(rb) as usize] = ra.min(rb);
                merged = true;
            }
        }
    }
    if merged {
        for l in labels.as_mut_slice() {
            *l = find(&mut parent, *l);
        }
    }
    merged
}

/// The root of `i` in the union-find forest `parent` (paths halved).
pub(crate) fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        parent[i as usize] = parent[parent[i as usize] as usize];
        i = parent[i as usize];
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereolink_image::segments::components;
    use stereolink_image::LabelMap;

    /// Every pixel its own region, colours from a fixed noise.
    fn noise(w: usize, h: usize) -> (Plane<u32>, RgbImage) {
        let mut s = 1u32;
        let image = RgbImage::from_fn(w, h, |_, _| {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            [(s >> 24) as u8, (s >> 16) as u8, (s >> 8) as u8]
        });
        (Plane::from_fn(w, h, |x, y| (y * w + x) as u32), image)
    }

    /// Region sizes by label, of the labels present.
    fn sizes(labels: &Plane<u32>) -> Vec<usize> {
        let mut n = vec![0; labels.len()];
        labels.as_slice().iter().for_each(|&l| n[l as usize] += 1);
        n.into_iter().filter(|&c| c > 0).collect()
    }

    /// The regions are 4-connected: as many components as labels.
    fn connected(labels: &Plane<u32>) -> bool {
        let (w, h) = labels.dims();
        let mut remap = std::collections::HashMap::new();
        let small = LabelMap::from_fn(w, h, |x, y| {
            let n = remap.len();
            *remap.entry(labels.get(x, y)).or_insert(n) as u16
        });
        // Labels above u16 would alias; the tests stay below.
        components(&small, 0).1 == remap.len()
    }

    /// A round merges every region it picks, and at least halves their
    /// number: closest-colour picks form no cycle longer than a pair.
    #[test]
    fn a_round_merges_every_pick_and_halves_them() {
        let (mut labels, image) = noise(60, 45);
        let before = labels.clone();
        let picked = |l: u32, _| l % 3 != 0;
        let chosen = (0..60 * 45).filter(|&l| picked(l, 0)).count();
        assert!(merge_round(&mut labels, &image, picked));
        let after = sizes(&labels).len();
        assert!(
            60 * 45 - after >= chosen.div_ceil(2),
            "{after} regions left"
        );
        // Every picked one-pixel region now shares its label.
        let mut count = std::collections::HashMap::new();
        labels
            .as_slice()
            .iter()
            .for_each(|&l| *count.entry(l).or_insert(0) += 1);
        for (l, &was) in labels.as_slice().iter().zip(before.as_slice()) {
            assert!(!picked(was, 0) || count[l] > 1, "pixel {was} alone");
        }
        assert!(connected(&labels));
        // Nothing picked: nothing merges.
        assert!(!merge_round(&mut labels, &image, |_, _| false));
    }

    #[test]
    fn the_cap_keeps_at_most_that_many_regions_and_merges_the_smallest() {
        let (mut labels, image) = noise(50, 40);
        // A large flat region stays whole: only the one-pixel ones merge.
        let image = RgbImage::from_fn(
            50,
            40,
            |x, y| {
                if x < 10 {
                    [7, 7, 7]
                } else {
                    image.get(x, y)
                }
            },
        );
        for y in 0..40 {
            for x in 0..10 {
                labels.set(x, y, 0);
            }
        }
        for cap in [1, 2, 77, 1000, 1600] {
            let mut capped = labels.clone();
            cap_regions(&mut capped, &image, cap);
            let n = sizes(&capped);
            assert_eq!(n.len(), cap, "cap {cap}");
            assert!(connected(&capped), "cap {cap}");
            if cap > 1 {
                assert!((0..40).all(|y| (0..10).all(|x| capped.get(x, y) == 0)));
            }
        }
        let mut whole = labels.clone();
        cap_regions(&mut whole, &image, 5000);
        assert_eq!(whole, labels);
    }

    #[test]
    fn one_region_and_empty_maps_are_left_alone() {
        let image = RgbImage::new(4, 3, [1, 2, 3]);
        let mut one = Plane::new(4, 3, 5u32);
        merge_small_regions(&mut one, &image, 100);
        cap_regions(&mut one, &image, 0);
        assert_eq!(one, Plane::new(4, 3, 5u32));
        let mut empty = Plane::new(0, 0, 0u32);
        merge_small_regions(&mut empty, &RgbImage::new(0, 0, [0; 3]), 100);
    }
}
