//! Every matcher (WTA, line growing, SGM, planes) on random pairs: sizes
//! from 1x1 up, flat, noise, stripe and checkerboard views, disparity
//! ranges from 1 to the width, label maps from one segment to one per
//! pixel, any refinement. Each returns a map of the views' size, or a
//! typed error for invalid parameters only (a range that does not fit the
//! width, a window of an even side or too large), never a panic.
//!
//! The property tests run a few dozen cases up to 320x240 (set
//! `PROPTEST_CASES` to run more of each); plain tests take a 2000x1500
//! pair and a range as wide as a 2000 px view.

use proptest::prelude::*;
use stereolink_image::{LabelMap, RgbImage};
use stereolink_stereo::refine::HoleFill;
use stereolink_stereo::weighted_median::WeightedMedian;
use stereolink_stereo::wta::WtaParams;
use stereolink_stereo::{Algorithm, MatchSpec, Matcher, Refinement, StereoError};

/// What a view (or a label map) shows.
#[derive(Clone, Copy, Debug)]
enum Pattern {
    /// One colour.
    Flat([u8; 3]),
    /// A new colour every pixel.
    Noise(u64),
    /// Stripes of `width` px across `x` (vertical stripes) or `y`.
    Stripes { width: usize, vertical: bool },
    /// Squares of side `side`.
    Checkers { side: usize },
}

impl Pattern {
    /// The value at `(x, y)`: a colour index of up to 48 bits.
    fn at(self, x: usize, y: usize) -> u64 {
        match self {
            Pattern::Flat(c) => u64::from(c[0]) | u64::from(c[1]) << 8 | u64::from(c[2]) << 16,
            Pattern::Noise(seed) => {
                let mut z = seed ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                z ^= (y as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z = (z ^ (z >> 30)).wrapping_mul(0x94D0_49BB_1331_11EB);
                z ^ (z >> 29)
            }
            Pattern::Stripes { width, vertical } => {
                let i = if vertical { x } else { y } / width;
                if i % 2 == 0 {
                    0x20_40_60
                } else {
                    0xE0_C0_A0
                }
            }
            Pattern::Checkers { side } => {
                if (x / side + y / side) % 2 == 0 {
                    0x10_10_10
                } else {
                    0xF0_F0_F0
                }
            }
        }
    }

    fn view(self, w: usize, h: usize) -> RgbImage {
        RgbImage::from_fn(w, h, |x, y| {
            let v = self.at(x, y);
            [v as u8, (v >> 8) as u8, (v >> 16) as u8]
        })
    }

    /// Labels from the pattern (noise: up to 65536 labels, about one
    /// segment per pixel).
    fn labels(self, w: usize, h: usize) -> LabelMap {
        LabelMap::from_fn(w, h, |x, y| self.at(x, y) as u16)
    }
}

fn pattern() -> impl Strategy<Value = Pattern> {
    prop_oneof![
        any::<[u8; 3]>().prop_map(Pattern::Flat),
        any::<u64>().prop_map(Pattern::Noise),
        (1usize..12, any::<bool>())
            .prop_map(|(width, vertical)| Pattern::Stripes { width, vertical }),
        (1usize..12).prop_map(|side| Pattern::Checkers { side }),
    ]
}

/// Any valid refinement: the steps on or off, with a few settings each.
fn refinement() -> impl Strategy<Value = Refinement> {
    let lr_check = prop_oneof![
        Just(None),
        Just(Some(0.5f32)),
        Just(Some(1.0)),
        Just(Some(3.0))
    ];
    let weighted = prop_oneof![
        Just(None),
        Just(Some(WeightedMedian::DEFAULT)),
        (1usize..4)
            .prop_flat_map(|radius| (Just(radius), 1..=radius))
            .prop_map(|(radius, step)| Some(WeightedMedian {
                radius,
                step,
                ..WeightedMedian::DEFAULT
            })),
    ];
    let fill = prop_oneof![
        Just(None),
        Just(Some(HoleFill::Row)),
        Just(Some(HoleFill::Directions))
    ];
    let median = prop_oneof![Just(0usize), Just(1), Just(3), Just(5), Just(15)];
    (
        lr_check,
        any::<bool>(),
        prop_oneof![Just(0u32), Just(15)],
        median,
        weighted,
        fill,
    )
        .prop_map(
            |(lr_check, subpixel, uniqueness, median, weighted_median, fill)| Refinement {
                lr_check,
                subpixel,
                uniqueness,
                median,
                weighted_median,
                fill,
            },
        )
}

/// The right view: another pattern, or the left one seen `shift` px
/// further (the left view's `x + shift`, as a pair at disparity `shift`).
#[derive(Clone, Copy, Debug)]
enum Right {
    Other(Pattern),
    Shifted(usize),
}

/// One case: views, labels, matcher and range.
#[derive(Clone, Debug)]
struct Case {
    w: usize,
    h: usize,
    left: Pattern,
    right: Right,
    labels: Pattern,
    algorithm: Algorithm,
    min_disp: usize,
    max_disp: usize,
    /// The window (the algorithm's default when `None`; 0, even sides and
    /// sides over 15 are invalid).
    block: Option<usize>,
    /// The refinement (the algorithm's default when `None`).
    refine: Option<Refinement>,
}

fn case(max_w: usize, max_h: usize) -> impl Strategy<Value = Case> {
    let algorithm = prop_oneof![
        Just(Algorithm::Wta),
        Just(Algorithm::LineGrowing),
        Just(Algorithm::Sgm),
        Just(Algorithm::Planes),
    ];
    let right = prop_oneof![
        pattern().prop_map(Right::Other),
        (0usize..64).prop_map(Right::Shifted)
    ];
    let block = prop_oneof![4 => Just(None), 1 => (0usize..=16).prop_map(Some)];
    let views = (1..=max_w, 1..=max_h, pattern(), right, pattern());
    let refine = prop_oneof![Just(None), refinement().prop_map(Some)];
    (views, algorithm, block, refine).prop_flat_map(
        |((w, h, left, right, labels), algorithm, block, refine)| {
            // max_disp from 1 to the width (the width itself is invalid);
            // min_disp mostly below it, sometimes not.
            (1..=w, 0..=w).prop_map(move |(max_disp, min)| Case {
                w,
                h,
                left,
                right,
                labels,
                algorithm,
                min_disp: if min % 4 == 0 { min } else { min % max_disp },
                max_disp,
                block,
                refine,
            })
        },
    )
}

/// Runs one case; `Err` describes a wrong answer (a panic fails the test
/// on its own).
fn run(case: &Case) -> Result<(), String> {
    let (w, h) = (case.w, case.h);
    let left = case.left.view(w, h);
    let right = match case.right {
        Right::Other(p) => p.view(w, h),
        Right::Shifted(s) => RgbImage::from_fn(w, h, |x, y| left.get((x + s).min(w - 1), y)),
    };
    let labels = case.labels.labels(w, h);
    let range_fits = case.min_disp < case.max_disp && case.max_disp < w;
    let block_fits = case.block.is_none_or(|b| b % 2 == 1 && b <= 15);
    let mut spec = match MatchSpec::new(case.algorithm, case.min_disp, case.max_disp) {
        Ok(spec) => spec,
        Err(StereoError::DisparityRange { .. }) if !range_fits => return Ok(()),
        Err(e) => return Err(format!("MatchSpec::new: {e}")),
    };
    if let Some(refine) = case.refine {
        spec.refine = refine;
    }
    if let Some(b) = case.block {
        spec.block = b;
    }
    // WTA's window sums must fit 16 bits.
    let wta_fits = spec.algorithm != Algorithm::Wta
        || !block_fits
        || spec.block <= WtaParams::max_block(spec.gray_bits);
    match Matcher::new().compute_segmented(&left, &right, Some(&labels), &spec) {
        Ok(d) if range_fits && block_fits && wta_fits && d.dims() == (w, h) => Ok(()),
        Ok(d) => Err(format!("a {:?} map", d.dims())),
        Err(StereoError::DisparityRange { .. }) if !range_fits => Ok(()),
        Err(StereoError::BlockSize(_)) if !block_fits => Ok(()),
        Err(StereoError::Parameter(_)) if !wta_fits => Ok(()),
        Err(e) => Err(format!("error: {e}")),
    }
}

/// `PROPTEST_CASES` when set, else `default`.
fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(64)))]

    /// Small pairs, where the edge cases are (1 px wide or high, ranges
    /// of one disparity, ranges as wide as the view).
    #[test]
    fn small_pairs_give_a_map_or_a_range_error(case in case(40, 24)) {
        prop_assert_eq!(run(&case), Ok(()), "{:?}", case);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(cases(8)))]

    /// A few larger pairs.
    #[test]
    fn larger_pairs_give_a_map_or_a_range_error(case in case(320, 240)) {
        prop_assert_eq!(run(&case), Ok(()), "{:?}", case);
    }
}

