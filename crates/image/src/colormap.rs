//! Colour maps that make disparity maps readable, and a colour bar to go with them.

use crate::{DisparityMap, Plane, Rgb, RgbImage};

/// The colour for invalid (infinite or NaN) disparities.
pub const INVALID: Rgb = [0, 0, 0];

/// The "turbo" colour map (Mikhailov 2019, Google AI blog), as its published
/// polynomial fit: blue for `t = 0` (far), red for `t = 1` (near).
pub fn turbo(t: f32) -> Rgb {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } as f64;
    let (t2, t3, t4, t5) = (t * t, t * t * t, t.powi(4), t.powi(5));
    let r = 0.135_721_38 + 4.615_392_6 * t - 42.660_322_6 * t2 + 132.131_082_9 * t3
        - 152.942_393_9 * t4
        + 59.286_379_8 * t5;
    let g = 0.091_402_61 + 2.194_188_39 * t + 4.842_966_58 * t2 - 14.185_033_8 * t3
        + 4.277_298_57 * t4
        + 2.829_566_04 * t5;
    let b = 0.106_673_3 + 12.641_946_08 * t - 60.582_048_6 * t2 + 110.362_767_1 * t3
        - 89.903_109_8 * t4
        + 27.348_249_5 * t5;
    [r, g, b].map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// [`turbo`] at 256 steps (entry `i` is `turbo(i / 255)`), computed once:
/// a table for painting many pixels (the receiver's screen) cheaply.
pub fn turbo_table() -> &'static [Rgb; 256] {
    static TABLE: std::sync::OnceLock<[Rgb; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| turbo(i as f32 / 255.0)))
}

/// The index of the [`turbo_table`] entry nearest to `t` (clamped to
/// `[0, 1]`; NaN is 0).
#[inline]
pub fn turbo_index(t: f32) -> usize {
    // `as` saturates: negative and NaN give 0.
    ((t * 255.0 + 0.5) as usize).min(255)
}

/// Paints a disparity map with [`turbo`] over `[min, max]`; invalid pixels are [`INVALID`].
pub fn colorize(map: &DisparityMap, min: f32, max: f32) -> RgbImage {
    let span = (max - min).max(f32::EPSILON);
    map.map(|d| {
        if d.is_finite() {
            turbo((d - min) / span)
        } else {
            INVALID
        }
    })
}

/// The finite range of a disparity map, or `None` if it has no finite value.
pub fn finite_range(map: &DisparityMap) -> Option<(f32, f32)> {
    map.as_slice()
        .iter()
        .filter(|d| d.is_finite())
        .fold(None, |acc, &d| match acc {
            None => Some((d, d)),
            Some((lo, hi)) => Some((lo.min(d), hi.max(d))),
        })
}

/// Paints `map` over `[min, max]` and appends a vertical colour bar on the right
/// (`max` at the top, `min` at the bottom, a tick every quarter).
pub fn colorize_with_bar(map: &DisparityMap, min: f32, max: f32) -> RgbImage {
    let body = colorize(map, min, max);
    let (w, h) = body.dims();
    let (gap, bar) = (4, 16.max(w / 32));
    Plane::from_fn(w + gap + bar, h, |x, y| {
        if x < w {
            body.get(x, y)
        } else if x < w + gap {
            [255, 255, 255]
        } else {
            let t = 1.0 - y as f32 / (h.max(2) - 1) as f32;
            let tick =
                h >= 8 && (0..=4).any(|q| y == q * (h - 1) / 4) && x >= w + gap + bar * 2 / 3;
            if tick {
                [255, 255, 255]
            } else {
                turbo(t)
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_ends_are_blue_and_red() {
        let lo = turbo(0.1);
        let hi = turbo(0.9);
        assert!(lo[2] > lo[0], "{lo:?}");
        assert!(hi[0] > hi[2], "{hi:?}");
        assert_eq!(turbo(f32::NAN), turbo(0.0));
        let table = turbo_table();
        assert_eq!(table[turbo_index(f32::NAN)], turbo(0.0));
        assert_eq!(table[turbo_index(-3.0)], turbo(0.0));
        assert_eq!(table[turbo_index(7.0)], turbo(1.0));
        assert_eq!(table[turbo_index(0.5)], turbo(128.0 / 255.0));
    }

    #[test]
    fn invalid_pixels_are_black_and_bar_is_appended() {
        let map = Plane::from_vec(2, 1, vec![1.0, f32::INFINITY]).unwrap();
        let c = colorize(&map, 0.0, 2.0);
        assert_eq!(c.get(1, 0), INVALID);
        assert_eq!(finite_range(&map), Some((1.0, 1.0)));
        let with_bar = colorize_with_bar(&map, 0.0, 2.0);
        assert!(with_bar.width() > 2 && with_bar.height() == 1);
    }
}
