//! Stereo matching and depth: winner-take-all SAD and line growing (the
//! paper's local and global methods), semi-global matching (beyond the
//! paper), segment-based disparity planes (the paper's Section III),
//! refinement, and depth from disparity.
//!
//! # Brief overview
//!
//! * [`compute_disparity`] runs any [`Algorithm`] with a validated
//!   [`MatchSpec`] and the chosen [`Refinement`] steps, returning an `f32`
//!   [`DisparityMap`] with `f32::INFINITY` where no disparity is known.
//! * [`Matcher`] does the same keeping its buffers between frames;
//!   [`wta::WtaMatcher`] alone is what the embedded receiver runs, frame
//!   after frame without allocating.
//! * [`planes`] is segment-based stereo: a disparity plane per segment of
//!   a label map of the left view ([`Matcher::compute_segmented`]).
//! * [`depth`] turns disparity into metres (`Z = b·f / (d + doffs)`), point
//!   clouds (PLY), region distances and the number of depth levels.
//!
//! Geometry: the left view is the reference, left `(x, y)` with disparity `d`
//! matches right `(x − d, y)`.
//!
//! # Example
//!
//! ```
//! use stereolink_image::synth::{synthesize, SynthSpec};
//! use stereolink_stereo::{compute_disparity, Algorithm, MatchSpec};
//!
//! let scene = synthesize(&SynthSpec { width: 96, height: 64, max_disp: 16, seed: 2 }).unwrap();
//! let spec = MatchSpec::new(Algorithm::Sgm, 0, 16).unwrap();
//! let disparity = compute_disparity(&scene.left, &scene.right, &spec).unwrap();
//! assert_eq!(disparity.dims(), (96, 64));
//! ```

pub mod census;
pub mod depth;
mod lanes;
pub mod line_growing;
mod median;
pub mod planes;
pub mod refine;
pub mod ripple;
pub mod sgm;
pub mod weighted_median;
pub mod wta;

use std::fmt;
use std::str::FromStr;

use stereolink_image::{color, DisparityMap, GrayImage, LabelMap, RgbImage};

pub use refine::Refinement;

/// Errors of the matchers: bad parameters or inputs that cannot be matched.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum StereoError {
    /// Left and right views differ in size.
    #[error("left view is {left_w}x{left_h} but right view is {right_w}x{right_h}")]
    SizeMismatch {
        /// Left width.
        left_w: usize,
        /// Left height.
        left_h: usize,
        /// Right width.
        right_w: usize,
        /// Right height.
        right_h: usize,
    },
    /// The disparity range is empty or does not fit the image.
    #[error("disparity range {min}..={max} is invalid for an image {width} px wide (need min < max < width)")]
    DisparityRange {
        /// Minimum disparity.
        min: usize,
        /// Maximum disparity.
        max: usize,
        /// Image width.
        width: usize,
    },
    /// The block (window) size is even, zero or too large.
    #[error("block size {0} must be odd, between 1 and 15")]
    BlockSize(usize),
    /// Another parameter is out of range.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// The label map of the plane matcher differs in size from the views.
    #[error("the label map is {}x{} but the views are {}x{}", labels.0, labels.1, image.0, image.1)]
    LabelMapSize {
        /// Label map width and height.
        labels: (usize, usize),
        /// View width and height.
        image: (usize, usize),
    },
    /// The plane matcher was asked for without the left view's label map.
    #[error("the planes matcher needs the left view's segmentation (a label map)")]
    NoSegments,
}

/// The matching algorithms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Algorithm {
    /// Winner-take-all on box-aggregated SAD (the paper's eq. 12).
    Wta,
    /// The paper's line growing on averaged squared error energy (eq. 15–16).
    #[serde(rename = "lg")]
    LineGrowing,
    /// Semi-global matching on census costs (Hirschmüller 2008).
    Sgm,
    /// Segment-based stereo with disparity planes ([`planes`]).
    Planes,
}

impl Algorithm {
    /// The pixel-wise algorithms, in the order reports list them (the plane
    /// matcher needs a segmentation as well).
    pub const ALL: [Algorithm; 3] = [Algorithm::Wta, Algorithm::LineGrowing, Algorithm::Sgm];

    /// The short name used on the command line (`wta`, `lg`, `sgm`, `planes`).
    pub fn name(self) -> &'static str {
        match self {
            Algorithm::Wta => "wta",
            Algorithm::LineGrowing => "lg",
            Algorithm::Sgm => "sgm",
            Algorithm::Planes => "planes",
        }
    }
}

