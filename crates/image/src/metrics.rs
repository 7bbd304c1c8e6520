//! Image-quality and accuracy measures: MSE and PSNR (the paper's Table IV),
//! compression figures, and Middlebury bad-pixel scoring.

use serde::Serialize;

use crate::{DisparityMap, Mask, Result, RgbImage};

/// PSNR in decibels, per channel and over all channels (8-bit peak, 255).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Psnr {
    /// PSNR of the R, G and B channels; infinite for identical channels.
    pub channels: [f64; 3],
    /// PSNR of the mean squared error over all three channels.
    pub overall: f64,
}

/// Mean squared error per channel between two RGB images of equal size.
pub fn mse_rgb(a: &RgbImage, b: &RgbImage) -> Result<[f64; 3]> {
    a.check_same_size(b, "second image")?;
    let mut sums = [0u64; 3];
    for (p, q) in a.as_slice().iter().zip(b.as_slice()) {
        for c in 0..3 {
            let d = p[c] as i64 - q[c] as i64;
            sums[c] += (d * d) as u64;
        }
    }
    let n = a.len().max(1) as f64;
    Ok(sums.map(|s| s as f64 / n))
}

/// PSNR = 10·log10(255² / MSE), in dB; infinite when the images are equal.
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// PSNR of `test` against `reference`, per channel and overall.
pub fn psnr_rgb(reference: &RgbImage, test: &RgbImage) -> Result<Psnr> {
    let mse = mse_rgb(reference, test)?;
    Ok(Psnr {
        channels: mse.map(psnr_from_mse),
        overall: psnr_from_mse(mse.iter().sum::<f64>() / 3.0),
    })
}

/// PSNR of a stereo pair: both views against their references, one mean
/// squared error over all their samples (views of equal size).
pub fn psnr_pair(
    (left_ref, right_ref): (&RgbImage, &RgbImage),
    (left, right): (&RgbImage, &RgbImage),
) -> Result<f64> {
    let (l, r) = (mse_rgb(left_ref, left)?, mse_rgb(right_ref, right)?);
    left_ref.check_same_size(right_ref, "right view")?;
    Ok(psnr_from_mse(l.iter().chain(&r).sum::<f64>() / 6.0))
}

/// Compression ratio: `original / compressed` (infinite for an empty output).
pub fn compression_ratio(original_bytes: usize, compressed_bytes: usize) -> f64 {
    original_bytes as f64 / compressed_bytes as f64
}

/// Percentage size reduction: `100 · (1 − compressed / original)`, as the paper's Fig. 12.
pub fn reduction_percent(original_bytes: usize, compressed_bytes: usize) -> f64 {
    100.0 * (1.0 - compressed_bytes as f64 / original_bytes as f64)
}

/// The Middlebury bad-pixel thresholds, in pixels.
pub const THRESHOLDS: [f32; 3] = [0.5, 1.0, 2.0];

/// Percentage of bad pixels: `|d − gt| > threshold` over the pixels where `mask`
/// is true (all pixels if `None`) and the ground truth is known (finite).
///
/// An invalid (non-finite) estimate counts as bad. Returns `None` when no pixel
/// is evaluated. Sizes must agree (callers check with
/// [`crate::Plane::check_same_size`]); a mismatch evaluates nothing.
pub fn bad_pixel_rate(
    estimate: &DisparityMap,
    ground_truth: &DisparityMap,
    mask: Option<&Mask>,
    threshold: f32,
) -> Option<f64> {
    if estimate.dims() != ground_truth.dims() || mask.is_some_and(|m| m.dims() != estimate.dims()) {
        return None;
    }
    let (mut bad, mut total) = (0usize, 0usize);
    for (i, (&d, &gt)) in estimate
        .as_slice()
        .iter()
        .zip(ground_truth.as_slice())
        .enumerate()
    {
        if !gt.is_finite() || mask.is_some_and(|m| !m.as_slice()[i]) {
            continue;
        }
        total += 1;
        if !d.is_finite() || (d - gt).abs() > threshold {
            bad += 1;
        }
    }
    (total > 0).then(|| 100.0 * bad as f64 / total as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Plane;

    #[test]
    fn pair_psnr_is_one_mse_over_both_views() {
        let a = Plane::new(4, 2, [100u8, 100, 100]);
        let b = Plane::new(4, 2, [110u8, 100, 100]);
        // Left off by 10 in one channel, right exact: MSE 100 / 6.
        let p = psnr_pair((&a, &a), (&b, &a)).unwrap();
        assert!((p - psnr_from_mse(100.0 / 6.0)).abs() < 1e-9, "{p}");
        assert!(psnr_pair((&a, &a), (&b, &Plane::new(3, 2, [0; 3]))).is_err());
    }

    #[test]
    fn psnr_of_known_error() {
        let a = RgbImage::new(4, 4, [100, 100, 100]);
        let b = RgbImage::new(4, 4, [110, 100, 100]);
        let p = psnr_rgb(&a, &b).unwrap();
        assert!((p.channels[0] - 10.0 * (65025.0f64 / 100.0).log10()).abs() < 1e-9);
        assert!(p.channels[1].is_infinite());
        assert!((p.overall - 10.0 * (65025.0f64 / (100.0 / 3.0)).log10()).abs() < 1e-9);
        assert!(psnr_rgb(&a, &RgbImage::new(3, 4, [0; 3])).is_err());
    }

    #[test]
    fn compression_figures() {
        assert_eq!(compression_ratio(1000, 250), 4.0);
        assert_eq!(reduction_percent(1000, 250), 75.0);
    }

    /// A hand-computed case: 3x2 estimate against ground truth with one unknown
    /// pixel, one invalid estimate and a mask that drops one pixel.
    #[test]
    fn bad_pixels_hand_computed() {
        let inf = f32::INFINITY;
        let gt = Plane::from_vec(3, 2, vec![10.0, 10.0, inf, 5.0, 5.0, 5.0]).unwrap();
        let est = Plane::from_vec(3, 2, vec![10.4, 11.5, 3.0, inf, 5.0, 7.1]).unwrap();
        // Evaluated: (0,0) err .4, (1,0) err 1.5, (0,1) invalid, (1,1) err 0, (2,1) err 2.1.
        assert_eq!(bad_pixel_rate(&est, &gt, None, 0.5), Some(60.0));
        assert_eq!(bad_pixel_rate(&est, &gt, None, 1.0), Some(60.0));
        assert_eq!(bad_pixel_rate(&est, &gt, None, 2.0), Some(40.0));
        assert_eq!(bad_pixel_rate(&est, &gt, None, 0.3), Some(80.0));
        let mask = Plane::from_vec(3, 2, vec![true, true, true, false, true, true]).unwrap();
        assert_eq!(bad_pixel_rate(&est, &gt, Some(&mask), 1.0), Some(50.0));
        let none = Plane::new(3, 2, false);
        assert_eq!(bad_pixel_rate(&est, &gt, Some(&none), 1.0), None);
    }
}
