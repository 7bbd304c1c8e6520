//! Lossy view coding: a view sent as a stock JPEG or WebP bitstream instead
//! of a segmented label map, for the best picture per byte on the radio.
//!
//! Why these codecs, by measurement (`docs/benchmarks.md`, "Lossy views"):
//! at the radio's budgets (a few kB per 320x240 view) both beat the
//! segmented pair by several dB of PSNR at equal bytes, and WebP beats JPEG
//! by more than that again. The board decides the details: an ARM926
//! without FPU or SIMD must decode a pair within its instruction budget
//! with pure-Rust decoders. `zune-jpeg` does so with room to spare.
//! `image-webp` does so only as this module codes WebP: VP8's simple loop
//! filter (the encoder's choice) and chroma upsampled from the nearest
//! sample (the decoder's, as `dwebp -nofancy`), each at a small cost in
//! PSNR; with the normal filter and bilinear upsampling it does not. So WebP
//! is the lossy coding to use, and JPEG the one that leaves the board the
//! most time. AV1 intra (AVIF) codes better still, but was not tried on the
//! board: its decoders do far more work per pixel than VP8's.
//!
//! Decoding is pure Rust and builds for armv5te. Encoding is the sender's:
//! `jpeg-encoder` (baseline, 4:2:0) and libwebp through the `webp` crate
//! (C), both behind the `encode` feature, which the board's build never
//! turns on; without it [`encode`] is a typed error.
//!
//! A coded view is checked before its pixels are: its size must be the
//! frame's, so a forged bitstream never makes the decoder allocate more
//! than one view.

use std::io::Cursor;
use std::ops::RangeInclusive;

use stereolink_image::RgbImage;

use crate::CodecError;

/// A stock image codec for a view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum LossyCodec {
    /// Baseline JPEG, 4:2:0: the cheapest to decode.
    Jpeg = 0,
    /// Lossy WebP (VP8 intra, simple loop filter): the most picture per
    /// byte.
    Webp = 1,
}

impl LossyCodec {
    /// The encoder's qualities, lowest (smallest frame) first: JPEG's
    /// from 1, libwebp's from 0 (its 0 is far smaller than its 1).
    pub fn qualities(self) -> RangeInclusive<u8> {
        match self {
            Self::Jpeg => 1..=100,
            Self::Webp => 0..=100,
        }
    }

    /// The codec's name (`jpeg`, `webp`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Jpeg => "jpeg",
            Self::Webp => "webp",
        }
    }

    /// From its wire code.
    pub(crate) fn from_u8(v: u8) -> Option<Self> {
        [Self::Jpeg, Self::Webp].get(v as usize).copied()
    }
}

/// How a frame's views are coded: segmented (the paper's mode: label maps,
/// lossless) or as lossy images.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ViewCoding {
    /// Segmented views, label maps coded losslessly.
    #[default]
    Segmented,
    /// Unsegmented views through a stock codec.
    Lossy(LossyCodec),
}

impl ViewCoding {
    /// The coding's name (`segmented`, `jpeg`, `webp`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Segmented => "segmented",
            Self::Lossy(c) => c.name(),
        }
    }
}

impl std::str::FromStr for ViewCoding {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "segmented" => Ok(Self::Segmented),
            "jpeg" => Ok(Self::Lossy(LossyCodec::Jpeg)),
            "webp" => Ok(Self::Lossy(LossyCodec::Webp)),
            _ => Err(format!(
                "unknown view coding {s:?} (segmented, jpeg or webp)"
            )),
        }
    }
}

/// A view coded lossily: the bitstream as sent, and the pixels it decodes
/// to (what the receiver shows).
#[derive(Clone, Debug, PartialEq)]
pub struct LossyView {
    codec: LossyCodec,
    bytes: Vec<u8>,
    image: RgbImage,
}

impl LossyView {
    /// Decodes `bytes`, which must hold a `width`×`height` view.
    pub fn decode(
        codec: LossyCodec,
        bytes: Vec<u8>,
        (width, height): (usize, usize),
    ) -> Result<Self, CodecError> {
        let mut image = RgbImage::default();
        decode_into(codec, &bytes, (width, height), &mut image)?;
        Ok(Self::decoded(codec, bytes, image))
    }

    /// A view its bitstream was decoded to already.
    pub(crate) fn decoded(codec: LossyCodec, bytes: Vec<u8>, image: RgbImage) -> Self {
        LossyView {
            codec,
            bytes,
            image,
        }
    }

    /// The codec.
    pub fn codec(&self) -> LossyCodec {
        self.codec
    }

    /// The coded bitstream.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The decoded view.
    pub fn image(&self) -> &RgbImage {
        &self.image
    }
}