impl fmt::Display for Algorithm {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Algorithm {
    type Err = StereoError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "wta" | "sad" => Ok(Algorithm::Wta),
            "lg" | "line-growing" | "linegrowing" => Ok(Algorithm::LineGrowing),
            "sgm" => Ok(Algorithm::Sgm),
            "planes" => Ok(Algorithm::Planes),
            other => Err(StereoError::Parameter(format!(
                "unknown algorithm {other:?}; use wta, lg, sgm or planes"
            ))),
        }
    }
}

/// Default WTA gray precision: 9 bits keep the half level of luma that
/// rounding to 8 would lose (docs/tuning.md, “9-bit gray samples”).
pub const WTA_GRAY_BITS: u32 = 9;

/// Default WTA min filter side: off. With the default refinement a min
/// filter helps some scenes and costs the 20-scene average (docs/tuning.md,
/// “No min filter”).
pub const WTA_MIN_FILTER: usize = 0;

/// A validated matching request: algorithm, disparity range, window and refinement.
#[derive(Clone, Debug, PartialEq)]
pub struct MatchSpec {
    /// The algorithm.
    pub algorithm: Algorithm,
    /// Smallest disparity searched.
    pub min_disp: usize,
    /// Largest disparity searched (inclusive).
    pub max_disp: usize,
    /// Odd window size for WTA and line growing (n = m).
    pub block: usize,
    /// WTA: bits per gray sample, 8..=10 ([`wta::WtaParams::gray_bits`]).
    pub gray_bits: u32,
    /// WTA: side of the min filter over the window sums, odd, 0 or 1 = off
    /// ([`wta::WtaParams::min_filter`]).
    pub min_filter: usize,
    /// SGM parameters.
    pub sgm: sgm::SgmParams,
    /// Line-growing parameters.
    pub line_growing: line_growing::LineGrowingParams,
    /// Plane matcher parameters (its initial SGM map uses [`Self::sgm`]).
    pub planes: planes::PlanesParams,
    /// SGM and planes: when to take a camera's column ripple out of the
    /// grey views first ([`ripple`]).
    pub ripple: ripple::RippleFilter,
    /// Post-processing steps.
    pub refine: Refinement,
}

impl MatchSpec {
    /// A spec with the defaults for `algorithm` over `min_disp..=max_disp`
    /// (docs/tuning.md gives the reasons for each).
    pub fn new(
        algorithm: Algorithm,
        min_disp: usize,
        max_disp: usize,
    ) -> Result<Self, StereoError> {
        let spec = MatchSpec {
            algorithm,
            min_disp,
            max_disp,
            block: match algorithm {
                Algorithm::Wta => 11,
                Algorithm::LineGrowing => 5,
                Algorithm::Sgm | Algorithm::Planes => 1,
            },
            gray_bits: WTA_GRAY_BITS,
            min_filter: WTA_MIN_FILTER,
            sgm: sgm::SgmParams {
                paths: match algorithm {
                    Algorithm::Planes => planes::INITIAL_PATHS,
                    _ => sgm::SgmParams::default().paths,
                },
                ..sgm::SgmParams::default()
            },
            line_growing: line_growing::LineGrowingParams::default(),
            planes: planes::PlanesParams::default(),
            ripple: ripple::RippleFilter::default(),
            refine: Refinement::default_for(algorithm),
        };
        if min_disp >= max_disp {
            return Err(StereoError::DisparityRange {
                min: min_disp,
                max: max_disp,
                width: usize::MAX,
            });
        }
        Ok(spec)
    }

    /// Checks the spec against an image size.
    pub fn validate(&self, width: usize, height: usize) -> Result<(), StereoError> {
        if self.min_disp >= self.max_disp || self.max_disp >= width {
            return Err(StereoError::DisparityRange {
                min: self.min_disp,
                max: self.max_disp,
                width,
            });
        }
        if self.block == 0 || self.block % 2 == 0 || self.block > 15 {
            return Err(StereoError::BlockSize(self.block));
        }
        if height == 0 {
            return Err(StereoError::Parameter("the image has no rows".into()));
        }
        if self.refine.median > 15 {
            return Err(StereoError::Parameter(format!(
                "median filter size {} is larger than 15",
                self.refine.median
            )));
        }
        if self.algorithm == Algorithm::Wta {
            wta::WtaParams::from_spec(self).validate()?;
        }
        if let Some(wm) = &self.refine.weighted_median {
            wm.validate()?;
        }
        self.sgm.validate()?;
        self.planes.validate()?;
        self.line_growing.validate()
    }

