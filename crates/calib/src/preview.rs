//! A rectified pair side by side with horizontal guide lines: after a good
//! calibration every feature crosses to the other view along the same
//! line, so a person sees a bad one at a glance (`rectify --guides`,
//! `calibrate`).

use stereolink_image::{Rgb, RgbImage};

/// The guide lines' colour: green, seen on most scenes.
pub const GUIDE: Rgb = [0, 255, 0];

/// `left` and `right` side by side (black below the shorter one), with a
/// [`GUIDE`] line across both every `spacing` rows from row 0 (none when
/// `spacing` is 0).
pub fn side_by_side_with_guides(left: &RgbImage, right: &RgbImage, spacing: usize) -> RgbImage {
    let (lw, rw) = (left.width(), right.width());
    let height = left.height().max(right.height());
    let mut out = RgbImage::new(lw + rw, height, [0; 3]);
    for y in 0..height {
        let row = out.row_mut(y);
        if spacing > 0 && y % spacing == 0 {
            row.fill(GUIDE);
            continue;
        }
        let (a, b) = row.split_at_mut(lw);
        if y < left.height() {
            a.copy_from_slice(left.row(y));
        }
        if y < right.height() {
            b.copy_from_slice(right.row(y));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_sit_side_by_side_under_guides() {
        let left = RgbImage::from_fn(5, 70, |x, y| [x as u8, y as u8, 1]);
        let right = RgbImage::from_fn(3, 40, |x, y| [x as u8, y as u8, 2]);
        let p = side_by_side_with_guides(&left, &right, 32);
        assert_eq!(p.dims(), (8, 70));
        for y in [0, 32, 64] {
            assert!(p.row(y).iter().all(|&c| c == GUIDE), "row {y}");
        }
        assert_eq!(p.get(4, 33), [4, 33, 1]);
        assert_eq!(p.get(6, 33), [1, 33, 2]);
        assert_eq!(p.get(6, 50), [0; 3]);
        assert_eq!(
            side_by_side_with_guides(&left, &right, 0).get(0, 0),
            [0, 0, 1]
        );
    }
}
