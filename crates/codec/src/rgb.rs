//! Lossless coding of unsegmented RGB images, so the original pair can be
//! sent for comparison: the LOCO-I/JPEG-LS median edge detector (MED)
//! predicts each channel from its W, N and NW neighbours, and the residual
//! (mod 256) is coded with adaptive contexts chosen by the local activity.

use stereolink_image::RgbImage;

use crate::rangecoder::{BitTree, Decoder, Encoder, Prob};
use crate::CodecError;

const BUCKETS: usize = 8;

/// MED prediction from W (a), N (b) and NW (c).
#[inline]
fn med(a: u8, b: u8, c: u8) -> u8 {
    let (lo, hi) = (a.min(b), a.max(b));
    if c >= hi {
        lo
    } else if c <= lo {
        hi
    } else {
        a.wrapping_add(b).wrapping_sub(c)
    }
}

#[inline]
fn bucket(a: u8, b: u8, c: u8) -> usize {
    let act = a.abs_diff(c) as u32 + b.abs_diff(c) as u32;
    (u32::BITS - act.leading_zeros()).min(BUCKETS as u32 - 1) as usize
}

struct Model {
    zero: Vec<Prob>,
    sign: Vec<Prob>,
    magnitude: Vec<BitTree>,
}

impl Model {
    fn new() -> Self {
        Model {
            zero: vec![Prob::default(); 3 * BUCKETS],
            sign: vec![Prob::default(); 3 * BUCKETS],
            magnitude: vec![BitTree::new(7); 3 * BUCKETS],
        }
    }

    /// Back to the state of [`Model::new`], reusing the storage.
    fn reset(&mut self) {
        self.zero.fill(Prob::default());
        self.sign.fill(Prob::default());
        self.magnitude.iter_mut().for_each(|t| t.reset(7));
    }
}

fn neighbours(img: &[[u8; 3]], w: usize, x: usize, y: usize, ch: usize) -> (u8, u8, u8) {
    let at = |xx: usize, yy: usize| img[yy * w + xx][ch];
    match (x, y) {
        (0, 0) => (0, 0, 0),
        (_, 0) => (at(x - 1, 0), at(x - 1, 0), at(x - 1, 0)),
        (0, _) => (at(0, y - 1), at(0, y - 1), at(0, y - 1)),
        _ => (at(x - 1, y), at(x, y - 1), at(x - 1, y - 1)),
    }
}

/// Codes an RGB image losslessly.
pub fn encode(img: &RgbImage) -> Vec<u8> {
    let (w, h) = img.dims();
    let data = img.as_slice();
    let mut m = Model::new();
    let mut enc = Encoder::new();
    for y in 0..h {
        for x in 0..w {
            for ch in 0..3 {
                let (a, b, c) = neighbours(data, w, x, y, ch);
                let ctx = ch * BUCKETS + bucket(a, b, c);
                let r = data[y * w + x][ch].wrapping_sub(med(a, b, c)) as i8;
                enc.bit(&mut m.zero[ctx], r == 0);
                if r != 0 {
                    enc.bit(&mut m.sign[ctx], r < 0);
                    m.magnitude[ctx].encode(&mut enc, r.unsigned_abs() as u32 - 1);
                }
            }
        }
    }
    enc.finish()
}

/// Decodes image after image with one model, so that a receiver decoding
/// frame after frame allocates nothing.
pub struct RgbDecoder {
    model: Model,
}

impl Default for RgbDecoder {
    fn default() -> Self {
        RgbDecoder {
            model: Model::new(),
        }
    }
}

impl RgbDecoder {
    /// Decodes an image written by [`encode`] into a caller-provided one
    /// (its size gives `w`×`h`).
    pub fn decode_into(&mut self, bytes: &[u8], out: &mut RgbImage) -> Result<(), CodecError> {
        self.model.reset();
        decode_with(&mut self.model, bytes, out)
    }
}

fn decode_with(m: &mut Model, bytes: &[u8], out: &mut RgbImage) -> Result<(), CodecError> {
    let (w, h) = out.dims();
    let mut dec = Decoder::new(bytes);
    for y in 0..h {
        for x in 0..w {
            for ch in 0..3 {
                let (a, b, c) = neighbours(out.as_slice(), w, x, y, ch);
                let ctx = ch * BUCKETS + bucket(a, b, c);
                let r: i16 = if dec.bit(&mut m.zero[ctx]) {
                    0
                } else {
                    let negative = dec.bit(&mut m.sign[ctx]);
                    let mag = m.magnitude[ctx].decode(&mut dec) as i16 + 1;
                    if negative {
                        -mag
                    } else {
                        mag
                    }
                };
                out.as_mut_slice()[y * w + x][ch] = med(a, b, c).wrapping_add(r as u8);
            }
        }
        if dec.overrun() {
            return Err(CodecError::Truncated("image stream"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn round_trip(w in 1usize..20, h in 1usize..20, seed in any::<u64>()) {
            let mut s = seed | 1;
            let img = RgbImage::from_fn(w, h, |x, y| {
                s ^= s << 13; s ^= s >> 7; s ^= s << 17;
                [(x * 9) as u8, (s >> 30) as u8, (y * 3 + x) as u8]
            });
            let mut out = RgbImage::new(w, h, [0; 3]);
            RgbDecoder::default().decode_into(&encode(&img), &mut out).unwrap();
            prop_assert_eq!(out, img);
        }
    }

    #[test]
    fn smooth_images_compress() {
        let img = RgbImage::from_fn(64, 64, |x, y| [(x * 4) as u8, (y * 4) as u8, 128]);
        assert!(encode(&img).len() < 64 * 64 * 3 / 8);
    }
}
