//! The gray samples WTA matches: the BT.601 luma of a view in fixed point
//! (8 to 10 bits), from RGB pixels or through a label map's palette. Its own
//! module because the receiver prepares these samples apart from matching.

use stereolink_image::{LabelMap, Rgb, RgbImage};

use super::Samples;

/// Writes the luma of `img` into `out` (resized, storage reused) in fixed
/// point with `bits` bits (8..=10): BT.601 weights `(77 R + 150 G + 29 B) / 256`
/// scaled by `2^(bits − 8)` and rounded; 8 bits equal
/// [`stereolink_image::color::luma`].
pub fn luma_samples_into(img: &RgbImage, bits: u32, out: &mut Samples) {
    // Every sample is written below: a plane of the size is not cleared.
    if out.dims() != img.dims() {
        out.reset(img.width(), img.height(), 0);
    }
    #[cfg(target_arch = "x86_64")]
    if stereolink_image::cpu::avx2() {
        // SAFETY: the CPU has AVX2.
        return unsafe { luma_avx2(img.as_slice(), bits, out.as_mut_slice()) };
    }
    luma(img.as_slice(), bits, out.as_mut_slice());
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn luma_avx2(pixels: &[Rgb], bits: u32, out: &mut [u16]) {
    luma(pixels, bits, out)
}

/// [`luma_samples_into`]'s loop: one per precision, with the shift a
/// constant, so that it vectorises (the pixels' bytes are spread apart by
/// shuffles; AVX2 has the wider ones).
#[inline(always)]
fn luma(pixels: &[Rgb], bits: u32, out: &mut [u16]) {
    #[inline(always)]
    fn shifted<const SHIFT: u32>(pixels: &[Rgb], out: &mut [u16]) {
        // 77 · 255 + 150 · 255 + 29 · 255 + 128 < 2¹⁶: 16-bit lanes suffice.
        for (o, p) in out.iter_mut().zip(pixels) {
            let sum = 77 * p[0] as u16 + 150 * p[1] as u16 + 29 * p[2] as u16;
            *o = (sum + (1 << (SHIFT - 1))) >> SHIFT;
        }
    }
    match bits.clamp(8, 10) {
        8 => shifted::<8>(pixels, out),
        9 => shifted::<7>(pixels, out),
        _ => shifted::<6>(pixels, out),
    }
}

/// [`luma_samples_into`] for a label map and its palette (each label
/// indexing it): the luma of each colour once, then a lookup per pixel.
/// `lut` is scratch (resized, storage reused).
///
/// # Panics
/// If a label does not index `palette`.
pub fn luma_labels_into(
    labels: &LabelMap,
    palette: &[Rgb],
    bits: u32,
    lut: &mut Vec<u16>,
    out: &mut Samples,
) {
    // A lookup for every u16 label (no bounds check per pixel): the
    // palette's luma, then NOT_IN_PALETTE (above every luma, 10 bits at most).
    const NOT_IN_PALETTE: u16 = u16::MAX;
    let n = palette.len();
    lut.clear();
    lut.resize(n.max(1 << 16), NOT_IN_PALETTE);
    luma(palette, bits, &mut lut[..n]);
    let lut: &[u16; 1 << 16] = lut[..1 << 16].try_into().expect("65 536 entries");
    // Every sample is written below: a plane of the size is not cleared.
    if out.dims() != labels.dims() {
        out.reset(labels.width(), labels.height(), 0);
    }
    // Four pixels a step (the loop's own work shared).
    let (out, labels) = (out.as_mut_slice(), labels.as_slice());
    let mut seen = 0;
    let (mut o4, mut l4) = (out.chunks_exact_mut(4), labels.chunks_exact(4));
    for (o, l) in (&mut o4).zip(&mut l4) {
        let v = [
            lut[l[0] as usize],
            lut[l[1] as usize],
            lut[l[2] as usize],
            lut[l[3] as usize],
        ];
        seen |= v[0] | v[1] | v[2] | v[3];
        o.copy_from_slice(&v);
    }
    for (o, &l) in o4.into_remainder().iter_mut().zip(l4.remainder()) {
        *o = lut[l as usize];
        seen |= *o;
    }
    assert!(seen != NOT_IN_PALETTE, "a label beyond its palette of {n}");
}

/// [`luma_samples_into`] into a new image.
pub fn luma_samples(img: &RgbImage, bits: u32) -> Samples {
    let mut out = Samples::default();
    luma_samples_into(img, bits, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_samples_refine_the_8_bit_luma() {
        let img = RgbImage::from_fn(16, 16, |x, y| [(x * 16) as u8, (y * 16) as u8, 255]);
        let (g8, g9) = (luma_samples(&img, 8), luma_samples(&img, 9));
        for (x, y) in [(0, 0), (3, 5), (15, 15)] {
            let p = img.get(x, y);
            assert_eq!(g8.get(x, y), stereolink_image::color::luma(p) as u16);
            assert!(g9.get(x, y).abs_diff(2 * g8.get(x, y)) <= 1);
        }
        assert_eq!(
            luma_samples(&RgbImage::new(1, 1, [255; 3]), 10).get(0, 0),
            1020
        );
        // The loop without AVX2 gives the same samples (33 pixels: a
        // vector tail too).
        let img = RgbImage::from_fn(33, 7, |x, y| {
            [(x * 37 + y) as u8, (y * 91) as u8, (x ^ y) as u8]
        });
        for bits in 8..=10 {
            let mut portable = vec![0; 33 * 7];
            luma(img.as_slice(), bits, &mut portable);
            assert_eq!(luma_samples(&img, bits).as_slice(), portable.as_slice());
        }
    }

    /// Luma through the palette equals the luma of the expanded view.
    #[test]
    fn luma_of_labels_equals_luma_of_their_colours() {
        let palette: Vec<Rgb> = (0..7u8)
            .map(|i| [i * 37, 255 - i * 29, i * i * 5])
            .collect();
        let labels = LabelMap::from_fn(23, 9, |x, y| ((x * 3 + y * 5) % 7) as u16);
        let rgb = labels.map(|l| palette[l as usize]);
        let (mut lut, mut out) = (Vec::new(), Samples::default());
        for bits in 8..=10 {
            luma_labels_into(&labels, &palette, bits, &mut lut, &mut out);
            assert_eq!(out, luma_samples(&rgb, bits), "{bits} bits");
        }
    }

    #[test]
    #[should_panic(expected = "beyond its palette")]
    fn a_label_beyond_the_palette_panics() {
        let labels = LabelMap::from_fn(5, 3, |x, _| x as u16);
        let (mut lut, mut out) = (Vec::new(), Samples::default());
        luma_labels_into(&labels, &[[9; 3]; 4], 8, &mut lut, &mut out);
    }
}