/// Codes `image` with `codec` at `quality` (clamped to
/// [`LossyCodec::qualities`]), and keeps what it decodes to.
#[cfg(feature = "encode")]
pub fn encode(image: &RgbImage, codec: LossyCodec, quality: u8) -> Result<LossyView, CodecError> {
    let q = quality.clamp(*codec.qualities().start(), *codec.qualities().end());
    let (w, h) = image.dims();
    let side = |v: usize| {
        u16::try_from(v).map_err(|_| CodecError::Invalid(format!("a view side of {v} px")))
    };
    let pixels = image.as_slice().as_flattened();
    let bytes = match codec {
        LossyCodec::Jpeg => {
            let mut out = Vec::new();
            let mut e = jpeg_encoder::Encoder::new(&mut out, q);
            // One interleaved scan with the standard Huffman tables: with
            // optimised tables the encoder writes a scan per component,
            // which zune-jpeg 0.5.15 decodes wrongly when subsampled
            // (zune-image issue 341).
            e.set_sampling_factor(jpeg_encoder::SamplingFactor::F_2_2);
            e.encode(pixels, side(w)?, side(h)?, jpeg_encoder::ColorType::Rgb)
                .map_err(|e| CodecError::Invalid(format!("JPEG encoder: {e}")))?;
            abbreviated(&out).ok_or(CodecError::Invalid("the JPEG encoder's markers".into()))?
        }
        LossyCodec::Webp => {
            let mut config = webp::WebPConfig::new()
                .map_err(|()| CodecError::Invalid("libwebp's configuration".into()))?;
            config.quality = f32::from(q);
            config.method = 6;
            // VP8's simple loop filter: the normal one costs the board's
            // decoder more than the pair's budget has left.
            config.filter_type = 0;
            webp::Encoder::from_rgb(pixels, side(w)?.into(), side(h)?.into())
                .encode_advanced(&config)
                .map_err(|e| CodecError::Invalid(format!("WebP encoder: {e:?}")))?
                .to_vec()
        }
    };
    LossyView::decode(codec, bytes, (w, h))
}

/// A JPEG without the tables every view shares, as Motion JPEG sends it: the
/// standard Huffman tables (JPEG Annex K, which the encoder uses) and the
/// JFIF segment give way to an `AVI1` APP0 segment, which tells decoders to
/// use the standard tables. A few hundred bytes less per view, which at the
/// radio's budgets is a good share of the picture. `None` if `jpeg` is not
/// the markers-then-scan stream the encoder writes.
#[cfg(feature = "encode")]
fn abbreviated(jpeg: &[u8]) -> Option<Vec<u8>> {
    const SOI: [u8; 2] = [0xFF, 0xD8];
    const APP0: u8 = 0xE0;
    const DHT: u8 = 0xC4;
    const SOS: u8 = 0xDA;
    let mut out = Vec::with_capacity(jpeg.len());
    out.extend_from_slice(&SOI);
    out.extend_from_slice(&[0xFF, APP0, 0, 7]);
    out.extend_from_slice(b"AVI1\0");
    let mut rest = jpeg.strip_prefix(&SOI)?;
    loop {
        let (&[0xFF, marker, hi, lo], _) = rest.split_first_chunk::<4>()? else {
            return None;
        };
        if marker == SOS {
            out.extend_from_slice(rest);
            return Some(out);
        }
        let (segment, next) =
            rest.split_at_checked(2 + usize::from(u16::from_be_bytes([hi, lo])))?;
        if marker != APP0 && marker != DHT {
            out.extend_from_slice(segment);
        }
        rest = next;
    }
}

/// Without the `encode` feature (the board's build): always an error.
#[cfg(not(feature = "encode"))]
pub fn encode(_image: &RgbImage, codec: LossyCodec, _quality: u8) -> Result<LossyView, CodecError> {
    Err(CodecError::Invalid(format!(
        "this build has no {} encoder (it is the sender's: feature `encode`)",
        codec.name()
    )))
}

