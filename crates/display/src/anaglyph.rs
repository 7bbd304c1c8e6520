//! Red-cyan anaglyphs and side-by-side pairs.
//!
//! The Dubois mode is Eric Dubois' least-squares projection for red-cyan
//! glasses ("A projection method to generate anaglyph stereo images",
//! ICASSP 2001), applied to the 8-bit values in fixed point (weights in
//! 1/65536, for a CPU without an FPU: at most one level from the `f32`
//! product, see the tests); the others are the classic
//! colour (R from the left view, G and B from the right), half-colour (left
//! in gray), and gray anaglyphs.

use std::str::FromStr;

use stereolink_image::{color::luma, LabelMap, Plane, Rgb, RgbImage};

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

/// Dubois' matrices (his paper's `f32` values, kept as the definition).
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

/// A matrix in 1/65536 (its entries rounded).
const fn fixed(m: [[f32; 3]; 3]) -> [[i32; 3]; 3] {
    let mut out = [[0; 3]; 3];
    let mut i = 0;
    while i < 9 {
        let w = m[i / 3][i % 3] * 65536.0;
        out[i / 3][i % 3] = if w < 0.0 {
            (w - 0.5) as i32
        } else {
            (w + 0.5) as i32
        };
        i += 1;
    }
    out
}
const DUBOIS_LEFT_Q16: [[i32; 3]; 3] = fixed(DUBOIS_LEFT);
const DUBOIS_RIGHT_Q16: [[i32; 3]; 3] = fixed(DUBOIS_RIGHT);