    /// Number of disparities searched.
    pub fn ndisp(&self) -> usize {
        self.max_disp - self.min_disp + 1
    }
}

fn check_pair(left: &RgbImage, right: &RgbImage) -> Result<(), StereoError> {
    if left.dims() != right.dims() {
        return Err(StereoError::SizeMismatch {
            left_w: left.width(),
            left_h: left.height(),
            right_w: right.width(),
            right_h: right.height(),
        });
    }
    Ok(())
}

/// Computes the left view's disparity map with `spec` (matching, then
/// refinement). To match frame after frame, keep a [`Matcher`] instead.
pub fn compute_disparity(
    left: &RgbImage,
    right: &RgbImage,
    spec: &MatchSpec,
) -> Result<DisparityMap, StereoError> {
    Matcher::new().compute(left, right, spec)
}

/// A matcher that keeps its buffers (WTA gray views and bands, SGM cost and sum volumes)
/// from one call to the next: matching frames of an unchanged size neither
/// allocates nor clears the volumes again.
#[derive(Default)]
pub struct Matcher {
    wta: wta::WtaMatcher,
    /// The views' gray samples for WTA (large enough to be allocated, and
    /// page-faulted in, anew on every call otherwise).
    luma: [wta::Samples; 2],
    /// The right view's WTA map, for the left-right check.
    wta_right: DisparityMap,
    sgm: sgm::SgmBuffers,
    refine: refine::RefineBuffers,
}

impl Matcher {
    /// An empty matcher; buffers grow on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// Computes the left view's disparity map with `spec` (matching, then
    /// refinement); [`Algorithm::Planes`] needs [`Self::compute_segmented`].
    pub fn compute(
        &mut self,
        left: &RgbImage,
        right: &RgbImage,
        spec: &MatchSpec,
    ) -> Result<DisparityMap, StereoError> {
        self.compute_segmented(left, right, None, spec)
    }

    /// [`Self::compute`] with the left view's label map, which the plane
    /// matcher needs and the others ignore.
    pub fn compute_segmented(
        &mut self,
        left: &RgbImage,
        right: &RgbImage,
        labels: Option<&LabelMap>,
        spec: &MatchSpec,
    ) -> Result<DisparityMap, StereoError> {
        check_pair(left, right)?;
        spec.validate(left.width(), left.height())?;
        let raw = match spec.algorithm {
            Algorithm::Wta => {
                let [l, r] = &mut self.luma;
                rayon::join(
                    || wta::luma_samples_into(left, spec.gray_bits, l),
                    || wta::luma_samples_into(right, spec.gray_bits, r),
                );
                wta_with_check(&mut self.wta, &mut self.wta_right, l, r, spec)
            }
            Algorithm::LineGrowing => line_growing::line_growing(left, right, spec),
            Algorithm::Sgm => {
                let (l, r) = gray_pair(left, right, spec.ripple);
                sgm::sgm(&l, &r, spec, &mut self.sgm)
            }
            Algorithm::Planes => {
                let labels = labels.ok_or(StereoError::NoSegments)?;
                let planes = planes::match_planes_with(left, right, labels, spec, &mut self.sgm)?;
                refine::Raw {
                    disparity: planes.disparity,
                    right: None,
                }
            }
        };
        Ok(refine::postprocess(raw, spec, left, &mut self.refine))
    }
}

/// Both views in gray, converted in parallel, with the column ripple
/// taken out of both when `ripple` says so for the left one.
fn gray_pair(
    left: &RgbImage,
    right: &RgbImage,
    ripple: ripple::RippleFilter,
) -> (GrayImage, GrayImage) {
    let ((l, filter), r) = rayon::join(
        || {
            let l = color::rgb_to_gray(left);
            let filter = ripple.applies(&l);
            (l, filter)
        },
        || color::rgb_to_gray(right),
    );
    if filter {
        rayon::join(
            || ripple::suppress_column_ripple(&l),
            || ripple::suppress_column_ripple(&r),
        )
    } else {
        (l, r)
    }
}