/// A noise pair and its right view shifted by 20 px, `w`x`h`.
fn shifted_noise(w: usize, h: usize) -> (RgbImage, RgbImage) {
    let left = Pattern::Noise(7).view(w, h);
    let right = RgbImage::from_fn(w, h, |x, y| left.get((x + 20).min(w - 1), y));
    (left, right)
}

/// Each matcher on a 2000x1500 pair, 8x8 segments for planes. The ranges
/// keep the cost volumes (`w·h·ndisp`) near a gigabyte at most. Measured
/// (release, two busy cores): WTA 0.4 s at 64 disparities, SGM 2.5 s at
/// 128, line growing 3.9 s at 16, planes 3.7 s at 64.
#[test]
fn a_2000x1500_pair_matches_with_every_matcher() {
    let (w, h) = (2000, 1500);
    let (left, right) = shifted_noise(w, h);
    let labels = Pattern::Checkers { side: 8 }.labels(w, h);
    for (algorithm, max_disp) in [
        (Algorithm::Wta, 63),
        (Algorithm::Sgm, 127),
        (Algorithm::LineGrowing, 15),
        (Algorithm::Planes, 63),
    ] {
        let spec = MatchSpec::new(algorithm, 0, max_disp).unwrap();
        let d = Matcher::new()
            .compute_segmented(&left, &right, Some(&labels), &spec)
            .unwrap();
        assert_eq!(d.dims(), (w, h), "{algorithm}");
    }
}

/// Ranges as wide as a 2000 px view: the widest valid one (0..=1999)
/// gives a map, the width itself is a range error ([`run`] checks which).
/// Under 2.5 s.
#[test]
fn ranges_as_wide_as_the_view() {
    for algorithm in [
        Algorithm::Wta,
        Algorithm::LineGrowing,
        Algorithm::Sgm,
        Algorithm::Planes,
    ] {
        for max_disp in [1999, 2000] {
            let case = Case {
                w: 2000,
                h: 12,
                left: Pattern::Noise(7),
                right: Right::Shifted(20),
                labels: Pattern::Noise(3),
                algorithm,
                min_disp: 0,
                max_disp,
                block: None,
                refine: None,
            };
            assert_eq!(run(&case), Ok(()), "{algorithm} 0..={max_disp}");
        }
    }
}