/// One anaglyph pixel.
#[inline]
pub fn anaglyph_pixel(l: [u8; 3], r: [u8; 3], mode: Anaglyph) -> [u8; 3] {
    match mode {
        Anaglyph::Dubois => {
            // |Σ w · 255| < 2^31 in 1/65536; +1/2 and a floor shift round.
            let row = |i: usize| {
                let v: i32 = (0..3)
                    .map(|k| {
                        DUBOIS_LEFT_Q16[i][k] * l[k] as i32 + DUBOIS_RIGHT_Q16[i][k] * r[k] as i32
                    })
                    .sum();
                ((v + (1 << 15)) >> 16).clamp(0, 255) as u8
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
    // Every pixel is written below: an image of the size is not cleared.
    if out.dims() != left.dims() {
        out.reset(left.width(), left.height(), [0; 3]);
    }
    let pixels = left.as_slice().iter().zip(right.as_slice());
    // A segmented pair has few distinct colour pairs, in long runs: the
    // previous pixel's pair is tried first, then a small direct-mapped
    // cache (exact: a miss computes the pixel).
    let mut cache: [Option<(Rgb, Rgb, Rgb)>; 64] = [None; 64];
    let mut last: Option<(Rgb, Rgb, Rgb)> = None;
    for (o, (&l, &r)) in out.as_mut_slice().iter_mut().zip(pixels) {
        *o = match last {
            Some((cl, cr, v)) if (cl, cr) == (l, r) => v,
            _ => {
                let slot = &mut cache[colour_pair_hash(l, r)];
                let v = match *slot {
                    Some((cl, cr, v)) if (cl, cr) == (l, r) => v,
                    _ => anaglyph_pixel(l, r, mode),
                };
                *slot = Some((l, r, v));
                last = *slot;
                v
            }
        };
    }
}

/// Most label pairs [`anaglyph_labels_into`] tabulates (two palettes of
/// 256 colours).
const MAX_PAIRS: usize = 1 << 16;

/// [`anaglyph_into`] for a pair of label maps and their palettes. A
/// segmented pair has few colours: the anaglyph pixel of each pair of
/// labels that occurs is computed once into `pairs` (scratch, resized,
/// storage reused), then a pixel is a lookup. Palettes with more than
/// [`MAX_PAIRS`] pairs compute every pixel.
///
/// # Panics
/// If the maps differ in size or a label does not index its palette.
pub fn anaglyph_labels_into(
    left: (&LabelMap, &[Rgb]),
    right: (&LabelMap, &[Rgb]),
    mode: Anaglyph,
    pairs: &mut Vec<u32>,
    out: &mut RgbImage,
) {
    let (w, h) = left.0.dims();
    anaglyph_labels_shown_into(left, right, mode, (0..h, 0..w), pairs, out);
}

/// [`anaglyph_labels_into`] at the pixels of `rows` x `cols` only (the
/// pixels a scaled blit reads, see [`Screen::view_shown`]): the other
/// pixels of `out` (resized, storage reused) are left as they were. A
/// row repeated in `rows` is computed once.
///
/// [`Screen::view_shown`]: crate::Screen::view_shown
///
/// # Panics
/// If the maps differ in size, a row or column is beyond them, or a label
/// does not index its palette.
pub fn anaglyph_labels_shown_into(
    (left, lp): (&LabelMap, &[Rgb]),
    (right, rp): (&LabelMap, &[Rgb]),
    mode: Anaglyph,
    (rows, cols): (
        impl Iterator<Item = usize>,
        impl Iterator<Item = usize> + Clone,
    ),
    pairs: &mut Vec<u32>,
    out: &mut RgbImage,
) {
    assert_eq!(left.dims(), right.dims(), "views differ in size");
    if out.dims() != left.dims() {
        out.reset(left.width(), left.height(), [0; 3]);
    }
    let (nr, n) = (rp.len(), lp.len() * rp.len());
    let table = n <= MAX_PAIRS;
    if table {
        // Pair `l · nr + r`: the pixel's bytes and a 1 above them, 0 until
        // computed (a left label beyond its palette is beyond the table).
        pairs.clear();
        pairs.resize(n, 0);
    }
    let mut last = None;
    for y in rows {
        if last == Some(y) {
            continue;
        }
        last = Some(y);
        let (lr, rr, o) = (left.row(y), right.row(y), out.row_mut(y));
        for x in cols.clone() {
            let (l, r) = (lr[x] as usize, rr[x] as usize);
            o[x] = if table {
                assert!(r < nr, "right label {r} beyond its palette");
                let pair = &mut pairs[l * nr + r];
                if *pair == 0 {
                    let [a, b, c] = anaglyph_pixel(lp[l], rp[r], mode);
                    *pair = u32::from_le_bytes([a, b, c, 1]);
                }
                let [a, b, c, _] = pair.to_le_bytes();
                [a, b, c]
            } else {
                anaglyph_pixel(lp[l], rp[r], mode)
            };
        }
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

    /// Through label pairs, as from the views: small palettes (the table)
    /// and large ones (per pixel), in every mode.
    #[test]
    fn labels_give_the_anaglyph_of_their_colours() {
        let colour = |i: usize| {
            [
                (i * 37) as u8,
                (255 - i * 29 % 256) as u8,
                (i * i * 5) as u8,
            ]
        };
        for (nl, nr) in [(3, 4), (300, 260)] {
            let (lp, rp): (Vec<Rgb>, Vec<Rgb>) = (
                (0..nl).map(colour).collect(),
                (0..nr).map(|i| colour(i + 7)).collect(),
            );
            let left = LabelMap::from_fn(31, 17, |x, y| ((x * 7 + y * 13) % nl) as u16);
            let right = LabelMap::from_fn(31, 17, |x, y| ((x * 5 + y * y) % nr) as u16);
            let (l, r) = (left.map(|i| lp[i as usize]), right.map(|i| rp[i as usize]));
            let (mut pairs, mut out) = (Vec::new(), RgbImage::default());
            for mode in [
                Anaglyph::Dubois,
                Anaglyph::Colour,
                Anaglyph::HalfColour,
                Anaglyph::Gray,
            ] {
                anaglyph_labels_into((&left, &lp), (&right, &rp), mode, &mut pairs, &mut out);
                assert_eq!(out, anaglyph(&l, &r, mode), "{nl}x{nr} {mode:?}");
            }
        }
    }

    /// At the pixels a screen shows only: those equal the full anaglyph's,
    /// for views scaled down and up, with small and large palettes.
    #[test]
    fn shown_pixels_are_the_anaglyphs() {
        let colour = |i: usize| [(i * 37) as u8, (i * 11) as u8, (i * i * 5) as u8];
        for ((w, h), (nl, nr)) in [
            ((640, 480), (3, 4)),
            ((97, 41), (300, 260)),
            ((9, 5), (5, 6)),
        ] {
            let (lp, rp): (Vec<Rgb>, Vec<Rgb>) = (
                (0..nl).map(colour).collect(),
                (0..nr).map(|i| colour(i + 7)).collect(),
            );
            let left = LabelMap::from_fn(w, h, |x, y| ((x * 7 + y * 13) % nl) as u16);
            let right = LabelMap::from_fn(w, h, |x, y| ((x * 5 + y * y) % nr) as u16);
            let (l, r) = (left.map(|i| lp[i as usize]), right.map(|i| rp[i as usize]));
            for mode in [Anaglyph::Dubois, Anaglyph::Gray] {
                let full = anaglyph(&l, &r, mode);
                let (mut pairs, mut out) = (Vec::new(), RgbImage::default());
                let (rows, cols) = crate::Screen::view_shown(w, h);
                anaglyph_labels_shown_into(
                    (&left, &lp),
                    (&right, &rp),
                    mode,
                    (rows.clone(), cols.clone()),
                    &mut pairs,
                    &mut out,
                );
                let mut seen = 0;
                for y in rows {
                    for x in cols.clone() {
                        assert_eq!(out.get(x, y), full.get(x, y), "{w}x{h} {mode:?} ({x}, {y})");
                        seen += 1;
                    }
                }
                assert!(seen > 0);
            }
        }
    }

    /// The fixed-point Dubois pixel against the `f32` product of the
    /// paper's matrices: never more than one level apart (rounding), and
    /// equal for almost every pair (443 of these 100 000 differ).
    #[test]
    fn fixed_point_dubois_follows_the_float_definition() {
        let float = |l: Rgb, r: Rgb| {
            let (lf, rf) = (l.map(f32::from), r.map(f32::from));
            std::array::from_fn::<u8, 3, _>(|i| {
                let v: f32 = (0..3)
                    .map(|k| DUBOIS_LEFT[i][k] * lf[k] + DUBOIS_RIGHT[i][k] * rf[k])
                    .sum();
                v.round().clamp(0.0, 255.0) as u8
            })
        };
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let (mut differ, n) = (0, 100_000);
        for _ in 0..n {
            let v = next().to_le_bytes();
            let (l, r) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
            let (a, b) = (anaglyph_pixel(l, r, Anaglyph::Dubois), float(l, r));
            assert!(
                a.iter().zip(&b).all(|(x, y)| x.abs_diff(*y) <= 1),
                "{l:?} {r:?}"
            );
            differ += (a != b) as usize;
        }
        assert!(differ * 100 < n, "{differ} of {n} pixels differ");
        for c in [[0; 3], [255; 3], [128, 64, 32]] {
            assert_eq!(anaglyph_pixel(c, c, Anaglyph::Dubois), float(c, c));
        }
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