/// WTA on gray views, and the left-right check when it is asked for:
/// inside the pass for whole disparities at a tolerance below one pixel
/// (the default), else against the right view's map from the same pass
/// (in `right_map`, kept from one call to the next).
fn wta_with_check(
    matcher: &mut wta::WtaMatcher,
    right_map: &mut DisparityMap,
    left: &wta::Samples,
    right: &wta::Samples,
    spec: &MatchSpec,
) -> refine::Raw {
    let params = wta::WtaParams::from_spec(spec);
    let (w, h) = left.dims();
    let mut disp = DisparityMap::new(w, h, f32::INFINITY);
    match spec.refine.lr_check {
        // Whole disparities and a tolerance below one pixel: the check
        // inside the pass, which needs no right map.
        Some(tol) if (0.0..1.0).contains(&tol) && !params.subpixel => {
            matcher.compute_checked_into(left, right, &params, &mut disp);
        }
        Some(tol) => {
            if right_map.dims() != (w, h) {
                right_map.reset(w, h, f32::INFINITY);
            }
            matcher.compute_both_into(left, right, &params, &mut disp, right_map);
            refine::lr_check(&mut disp, right_map, tol);
        }
        None => matcher.compute_into(left, right, &params, &mut disp),
    }
    // Checked already: no right map for the refinement.
    refine::Raw {
        disparity: disp,
        right: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereolink_image::metrics::bad_pixel_rate;
    use stereolink_image::synth::{synthesize, SynthSpec};

    fn scene() -> stereolink_image::Scene {
        synthesize(&SynthSpec {
            width: 200,
            height: 150,
            max_disp: 24,
            seed: 11,
        })
        .unwrap()
    }

    #[test]
    fn every_algorithm_recovers_the_synthetic_ground_truth() {
        let s = scene();
        let gt = s.gt_left.as_ref().unwrap();
        for (algo, limit) in [
            (Algorithm::Wta, 8.0),
            (Algorithm::LineGrowing, 15.0),
            (Algorithm::Sgm, 5.0),
        ] {
            let spec = MatchSpec::new(algo, 0, 24).unwrap();
            let d = compute_disparity(&s.left, &s.right, &spec).unwrap();
            let bad = bad_pixel_rate(&d, gt, s.masks.nonocc.as_ref(), 1.0).unwrap();
            assert!(bad < limit, "{algo}: {bad:.2} % bad");
            assert!(d.as_slice().iter().all(|v| !v.is_nan()));
        }
    }

    #[test]
    fn bad_parameters_are_clear_errors() {
        let s = scene();
        assert!(matches!(
            MatchSpec::new(Algorithm::Wta, 5, 5),
            Err(StereoError::DisparityRange { .. })
        ));
        let mut spec = MatchSpec::new(Algorithm::Wta, 0, 24).unwrap();
        spec.block = 4;
        assert_eq!(
            compute_disparity(&s.left, &s.right, &spec),
            Err(StereoError::BlockSize(4))
        );
        spec.block = 0;
        assert_eq!(
            compute_disparity(&s.left, &s.right, &spec),
            Err(StereoError::BlockSize(0))
        );
        spec.block = 5;
        spec.refine.median = 17;
        assert!(matches!(
            compute_disparity(&s.left, &s.right, &spec),
            Err(StereoError::Parameter(_))
        ));
        let spec = MatchSpec::new(Algorithm::Sgm, 0, 200).unwrap();
        assert!(matches!(
            compute_disparity(&s.left, &s.right, &spec),
            Err(StereoError::DisparityRange { .. })
        ));
        let small = RgbImage::new(10, 10, [0; 3]);
        let spec = MatchSpec::new(Algorithm::Wta, 0, 4).unwrap();
        assert!(matches!(
            compute_disparity(&s.left, &small, &spec),
            Err(StereoError::SizeMismatch { .. })
        ));
        assert!("foo".parse::<Algorithm>().is_err());
        assert_eq!("LG".parse::<Algorithm>(), Ok(Algorithm::LineGrowing));
    }

    #[test]
    fn constant_images_give_finite_or_invalid_never_nan() {
        let img = RgbImage::new(40, 20, [128, 128, 128]);
        for algo in Algorithm::ALL {
            let spec = MatchSpec::new(algo, 0, 8).unwrap();
            let d = compute_disparity(&img, &img, &spec).unwrap();
            assert!(d.as_slice().iter().all(|v| !v.is_nan()), "{algo}");
        }
    }
}
