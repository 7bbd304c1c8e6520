//! Stereo-consistent segmentation of a right view: labels carried over from
//! the left view wherever the right pixel's colour is consistent with the
//! carried class.
//!
//! Two views segmented independently agree on their classes but not on
//! their speckle and boundaries (pixels near a class border fall either
//! way), which a coder predicting the right view from the left pays for.
//! Carrying the left view's label over, where the right pixel's colour
//! allows it within a margin, removes most of that disagreement at a small
//! cost in fidelity; the rest keeps its own label. Which left label a right
//! pixel receives (along which disparity) is the caller's choice.

use stereolink_image::{IndexedImage, LabelMap, RgbImage};

use crate::{Method, Segmentation};

/// Marks a pixel of a carried map with nothing carried. It is also the last
/// label of a full palette ([`crate::MAX_LABELS`] colours), which therefore
/// is never carried over.
pub const NOTHING: u16 = u16::MAX;

/// The default margin of [`carry_over`] for `method`: 6 levels for the
/// thresholding methods, 20 RGB units for the others. A wider margin makes
/// the right view cheaper to code conditioned on the left, for a little
/// more of its PSNR (docs/tuning.md, “Carry margin of the
/// stereo-consistent right view”).
pub fn default_margin(method: &Method) -> f32 {
    match method {
        Method::Otsu | Method::Pso(_) | Method::Dpso(_) | Method::Fodpso(_) => 6.0,
        Method::KMeans | Method::MeanShift(_) => 20.0,
    }
}

/// `right` (a segmentation of `image`) with each pixel's label replaced by
/// the one `carried` proposes (in `right`'s numbering; [`NOTHING`] or a
/// label outside the palette proposes nothing) where the pixel's colour is
/// consistent with that class within `margin`:
///
/// * thresholding methods (`right.channels` set): in each channel the value
///   lies in the carried class's interval, widened by `margin` levels on
///   both sides (the class of a colour is that of its mean in each channel);
/// * other methods (k-means, mean shift): the colour's Euclidean distance
///   to the carried class's colour is at most its distance to its own
///   class's colour plus `margin` (RGB units).
///
/// A margin of 0 carries only where the class does not change (for
/// thresholds) or where the carried colour is as near (the others).
///
/// # Panics
/// If `image`, `right` and `carried` differ in size.
pub fn carry_over(
    image: &RgbImage,
    right: &Segmentation,
    carried: &LabelMap,
    margin: f32,
) -> Segmentation {
    let labels = right.image.labels();
    assert_eq!(
        image.dims(),
        labels.dims(),
        "image and labels differ in size"
    );
    assert_eq!(carried.dims(), labels.dims(), "carried map differs in size");
    let palette = right.image.palette();
    let colour = |l: u16| palette[l as usize].map(f32::from);
    let consistent: Box<dyn Fn([u8; 3], u16, u16) -> bool> = match &right.channels {
        Some(ch) => {
            // Each label's interval per channel, widened.
            let bounds: Vec<[(f32, f32); 3]> = palette
                .iter()
                .map(|p| {
                    [0, 1, 2].map(|c| {
                        let t = &ch.thresholds[c];
                        let k = t.iter().filter(|&&th| p[c] > th).count();
                        let lo = if k == 0 {
                            0.0
                        } else {
                            f32::from(t[k - 1]) + 1.0
                        };
                        let hi = t.get(k).map_or(255.0, |&th| f32::from(th));
                        (lo - margin, hi + margin)
                    })
                })
                .collect();
            Box::new(move |px, _, to| {
                (0..3).all(|c| {
                    let (lo, hi) = bounds[to as usize][c];
                    (lo..=hi).contains(&f32::from(px[c]))
                })
            })
        }
        None => {
            let dist = |px: [u8; 3], c: [f32; 3]| {
                (0..3)
                    .map(|k| (f32::from(px[k]) - c[k]).powi(2))
                    .sum::<f32>()
                    .sqrt()
            };
            Box::new(move |px, own, to| dist(px, colour(to)) <= dist(px, colour(own)) + margin)
        }
    };
    let n = palette.len();
    let mut out = labels.clone();
    for ((l, &to), &px) in out
        .as_mut_slice()
        .iter_mut()
        .zip(carried.as_slice())
        .zip(image.as_slice())
    {
        if to != *l && to != NOTHING && (to as usize) < n && consistent(px, *l, to) {
            *l = to;
        }
    }
    Segmentation {
        image: IndexedImage::new(out, palette.to_vec()).expect("labels of the palette"),
        channels: right.channels.clone(),
        iterations: right.iterations,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{segment, Method};

    /// Two flat halves, dark and bright, and a mid-grey column between.
    fn halves() -> RgbImage {
        RgbImage::from_fn(20, 4, |x, _| match x {
            0..=9 => [20; 3],
            10 => [120; 3],
            _ => [220; 3],
        })
    }

    #[test]
    fn carries_only_consistent_colours() {
        let img = halves();
        for method in [Method::KMeans, "fodpso".parse().unwrap()] {
            let seg = segment(&img, &method, 2, 1).unwrap();
            let l = seg.image.labels();
            let (dark, bright) = (l.get(0, 0), l.get(19, 0));
            // Propose the bright label everywhere.
            let carried = LabelMap::new(20, 4, bright);
            let near = carry_over(&img, &seg, &carried, 0.0);
            let far = carry_over(&img, &seg, &carried, 500.0);
            // The dark half is never consistent with the bright class
            // unless the margin spans the whole range.
            assert_eq!(near.image.labels().get(0, 0), dark, "{method}");
            assert_eq!(far.image.labels().get(0, 0), bright, "{method}");
            assert_eq!(near.image.palette(), seg.image.palette());
            // Nothing proposed: unchanged.
            let none = carry_over(&img, &seg, &LabelMap::new(20, 4, NOTHING), 500.0);
            assert_eq!(none, seg, "{method}");
        }
    }

    /// A full palette's last label is NOTHING: proposing nothing carries
    /// nothing there too (it carried that label wherever the colour let it).
    #[test]
    fn nothing_carries_nothing_in_a_full_palette() {
        let image = RgbImage::from_fn(256, 256, |x, y| [x as u8, y as u8, 0]);
        let labels = LabelMap::from_fn(256, 256, |x, y| (y * 256 + x) as u16);
        let palette = image.as_slice().to_vec();
        let seg = Segmentation {
            image: IndexedImage::new(labels, palette).unwrap(),
            channels: None,
            iterations: 0,
        };
        let none = carry_over(&image, &seg, &LabelMap::new(256, 256, NOTHING), 1000.0);
        assert_eq!(none, seg);
    }
}
