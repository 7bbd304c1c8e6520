//! A camera's column ripple, found and taken out before matching.
//!
//! Some sensors read alternate columns through different amplifiers, and
//! leave a period-2 pattern across each row: Middlebury's Tsukuba pair has
//! it, and so do cheap webcams. In dark, flat regions it is most of the
//! signal, and a matcher then prefers even shifts, whatever the depth.
//! Census and grey costs both see it.
//!
//! **Detection** ([`column_ripple`]): the horizontal second difference
//! `2·g(x) − g(x−1) − g(x+1)` of a period-2 pattern flips sign at every
//! column, so along rows it alternates far more often than the vertical
//! second difference alternates along columns. The score is the difference
//! of the two rates (opposite signs of adjacent second differences, in
//! [−1, 1]). Of the 20 shared Middlebury left views only Tsukuba scores
//! far above zero.
//!
//! **Removal** ([`suppress_column_ripple`]): the two-tap average
//! `(g(x) + g(x+1)) / 2` along rows cancels a period-2 pattern exactly. It
//! shifts both views by the same half pixel, so disparities are unchanged,
//! and it blurs only the finest horizontal detail. It helps SGM and planes
//! much on Tsukuba, but always on it costs the other scenes: hence
//! [`RippleFilter::Auto`]. The figures are in docs/tuning.md, “Column
//! ripple filter”.

use stereolink_image::GrayImage;

/// When the matchers that work on grey views (SGM, planes) take the column
/// ripple out of both views first.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub enum RippleFilter {
    /// When the left view's [`column_ripple`] exceeds [`RIPPLE_THRESHOLD`].
    #[default]
    Auto,
    /// Always.
    On,
    /// Never.
    Off,
}

/// The [`column_ripple`] score above which [`RippleFilter::Auto`] filters:
/// midway between Tsukuba's score and the highest of the other shared
/// scenes (docs/tuning.md, “Column ripple filter”).
pub const RIPPLE_THRESHOLD: f32 = 0.1;

impl RippleFilter {
    /// Whether to filter a pair whose left view is `left`.
    pub fn applies(self, left: &GrayImage) -> bool {
        match self {
            RippleFilter::Auto => column_ripple(left) > RIPPLE_THRESHOLD,
            RippleFilter::On => true,
            RippleFilter::Off => false,
        }
    }
}

/// How much more often the horizontal second difference alternates in sign
/// along rows than the vertical one along columns, in [−1, 1]: near 0 for
/// natural images, high for a period-2 column pattern. 0 for images under
/// 4 pixels on a side.
pub fn column_ripple(gray: &GrayImage) -> f32 {
    let (w, h) = gray.dims();
    if w < 4 || h < 4 {
        return 0.0;
    }
    // Second differences of rows a, b, c at each column (b the middle),
    // and the sign flips between two such lines; row-major, so that both
    // passes stream through memory.
    let second = |a: &[u8], b: &[u8], c: &[u8], out: &mut [i16]| {
        for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
            *o = 2 * i16::from(b) - i16::from(a) - i16::from(c);
        }
    };
    let flips = |d0: &[i16], d1: &[i16]| -> u64 {
        d0.iter()
            .zip(d1)
            .map(|(&a, &b)| u64::from(i32::from(a) * i32::from(b) < 0))
            .sum()
    };
    let rows: Vec<&[u8]> = gray.as_slice().chunks_exact(w).collect();
    let mut along_rows = 0u64;
    let mut d = vec![0i16; w - 2];
    for row in &rows {
        second(row, &row[1..], &row[2..], &mut d);
        along_rows += flips(&d[..w - 3], &d[1..]);
    }
    let mut along_columns = 0u64;
    let (mut prev, mut cur) = (vec![0i16; w], vec![0i16; w]);
    second(rows[0], rows[1], rows[2], &mut prev);
    for t in rows.windows(3).skip(1) {
        second(t[0], t[1], t[2], &mut cur);
        along_columns += flips(&prev, &cur);
        std::mem::swap(&mut prev, &mut cur);
    }
    let row_pairs = (h * (w - 3)) as f32;
    let column_pairs = (w * (h - 3)) as f32;
    along_rows as f32 / row_pairs - along_columns as f32 / column_pairs
}

/// The view with `(g(x) + g(x+1)) / 2` (rounded) at each pixel; the last
/// column keeps its value.
pub fn suppress_column_ripple(gray: &GrayImage) -> GrayImage {
    let mut out = gray.clone();
    let w = gray.width();
    for (src, dst) in gray
        .as_slice()
        .chunks_exact(w)
        .zip(out.as_mut_slice().chunks_exact_mut(w))
    {
        for (d, pair) in dst.iter_mut().zip(src.windows(2)) {
            *d = (u16::from(pair[0]) + u16::from(pair[1])).div_ceil(2) as u8;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereolink_image::synth::{synthesize, SynthSpec};

    fn textured() -> GrayImage {
        let scene = synthesize(&SynthSpec {
            width: 96,
            height: 64,
            max_disp: 8,
            seed: 5,
        })
        .unwrap();
        stereolink_image::color::rgb_to_gray(&scene.left)
    }

    fn with_ripple(g: &GrayImage, amplitude: i16) -> GrayImage {
        let mut out = g.clone();
        let w = g.width();
        for (p, v) in out.as_mut_slice().iter_mut().enumerate() {
            let sign = if p % w % 2 == 0 { 1 } else { -1 };
            *v = (i16::from(*v) + sign * amplitude).clamp(0, 255) as u8;
        }
        out
    }

    #[test]
    fn a_period_two_column_pattern_scores_high_and_a_scene_without_it_low() {
        let clean = textured();
        let clean_score = column_ripple(&clean);
        let rippled = column_ripple(&with_ripple(&clean, 6));
        assert!(clean_score.abs() < RIPPLE_THRESHOLD, "clean {clean_score}");
        assert!(rippled > RIPPLE_THRESHOLD, "rippled {rippled}");
        assert!(RippleFilter::Auto.applies(&with_ripple(&clean, 6)));
        assert!(!RippleFilter::Auto.applies(&clean));
        assert!(RippleFilter::On.applies(&clean));
        assert!(!RippleFilter::Off.applies(&with_ripple(&clean, 6)));
    }

    #[test]
    fn the_two_tap_average_cancels_the_ripple_exactly() {
        let clean = textured();
        let a = suppress_column_ripple(&clean);
        let b = suppress_column_ripple(&with_ripple(&clean, 6));
        // Clamping at 0 and 255 aside, the pattern's +a and −a cancel in
        // every column but the last, which has no right neighbour.
        let w = clean.width();
        let differ = (a.as_slice().iter().zip(b.as_slice()).enumerate())
            .filter(|(p, (x, y))| p % w + 1 < w && x != y)
            .count();
        assert!(differ * 100 < a.as_slice().len(), "{differ} pixels differ");
        assert_eq!(a.as_slice()[95], clean.as_slice()[95], "last column kept");
    }

    #[test]
    fn tiny_and_flat_images_score_zero() {
        assert_eq!(column_ripple(&GrayImage::new(3, 3, 7)), 0.0);
        assert_eq!(column_ripple(&GrayImage::new(16, 16, 7)), 0.0);
    }
}
