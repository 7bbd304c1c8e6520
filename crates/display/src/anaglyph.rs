//! Red-cyan anaglyphs and side-by-side pairs.
//!
//! The Dubois mode is Eric Dubois' least-squares projection for red-cyan
//! glasses ("A projection method to generate anaglyph stereo images",
//! ICASSP 2001), applied to the 8-bit values; the others are the classic
//! colour (R from the left view, G and B from the right), half-colour (left
//! in gray), and gray anaglyphs.

use std::str::FromStr;

use stereolink_image::{color::luma, Plane, Rgb, RgbImage};

/// Anaglyph modes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Anaglyph {
    /// Dubois least-squares (least retinal rivalry, good colour).
    Dubois,
    /// Full colour: R from the left, G and B from the right.
    Colour,
    /// Half colour: left in gray on R, right in colour on G and B.
    HalfColour,
    /// Gray: both views in gray.
    Gray,
}

impl FromStr for Anaglyph {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "dubois" => Ok(Anaglyph::Dubois),
            "colour" | "color" => Ok(Anaglyph::Colour),
            "half" | "half-colour" | "half-color" => Ok(Anaglyph::HalfColour),
            "gray" | "grey" => Ok(Anaglyph::Gray),
            _ => Err(format!(
                "unknown anaglyph {s:?}: use dubois, colour, half or gray"
            )),
        }
    }
}

const DUBOIS_LEFT: [[f32; 3]; 3] = [
    [0.456, 0.500, 0.176],
    [-0.040, -0.038, -0.016],
    [-0.015, -0.021, -0.005],
];
const DUBOIS_RIGHT: [[f32; 3]; 3] = [
    [-0.043, -0.088, -0.002],
    [0.378, 0.734, -0.018],
    [-0.072, -0.113, 1.226],
];

/// One anaglyph pixel.
#[inline]
pub fn anaglyph_pixel(l: [u8; 3], r: [u8; 3], mode: Anaglyph) -> [u8; 3] {
    match mode {
        Anaglyph::Dubois => {
            let (lf, rf) = (l.map(f32::from), r.map(f32::from));
            let row = |i: usize| {
                let v: f32 = (0..3)
                    .map(|k| DUBOIS_LEFT[i][k] * lf[k] + DUBOIS_RIGHT[i][k] * rf[k])
                    .sum();
                v.round().clamp(0.0, 255.0) as u8
            };
            [row(0), row(1), row(2)]
        }
        Anaglyph::Colour => [l[0], r[1], r[2]],
        Anaglyph::HalfColour => [luma(l), r[1], r[2]],
        Anaglyph::Gray => {
            let g = luma(r);
            [luma(l), g, g]
        }
    }
}

/// The anaglyph of a pair of equal size.
///
/// # Panics
/// If the views differ in size.
pub fn anaglyph(left: &RgbImage, right: &RgbImage, mode: Anaglyph) -> RgbImage {
    let mut out = RgbImage::default();
    anaglyph_into(left, right, mode, &mut out);
    out
}

/// [`anaglyph`] into `out` (resized, storage reused).
///
/// # Panics
/// If the views differ in size.
pub fn anaglyph_into(left: &RgbImage, right: &RgbImage, mode: Anaglyph, out: &mut RgbImage) {
    assert_eq!(left.dims(), right.dims(), "views differ in size");
    out.reset(left.width(), left.height(), [0; 3]);
    let pixels = left.as_slice().iter().zip(right.as_slice());
    // A segmented pair has few distinct colour pairs: remember them in a
    // small direct-mapped cache (exact: a miss computes the pixel).
    let mut cache: [Option<(Rgb, Rgb, Rgb)>; 64] = [None; 64];
    for (o, (&l, &r)) in out.as_mut_slice().iter_mut().zip(pixels) {
        let slot = &mut cache[colour_pair_hash(l, r)];
        *o = match *slot {
            Some((cl, cr, v)) if (cl, cr) == (l, r) => v,
            _ => {
                let v = anaglyph_pixel(l, r, mode);
                *slot = Some((l, r, v));
                v
            }
        };
    }
}

/// A slot in `0..64` for a colour pair.
#[inline]
fn colour_pair_hash(l: Rgb, r: Rgb) -> usize {
    let key = u64::from_le_bytes([l[0], l[1], l[2], r[0], r[1], r[2], 0, 0]);
    (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as usize
}

/// The two views next to each other (left, then right), as the paper concatenates them.
///
/// # Panics
/// If the views differ in height.
pub fn side_by_side(left: &RgbImage, right: &RgbImage) -> RgbImage {
    assert_eq!(left.height(), right.height(), "views differ in height");
    let w = left.width();
    Plane::from_fn(w + right.width(), left.height(), |x, y| {
        if x < w {
            left.get(x, y)
        } else {
            right.get(x - w, y)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channels_come_from_the_right_view() {
        let l = RgbImage::new(2, 1, [200, 10, 20]);
        let r = RgbImage::new(2, 1, [30, 150, 250]);
        assert_eq!(
            anaglyph(&l, &r, Anaglyph::Colour).get(0, 0),
            [200, 150, 250]
        );
        assert_eq!(
            anaglyph(&l, &r, Anaglyph::HalfColour).get(1, 0),
            [luma([200, 10, 20]), 150, 250]
        );
        let d = anaglyph(&l, &r, Anaglyph::Dubois).get(0, 0);
        assert!(d[0] > 80 && d[2] > 200, "{d:?}");
        assert_eq!(side_by_side(&l, &r).dims(), (4, 1));
        assert_eq!("half".parse::<Anaglyph>(), Ok(Anaglyph::HalfColour));
        assert!("x".parse::<Anaglyph>().is_err());
    }

    #[test]
    fn white_stays_bright_in_every_mode() {
        for m in [
            Anaglyph::Dubois,
            Anaglyph::Colour,
            Anaglyph::HalfColour,
            Anaglyph::Gray,
        ] {
            let p = anaglyph_pixel([255; 3], [255; 3], m);
            assert!(p.iter().all(|&c| c > 200), "{m:?}: {p:?}");
        }
    }
}
