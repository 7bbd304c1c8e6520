//! Colour conversions: RGB ↔ gray ↔ CIE L\*u\*v\* (D65 white, sRGB primaries).
//!
//! Mean shift clusters in L\*u\*v\* because Euclidean distances there follow
//! perceived colour differences (Comaniciu & Meer 2002, §4).

use crate::{GrayImage, Plane, Rgb, RgbImage};

/// Gray value of an RGB pixel: ITU-R BT.601 luma, `(77 R + 150 G + 29 B + 128) >> 8`.
#[inline]
pub fn luma(p: Rgb) -> u8 {
    ((77 * p[0] as u32 + 150 * p[1] as u32 + 29 * p[2] as u32 + 128) >> 8) as u8
}

/// Converts an RGB image to gray with [`luma`].
pub fn rgb_to_gray(img: &RgbImage) -> GrayImage {
    img.map(luma)
}

/// [`rgb_to_gray`] into `out` (resized, storage reused).
pub fn rgb_to_gray_into(img: &RgbImage, out: &mut GrayImage) {
    img.map_into(out, luma);
}

/// Replicates a gray image into three equal channels.
pub fn gray_to_rgb(img: &GrayImage) -> RgbImage {
    img.map(|g| [g, g, g])
}

/// One channel of an RGB image (0 = R, 1 = G, 2 = B).
///
/// # Panics
/// If `channel > 2`.
pub fn channel(img: &RgbImage, channel: usize) -> GrayImage {
    assert!(channel < 3, "channel {channel} does not exist");
    img.map(|p| p[channel])
}

/// A CIE L\*u\*v\* colour: `L` in 0..=100, `u` and `v` roughly in −100..=180.
pub type Luv = [f32; 3];

const WHITE_X: f32 = 0.950_47;
const WHITE_Y: f32 = 1.0;
const WHITE_Z: f32 = 1.088_83;
const EPSILON: f32 = 216.0 / 24389.0;
const KAPPA: f32 = 24389.0 / 27.0;

fn white_uv() -> (f32, f32) {
    let d = WHITE_X + 15.0 * WHITE_Y + 3.0 * WHITE_Z;
    (4.0 * WHITE_X / d, 9.0 * WHITE_Y / d)
}

fn srgb_to_linear(c: u8) -> f32 {
    let c = c as f32 / 255.0;
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn linear_to_srgb(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

/// Converts an sRGB pixel to L\*u\*v\*.
pub fn rgb_to_luv(p: Rgb) -> Luv {
    let [r, g, b] = p.map(srgb_to_linear);
    let x = 0.412_456_4 * r + 0.357_576_1 * g + 0.180_437_5 * b;
    let y = 0.212_672_9 * r + 0.715_152_2 * g + 0.072_175 * b;
    let z = 0.019_333_9 * r + 0.119_192 * g + 0.950_304_1 * b;
    let yr = y / WHITE_Y;
    let l = if yr > EPSILON {
        116.0 * yr.cbrt() - 16.0
    } else {
        KAPPA * yr
    };
    let d = x + 15.0 * y + 3.0 * z;
    if d <= 0.0 {
        return [l, 0.0, 0.0];
    }
    let (un, vn) = white_uv();
    let (up, vp) = (4.0 * x / d, 9.0 * y / d);
    [l, 13.0 * l * (up - un), 13.0 * l * (vp - vn)]
}

/// Converts L\*u\*v\* back to the nearest sRGB pixel (out-of-gamut values are clamped).
pub fn luv_to_rgb(c: Luv) -> Rgb {
    let [l, u, v] = c;
    if l <= 0.0 {
        return [0, 0, 0];
    }
    let (un, vn) = white_uv();
    let up = u / (13.0 * l) + un;
    let vp = v / (13.0 * l) + vn;
    let y = if l > KAPPA * EPSILON {
        ((l + 16.0) / 116.0).powi(3)
    } else {
        l / KAPPA
    } * WHITE_Y;
    let x = y * 9.0 * up / (4.0 * vp);
    let z = y * (12.0 - 3.0 * up - 20.0 * vp) / (4.0 * vp);
    let r = 3.240_454_2 * x - 1.537_138_5 * y - 0.498_531_4 * z;
    let g = -0.969_266 * x + 1.876_010_8 * y + 0.041_556 * z;
    let b = 0.055_643_4 * x - 0.204_025_9 * y + 1.057_225_2 * z;
    [linear_to_srgb(r), linear_to_srgb(g), linear_to_srgb(b)]
}

/// Converts a whole image to L\*u\*v\*.
pub fn rgb_image_to_luv(img: &RgbImage) -> Plane<Luv> {
    img.map(rgb_to_luv)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_of_primaries() {
        assert_eq!(luma([255, 255, 255]), 255);
        assert_eq!(luma([0, 0, 0]), 0);
        assert_eq!(luma([255, 0, 0]), 77);
    }

    #[test]
    fn luv_of_white_and_black() {
        let w = rgb_to_luv([255, 255, 255]);
        assert!(
            (w[0] - 100.0).abs() < 0.01 && w[1].abs() < 0.05 && w[2].abs() < 0.05,
            "{w:?}"
        );
        assert_eq!(rgb_to_luv([0, 0, 0]), [0.0, 0.0, 0.0]);
        // A reference value: sRGB red is L*u*v* (53.24, 175.01, 37.76).
        let r = rgb_to_luv([255, 0, 0]);
        assert!(
            (r[0] - 53.24).abs() < 0.05
                && (r[1] - 175.01).abs() < 0.2
                && (r[2] - 37.76).abs() < 0.2,
            "{r:?}"
        );
    }

    #[test]
    fn luv_round_trips_every_gray_and_a_colour_grid() {
        for g in 0..=255u8 {
            assert_eq!(luv_to_rgb(rgb_to_luv([g, g, g])), [g, g, g]);
        }
        for r in (0..=255u8).step_by(17) {
            for g in (0..=255u8).step_by(17) {
                for b in (0..=255u8).step_by(17) {
                    let back = luv_to_rgb(rgb_to_luv([r, g, b]));
                    for c in 0..3 {
                        assert!(
                            (back[c] as i32 - [r, g, b][c] as i32).abs() <= 1,
                            "{r} {g} {b} -> {back:?}"
                        );
                    }
                }
            }
        }
    }
}