/// Decodes a `width`×`height` view coded with `codec` into `out`, resized
/// to the view (no allocation for `out` once it is large enough; the
/// decoders keep their own buffers per call).
pub fn decode_into(
    codec: LossyCodec,
    bytes: &[u8],
    (width, height): (usize, usize),
    out: &mut RgbImage,
) -> Result<(), CodecError> {
    let wrong_size = |w: usize, h: usize| {
        CodecError::Invalid(format!(
            "a {} view of {w}x{h} in a {width}x{height} frame",
            codec.name()
        ))
    };
    match codec {
        LossyCodec::Jpeg => {
            use zune_jpeg::zune_core::{
                bytestream::ZCursor, colorspace::ColorSpace, options::DecoderOptions,
            };
            // Strict: more corrupt streams are errors, not pictures.
            let options = DecoderOptions::default()
                .set_strict_mode(true)
                .set_max_width(width)
                .set_max_height(height)
                .jpeg_set_out_colorspace(ColorSpace::RGB);
            let mut d = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
            d.decode_headers().map_err(|e| jpeg_error(&e))?;
            let (w, h) = d.dimensions().ok_or(CodecError::Truncated("JPEG header"))?;
            if (w, h) != (width, height) {
                return Err(wrong_size(w, h));
            }
            fit(out, (width, height));
            d.decode_into(out.as_mut_slice().as_flattened_mut())
                .map_err(|e| jpeg_error(&e))
        }
        LossyCodec::Webp => {
            let mut d =
                image_webp::WebPDecoder::new(Cursor::new(bytes)).map_err(|e| webp_error(&e))?;
            let (w, h) = d.dimensions();
            if (w as usize, h as usize) != (width, height) {
                return Err(wrong_size(w as usize, h as usize));
            }
            if d.has_alpha() || d.is_animated() {
                return Err(CodecError::Invalid(
                    "a WebP view with alpha or animation".into(),
                ));
            }
            // Chroma upsampled from the nearest sample (dwebp -nofancy):
            // the bilinear filter would cost the board as much as the
            // rest of a view's decoding.
            d.set_lossy_upsampling(image_webp::UpsamplingMethod::Simple);
            fit(out, (width, height));
            d.read_image(out.as_mut_slice().as_flattened_mut())
                .map_err(|e| webp_error(&e))
        }
    }
}

/// Sizes and clears `out`. The decoders do not always write every pixel: on
/// some corrupt scans zune-jpeg ends early without an error, even in strict
/// mode, and a view reused from frame to frame would then keep the last
/// frame's pixels there (found by the `frame_decoder` fuzz target). Cleared,
/// a view decodes to the same pixels whatever the buffer held; the clearing
/// costs a few thousandths of the decoding.
fn fit(out: &mut RgbImage, (width, height): (usize, usize)) {
    out.reset(width, height, [0; 3]);
}

fn jpeg_error(e: &zune_jpeg::errors::DecodeErrors) -> CodecError {
    CodecError::Invalid(format!("JPEG view: {e:?}"))
}

fn webp_error(e: &image_webp::DecodingError) -> CodecError {
    CodecError::Invalid(format!("WebP view: {e}"))
}

#[cfg(all(test, feature = "encode"))]
mod tests {
    use super::*;
    use stereolink_image::metrics::psnr_rgb;
    use stereolink_image::synth::{synthesize, SynthSpec};

    fn view() -> RgbImage {
        synthesize(&SynthSpec {
            width: 96,
            height: 64,
            max_disp: 8,
            seed: 3,
        })
        .unwrap()
        .left
    }

    #[test]
    fn both_codecs_round_trip_above_a_psnr_floor() {
        // The synthetic view is textured: 4:2:0 JPEG at q90 gives it under
        // 30 dB; a decoder that mixes up its planes gives under 10.
        let img = view();
        for codec in [LossyCodec::Jpeg, LossyCodec::Webp] {
            let v = encode(&img, codec, 90).unwrap();
            let psnr = psnr_rgb(&img, v.image()).unwrap().overall;
            assert!(psnr > 27.0, "{} q90: {psnr} dB", codec.name());
            let again = LossyView::decode(codec, v.bytes().to_vec(), img.dims()).unwrap();
            assert_eq!(again, v);
        }
    }

    #[test]
    fn truncated_or_wrong_sized_bitstreams_are_errors() {
        let img = view();
        for codec in [LossyCodec::Jpeg, LossyCodec::Webp] {
            let v = encode(&img, codec, 50).unwrap();
            let mut out = RgbImage::default();
            for cut in [0, 1, 10] {
                let r = decode_into(codec, &v.bytes()[..cut], img.dims(), &mut out);
                assert!(r.is_err(), "{} cut to {cut} bytes", codec.name());
            }
            for cut in [v.bytes().len() / 2, v.bytes().len() - 1] {
                let r = decode_into(codec, &v.bytes()[..cut], img.dims(), &mut out);
                // A JPEG cut in its entropy-coded data may still decode (the
                // decoder pads what is missing): an error or a whole view.
                assert!(
                    r.is_err() || out.dims() == img.dims(),
                    "{} cut {cut}",
                    codec.name()
                );
            }
            let r = decode_into(codec, v.bytes(), (97, 64), &mut out);
            assert!(matches!(r, Err(CodecError::Invalid(m)) if m.contains("96x64")));
        }
    }
}
