//! The segments of the plane matcher: the `stereo` crate fits planes to the
//! connected components of a label map and imports nothing above `image`,
//! so this pipeline segments the left view first. By default a mean shift
//! over-segmentation (small bandwidths, a few hundred to a few thousand
//! segments); `--segments METHOD` takes that method's label map instead
//! (its connected components become the segments), as the paper does.

use stereolink_image::{DisparityMap, LabelMap, RgbImage};
use stereolink_segment::meanshift::MeanShiftSpec;
use stereolink_segment::{segment, Method};
use stereolink_stereo::{Algorithm, MatchSpec, Matcher};

/// Where the plane matcher's segments come from.
#[derive(Clone, Debug, PartialEq)]
pub enum Segments {
    /// The mean shift over-segmentation of [`over_segmentation`].
    OverSegmentation,
    /// A segmentation method's label map with its levels and seed.
    Method(Method, usize, u64),
}

/// The default over-segmentation: mean shift with `h_s = 4`, `h_r = 5`
/// (L\*u\*v\*) and regions of at least 30 pixels. Measured with the
/// plane matcher's first defaults on Tsukuba / Venus / Teddy / Cones (bad >
/// 1 px non-occluded, %): 11.12 / 0.34 / 4.94 / 3.66, against 7.43 / 0.56
/// / 5.56 / 4.09 with `h_r = 3`, 8.25 / 0.44 / 5.20 / 3.79 with `h_s = 6,
/// h_r = 4` and 7.61 / 0.42 / 5.83 / 3.81 with `h_s = 8, h_r = 3`: the best
/// average but Tsukuba; its dark background merges across depths.
pub fn over_segmentation() -> MeanShiftSpec {
    MeanShiftSpec {
        spatial: 4,
        range: 5.0,
        min_region: 30,
        ..MeanShiftSpec::default()
    }
}

/// The left view's label map for the plane matcher.
pub fn left_segments(left: &RgbImage, segments: &Segments) -> anyhow::Result<LabelMap> {
    let seg = match segments {
        Segments::OverSegmentation => segment(left, &Method::MeanShift(over_segmentation()), 2, 0)?,
        Segments::Method(method, levels, seed) => segment(left, method, *levels, *seed)?,
    };
    Ok(seg.image.into_parts().0)
}

/// The left view's disparity with `spec`: for the plane matcher the left
/// view is segmented first (as `segments` says), the others match directly.
pub fn disparity(
    matcher: &mut Matcher,
    (left, right): (&RgbImage, &RgbImage),
    spec: &MatchSpec,
    segments: &Segments,
) -> anyhow::Result<DisparityMap> {
    let labels = match spec.algorithm {
        Algorithm::Planes => Some(left_segments(left, segments)?),
        _ => None,
    };
    Ok(matcher.compute_segmented(left, right, labels.as_ref(), spec)?)
}
