//! Stereo prediction: the right view coded as the left view, as the
//! receiver decoded it, shifted by the sender's disparity, with what the
//! shift misses coded per block.
//!
//! Each [`CELL`]×[`CELL`] cell of the right view carries an integer
//! disparity `d`: its prediction is the decoded left view `d` px to the
//! right (rectified views: right(x, y) = left(x + d, y), clamped at the
//! edge). Each [`BLOCK`]×[`BLOCK`] block (the macroblocks of [`temporal`])
//! then has a [`Mode`]: *skipped* (the prediction alone), a *residual* (the
//! prediction's error, offset by 128) or *intra* (its pixels). Coded blocks
//! are packed into one mosaic, coded by the left view's lossy codec a few
//! quality steps coarser, and put over the prediction, as [`temporal`]
//! packs changed blocks.
//!
//! Why this scheme, by measurement (`docs/tuning.md`, "Stereo prediction",
//! on 8 scenes; `docs/benchmarks.md`, "Stereo prediction", on 20):
//!
//! * the loop is closed: disparities are found against the *decoded* left
//!   view, so what the sender predicts is what the receiver predicts;
//! * coding the blocks the shift misses as pixels (as temporal prediction
//!   does) pays for their texture again: a residual pays only for the miss.
//!   But where the shift is worse than no prediction (occlusions), pixels
//!   cost less: the three modes beat a whole residual view and pixels alone;
//! * the skip test scales with the left view's coding error where the
//!   prediction comes from ([`StereoSpec`]), so it follows the quality rate
//!   control picks; skipping 60 % of the blocks costs no PSNR per byte
//!   against coding them all, and leaves the board less to decode;
//! * 8-px cells predict better than 16-px ones by more than their
//!   disparities cost (4-px cells cost more than they gain); disparities
//!   are median-predicted from their causal neighbours, range coded, and
//!   chosen with a rate term. They are the sender's disparity map at 8 px,
//!   which the receiver shows instead of matching the pair itself.
//!
//! Payload of a stereo-predicted right view (after the container's view
//! header; `docs/wire-format.md`, coding 6):
//!
//! ```text
//! blocks length (u32) | blocks (range coded: each block's mode in raster
//! order, then each cell's disparity less the median of its left, upper and
//! upper-right neighbours') | [codec (u8) | mosaic bitstream]  (if any block is coded)
//! ```
//!
//! A disparity decoded outside `0..=width` is an error, as are a mosaic
//! with no coded block, a coded block without a mosaic, and blocks data
//! that end early: a corrupt payload is a [`CodecError`], never a panic.

use stereolink_image::{Plane, RgbImage};

use crate::lossy::{self, LossyCodec, LossyView};
use crate::rangecoder::{Decoder, Encoder, Prob};
use crate::temporal::{self, blocks, BLOCK};
use crate::CodecError;

/// How the sender chooses each block's mode. A block is *skipped* (its
/// prediction kept) when the prediction's squared error against the
/// original is at most `skip_ratio` times the left view's coding error
/// (squared, over the block the prediction comes from) plus `skip_floor`²
/// per sample. Otherwise it is coded *intra* (its pixels) when the
/// prediction's error exceeds `intra_ratio` times the block's own energy
/// about its mean (the prediction is worse than none: an occlusion), else
/// as a *residual* (the prediction's error). `docs/tuning.md` ("Stereo
/// prediction") gives the measurement behind the defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoSpec {
    /// Largest disparity searched (px); `None`: a quarter of the width.
    pub max_disp: Option<usize>,
    /// Skipped when the prediction's error is within this many times the
    /// left view's coding error ...
    pub skip_ratio: f32,
    /// ... plus this RMS error (grey levels).
    pub skip_floor: f32,
    /// Coded intra when the prediction's error exceeds this many times the
    /// block's energy about its mean.
    pub intra_ratio: f32,
    /// The coded blocks' quality, less the left view's (the codec's steps).
    pub quality_drop: u8,
}

impl Default for StereoSpec {
    fn default() -> Self {
        StereoSpec {
            max_disp: None,
            skip_ratio: 2.0,
            skip_floor: 2.0,
            intra_ratio: 1.0,
            quality_drop: 10,
        }
    }
}

/// A block's mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Mode {
    /// The prediction alone.
    Skip = 0,
    /// The prediction plus a coded residual (offset by 128).
    Residual = 1,
    /// The block's pixels, coded.
    Intra = 2,
}

/// Side of a disparity's cell, in pixels: each cell of the right view has
/// one disparity. The modes stay per [`BLOCK`] (the codecs' macroblock).
pub const CELL: usize = 8;

/// The disparity cells of a `width`×`height` view: `(columns, rows)`.
pub fn cells((width, height): (usize, usize)) -> (usize, usize) {
    (width.div_ceil(CELL), height.div_ceil(CELL))
}

/// Bits of the largest disparity residual's exponent.
const MAX_EXP: usize = 15;

/// Weight of a disparity's residual bits against its cell's summed
/// absolute difference in the search (docs/tuning.md, "Stereo
/// prediction"): smooth disparities cost fewer bits, predict about as
/// well, and make a cleaner map.
const LAMBDA: u32 = 48;

/// A right view predicted from the left: the blocks' disparities and
/// modes, the coded blocks' mosaic, and the view it rebuilds.
#[derive(Clone, Debug, PartialEq)]
pub struct StereoView {
    disparities: Vec<u16>,
    modes: Vec<Mode>,
    blocks: Vec<u8>,
    mosaic: Option<LossyView>,
    image: RgbImage,
}

impl StereoView {
    /// Codes `right` predicted from the left view as the receiver decoded
    /// it (`left_sent`; `left` is its original, which tells the left view's
    /// coding error), the coded blocks with `codec` at `quality` less
    /// `spec.quality_drop`.
    ///
    /// # Panics
    /// If the views differ in size.
    pub fn encode(
        right: &RgbImage,
        (left, left_sent): (&RgbImage, &RgbImage),
        codec: LossyCodec,
        quality: u8,
        spec: &StereoSpec,
    ) -> Result<Self, CodecError> {
        assert_eq!(right.dims(), left.dims(), "views differ in size");
        assert_eq!(left.dims(), left_sent.dims(), "views differ in size");
        let (w, h) = right.dims();
        let max_disp = spec.max_disp.unwrap_or(w / 4).min(w.saturating_sub(1));
        let disparities = search(right, left_sent, max_disp);
        let mut image = RgbImage::default();
        warp_into(left_sent, &disparities, &mut image);
        let modes = modes(right, (left, left_sent), &image, &disparities, spec);
        let coded: Vec<bool> = modes.iter().map(|&m| m != Mode::Skip).collect();
        let mosaic = if coded.contains(&true) {
            // What each coded block's slot holds: its pixels, or its
            // prediction's error offset by 128.
            let cols = blocks((w, h)).0;
            let source = RgbImage::from_fn(w, h, |x, y| {
                let (r, p) = (right.get(x, y), image.get(x, y));
                match modes[(y / BLOCK) * cols + x / BLOCK] {
                    Mode::Residual => [0, 1, 2]
                        .map(|k| (i32::from(r[k]) - i32::from(p[k]) + 128).clamp(0, 255) as u8),
                    Mode::Skip | Mode::Intra => r,
                }
            });
            let q = quality.saturating_sub(spec.quality_drop);
            let m = lossy::encode(&temporal::mosaic(&source, &coded), codec, q)?;
            paste(m.image(), &coded, &modes, &mut image);
            Some(m)
        } else {
            None
        };
        let blocks = write_blocks(&disparities, &modes, (w, h));
        Ok(StereoView {
            disparities,
            modes,
            blocks,
            mosaic,
            image,
        })
    }

    /// Decodes a payload predicted from `left` (the frame's decoded left
    /// view).
    pub fn decode(payload: &[u8], left: &RgbImage) -> Result<Self, CodecError> {
        let mut d = StereoDecoder::default();
        let mut image = RgbImage::default();
        d.decode_into(payload, left, &mut image)?;
        let parsed = parse(payload)?;
        let mosaic = parsed
            .mosaic
            .map(|(codec, bits)| LossyView::decoded(codec, bits.to_vec(), d.mosaic));
        Ok(StereoView {
            disparities: d.disparities,
            modes: d.modes,
            blocks: parsed.blocks.to_vec(),
            mosaic,
            image,
        })
    }

    /// Each cell's disparity (px), raster order ([`cells`]).
    pub fn disparities(&self) -> &[u16] {
        &self.disparities
    }

    /// Each block's mode, raster order.
    pub fn modes(&self) -> &[Mode] {
        &self.modes
    }

    /// The codec of the coded blocks, if any is coded.
    pub fn codec(&self) -> Option<LossyCodec> {
        self.mosaic.as_ref().map(LossyView::codec)
    }

    /// The right view rebuilt.
    pub fn image(&self) -> &RgbImage {
        &self.image
    }

    /// The view's payload in the container.
    pub fn payload(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(5 + self.blocks.len());
        out.extend_from_slice(&(self.blocks.len() as u32).to_le_bytes());
        out.extend_from_slice(&self.blocks);
        if let Some(m) = &self.mosaic {
            out.push(m.codec() as u8);
            out.extend_from_slice(m.bytes());
        }
        out
    }
}

/// Puts the decoded mosaic's slots over the prediction in `out`: an intra
/// block's pixels as they are, a residual block's added to the prediction
/// (less 128, clamped).
fn paste(mosaic: &RgbImage, coded: &[bool], modes: &[Mode], out: &mut RgbImage) {
    temporal::unpack_with(mosaic, coded, out, |to, from, i| match modes[i] {
        Mode::Residual => {
            for (p, r) in to.iter_mut().zip(from) {
                for k in 0..3 {
                    p[k] = (i32::from(p[k]) + i32::from(r[k]) - 128).clamp(0, 255) as u8;
                }
            }
        }
        Mode::Skip | Mode::Intra => to.copy_from_slice(from),
    });
}

/// A payload split: the blocks' range-coded data and the mosaic.
struct Parsed<'a> {
    blocks: &'a [u8],
    mosaic: Option<(LossyCodec, &'a [u8])>,
}

fn parse(payload: &[u8]) -> Result<Parsed<'_>, CodecError> {
    let (len, rest) = payload
        .split_first_chunk::<4>()
        .ok_or(CodecError::Truncated("stereo view"))?;
    let (blocks, rest) = rest
        .split_at_checked(u32::from_le_bytes(*len) as usize)
        .ok_or(CodecError::Truncated("stereo view's blocks"))?;
    let mosaic = match rest.split_first() {
        None => None,
        Some((&codec, bits)) => Some((
            LossyCodec::from_u8(codec)
                .ok_or_else(|| CodecError::Invalid(format!("lossy codec {codec}")))?,
            bits,
        )),
    };
    Ok(Parsed { blocks, mosaic })
}

/// Decodes stereo-predicted right views into buffers it keeps: after the
/// first view of a size it allocates nothing (the lossy decoders aside,
/// as for any lossy view).
#[derive(Default)]
pub struct StereoDecoder {
    disparities: Vec<u16>,
    modes: Vec<Mode>,
    coded: Vec<bool>,
    mosaic: RgbImage,
}

impl StereoDecoder {
    /// Rebuilds the right view of `payload` into `out` from `left`, the
    /// frame's decoded left view (its size is the right view's).
    pub fn decode_into(
        &mut self,
        payload: &[u8],
        left: &RgbImage,
        out: &mut RgbImage,
    ) -> Result<(), CodecError> {
        let parsed = parse(payload)?;
        let (w, _) = left.dims();
        read_blocks(
            parsed.blocks,
            left.dims(),
            &mut self.disparities,
            &mut self.modes,
        )?;
        self.coded.clear();
        self.coded
            .extend(self.modes.iter().map(|&m| m != Mode::Skip));
        let any = self.coded.contains(&true);
        warp_into(left, &self.disparities, out);
        match (any, parsed.mosaic) {
            (false, None) => Ok(()),
            (false, Some(_)) => Err(CodecError::Invalid("a mosaic with no coded block".into())),
            (true, None) => Err(CodecError::Truncated("stereo view's mosaic")),
            (true, Some((codec, bits))) => {
                let n = self.coded.iter().filter(|&&c| c).count();
                lossy::decode_into(codec, bits, temporal::mosaic_dims(n, w), &mut self.mosaic)?;
                paste(&self.mosaic, &self.coded, &self.modes, out);
                Ok(())
            }
        }
    }

    /// The last view's cell disparities (px), raster order ([`cells`]).
    pub fn disparities(&self) -> &[u16] {
        &self.disparities
    }
}

/// The cell disparities of a `width`×`height` right view as a map over
/// the *left* view (the receiver's disparity panel): each right pixel
/// marks its left pixel, x + d, with d (the larger where two meet: the
/// nearer surface), and the left pixels no right pixel sees (occluded)
/// take the smaller of their row's nearest marked neighbours (the
/// background). A row with none is `none`. `out` is resized if need be.
pub fn left_disparity_into(
    disparities: &[u16],
    (width, height): (usize, usize),
    none: u16,
    out: &mut Plane<u16>,
) {
    if out.dims() != (width, height) {
        out.reset(width, height, none);
    }
    let cols = cells((width, height)).0;
    for y in 0..height {
        let row = out.row_mut(y);
        row.fill(none);
        let cy = y / CELL;
        for x in 0..width {
            let d = disparities[cy * cols + x / CELL];
            let xl = x + usize::from(d);
            if xl < width && (row[xl] == none || d > row[xl]) {
                row[xl] = d;
            }
        }
        // Holes: the smaller of the nearest marked pixels either side.
        let mut x = 0;
        while x < width {
            if row[x] != none {
                x += 1;
                continue;
            }
            let start = x;
            while x < width && row[x] == none {
                x += 1;
            }
            let before = start.checked_sub(1).map(|i| row[i]);
            let after = (x < width).then(|| row[x]);
            let fill = match (before, after) {
                (Some(a), Some(b)) => a.min(b),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => none,
            };
            row[start..x].fill(fill);
        }
    }
}

/// `left` shifted per block by `disparities` into `out` (resized if need
/// be): right(x, y) = left(min(x + d, width − 1), y).
fn warp_into(left: &RgbImage, disparities: &[u16], out: &mut RgbImage) {
    let (w, h) = left.dims();
    if out.dims() != (w, h) {
        out.reset(w, h, [0; 3]);
    }
    let cols = cells((w, h)).0;
    for y in 0..h {
        let from = left.row(y);
        let to = out.row_mut(y);
        for cx in 0..cols {
            let d = usize::from(disparities[(y / CELL) * cols + cx]);
            let (x0, x1) = (cx * CELL, ((cx + 1) * CELL).min(w));
            let inside = x1.saturating_add(d).min(w).saturating_sub(d).max(x0);
            if inside > x0 {
                to[x0..inside].copy_from_slice(&from[x0 + d..inside + d]);
            }
            to[inside..x1].fill(from[w - 1]);
        }
    }
}

/// The median of a block's causal neighbours' disparities (left, upper,
/// upper-right, or upper-left at the right edge); one neighbour alone is
/// taken as is, none gives 0.
fn predictor(d: &[u16], cols: usize, i: usize) -> u16 {
    let (bx, by) = (i % cols, i / cols);
    match (bx > 0, by > 0) {
        (false, false) => 0,
        (true, false) => d[i - 1],
        (false, true) => d[i - cols],
        (true, true) => {
            let corner = if bx + 1 < cols {
                d[i - cols + 1]
            } else {
                d[i - cols - 1]
            };
            let (a, b, c) = (d[i - 1], d[i - cols], corner);
            a.max(b).min(a.min(b).max(c))
        }
    }
}

/// The adaptive models of the blocks' data.
struct Model {
    /// A block's mode, by how many of its left and upper neighbours are
    /// coded.
    mode: [Prob; 3],
    /// A coded block's: intra or residual.
    intra: Prob,
    /// Whether the disparity differs from its prediction, by mode.
    moved: [Prob; 3],
    sign: Prob,
    /// Exp-Golomb exponent, one probability a bit of its unary code.
    exp: [Prob; MAX_EXP],
}

impl Model {
    fn new() -> Self {
        Model {
            mode: Default::default(),
            intra: Prob::default(),
            moved: Default::default(),
            sign: Prob::default(),
            exp: Default::default(),
        }
    }
}

/// The mode context of block `i`: coded neighbours, left and above.
fn mode_context(modes: &[Mode], cols: usize, i: usize) -> usize {
    let left = i % cols > 0 && modes[i - 1] != Mode::Skip;
    let up = i >= cols && modes[i - cols] != Mode::Skip;
    usize::from(left) + usize::from(up)
}

/// Range codes the modes of a `width`×`height` view's blocks, then its
/// cells' disparities.
fn write_blocks(disparities: &[u16], modes: &[Mode], dims: (usize, usize)) -> Vec<u8> {
    let (bcols, ccols) = (blocks(dims).0, cells(dims).0);
    let mut enc = Encoder::new();
    let mut m = Model::new();
    for (i, &mode) in modes.iter().enumerate() {
        enc.bit(
            &mut m.mode[mode_context(modes, bcols, i)],
            mode != Mode::Skip,
        );
        if mode != Mode::Skip {
            enc.bit(&mut m.intra, mode == Mode::Intra);
        }
    }
    for (i, &d) in disparities.iter().enumerate() {
        let mode = modes[block_of(i, ccols, bcols)];
        let r = i32::from(d) - i32::from(predictor(disparities, ccols, i));
        enc.bit(&mut m.moved[mode as usize], r != 0);
        if r != 0 {
            enc.bit(&mut m.sign, r < 0);
            let mag = r.unsigned_abs();
            let k = (31 - mag.leading_zeros()) as usize;
            for p in &mut m.exp[..k] {
                enc.bit(p, true);
            }
            if k < MAX_EXP {
                enc.bit(&mut m.exp[k], false);
            }
            enc.direct(mag - (1 << k), k as u32);
        }
    }
    enc.finish()
}

/// The block holding cell `i` (of `ccols` a row; `bcols` blocks a row).
fn block_of(i: usize, ccols: usize, bcols: usize) -> usize {
    let (cx, cy) = (i % ccols, i / ccols);
    (cy * CELL / BLOCK) * bcols + cx * CELL / BLOCK
}

/// Decodes the block modes and cell disparities of a `width`×`height`
/// view into `disparities` and `modes`.
fn read_blocks(
    bits: &[u8],
    (width, height): (usize, usize),
    disparities: &mut Vec<u16>,
    modes: &mut Vec<Mode>,
) -> Result<(), CodecError> {
    let (bcols, brows) = blocks((width, height));
    let (ccols, crows) = cells((width, height));
    disparities.clear();
    modes.clear();
    let mut dec = Decoder::new(bits);
    let mut m = Model::new();
    for i in 0..bcols * brows {
        let mode = match dec.bit(&mut m.mode[mode_context(modes, bcols, i)]) {
            false => Mode::Skip,
            true if dec.bit(&mut m.intra) => Mode::Intra,
            true => Mode::Residual,
        };
        modes.push(mode);
    }
    for i in 0..ccols * crows {
        let mode = modes[block_of(i, ccols, bcols)];
        disparities.push(0);
        let mut d = i64::from(predictor(disparities, ccols, i));
        if dec.bit(&mut m.moved[mode as usize]) {
            let negative = dec.bit(&mut m.sign);
            let mut k = 0;
            while k < MAX_EXP && dec.bit(&mut m.exp[k]) {
                k += 1;
            }
            let mag = (1i64 << k) + i64::from(dec.direct(k as u32));
            d += if negative { -mag } else { mag };
        }
        if !(0..=width as i64).contains(&d) {
            return Err(CodecError::Invalid(format!(
                "a cell disparity of {d} px in a {width} px wide view"
            )));
        }
        disparities[i] = d as u16;
    }
    if dec.overrun() {
        return Err(CodecError::Truncated("stereo view's blocks"));
    }
    Ok(())
}

/// Each cell's disparity in `0..=max_disp`: the least summed absolute
/// difference of its pixels against the decoded left view, plus
/// [`LAMBDA`] a bit of its residual from the median prediction.
fn search(right: &RgbImage, left: &RgbImage, max_disp: usize) -> Vec<u16> {
    let (w, h) = right.dims();
    let (cols, rows) = cells((w, h));
    let mut d = vec![0u16; cols * rows];
    for i in 0..cols * rows {
        let (x0, y0) = ((i % cols) * CELL, (i / cols) * CELL);
        let (x1, y1) = ((x0 + CELL).min(w), (y0 + CELL).min(h));
        let pred = predictor(&d, cols, i);
        let mut best = (u32::MAX, 0u16);
        for disp in 0..=max_disp {
            let mut sad = 0u32;
            for y in y0..y1 {
                let (r, l) = (right.row(y), left.row(y));
                for x in x0..x1 {
                    let q = l[(x + disp).min(w - 1)];
                    for k in 0..3 {
                        sad += u32::from(r[x][k].abs_diff(q[k]));
                    }
                }
            }
            let cost = sad + LAMBDA * residual_bits(disp as i32 - i32::from(pred));
            if cost < best.0 {
                best = (cost, disp as u16);
            }
        }
        d[i] = best.1;
    }
    d
}

/// About the bits a disparity residual takes.
fn residual_bits(r: i32) -> u32 {
    match r.unsigned_abs() {
        0 => 1,
        m => 3 + 2 * (31 - m.leading_zeros()),
    }
}

/// Each block's mode ([`StereoSpec`]): skipped when its prediction's
/// squared error is within what the left view's coding error where the
/// prediction comes from allows; else intra when the prediction is worse
/// than the block's own energy about its mean allows, else a residual.
fn modes(
    right: &RgbImage,
    (left, left_sent): (&RgbImage, &RgbImage),
    predicted: &RgbImage,
    disparities: &[u16],
    spec: &StereoSpec,
) -> Vec<Mode> {
    let (w, h) = right.dims();
    let (cols, rows) = blocks((w, h));
    let ccols = cells((w, h)).0;
    let sq = |a: [u8; 3], b: [u8; 3]| -> u64 {
        (0..3).map(|k| u64::from(a[k].abs_diff(b[k])).pow(2)).sum()
    };
    (0..cols * rows)
        .map(|i| {
            let (x0, y0) = ((i % cols) * BLOCK, (i / cols) * BLOCK);
            let (x1, y1) = ((x0 + BLOCK).min(w), (y0 + BLOCK).min(h));
            let (mut err, mut noise) = (0u64, 0u64);
            let (mut sum, mut sum_sq) = ([0u64; 3], 0u64);
            for y in y0..y1 {
                for x in x0..x1 {
                    let r = right.get(x, y);
                    err += sq(r, predicted.get(x, y));
                    let d = disparities[(y / CELL) * ccols + x / CELL];
                    let xl = (x + usize::from(d)).min(w - 1);
                    noise += sq(left.get(xl, y), left_sent.get(xl, y));
                    for k in 0..3 {
                        sum[k] += u64::from(r[k]);
                        sum_sq += u64::from(r[k]).pow(2);
                    }
                }
            }
            let pixels = ((x1 - x0) * (y1 - y0)) as f32;
            let energy =
                sum_sq as f32 - sum.iter().map(|&s| (s as f32).powi(2)).sum::<f32>() / pixels;
            let allowed = spec.skip_ratio * noise as f32 + spec.skip_floor.powi(2) * pixels * 3.0;
            if err as f32 <= allowed {
                Mode::Skip
            } else if err as f32 > spec.intra_ratio * energy {
                Mode::Intra
            } else {
                Mode::Residual
            }
        })
        .collect()
}

#[cfg(all(test, feature = "encode"))]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use stereolink_image::synth::{synthesize, SynthSpec};

    fn pair() -> (RgbImage, RgbImage) {
        let s = synthesize(&SynthSpec {
            width: 96,
            height: 64,
            max_disp: 12,
            seed: 5,
        })
        .unwrap();
        (s.left, s.right)
    }

    fn coded() -> (RgbImage, StereoView) {
        let (left, right) = pair();
        let sent = lossy::encode(&left, LossyCodec::Webp, 60).unwrap();
        let v = StereoView::encode(
            &right,
            (&left, sent.image()),
            LossyCodec::Webp,
            60,
            &StereoSpec::default(),
        )
        .unwrap();
        (sent.image().clone(), v)
    }

    #[test]
    fn the_payload_rebuilds_the_senders_view_bit_for_bit() {
        let (left, v) = coded();
        let again = StereoView::decode(&v.payload(), &left).unwrap();
        assert_eq!(again, v);
        assert!(v.modes().contains(&Mode::Skip), "some block is predicted");
    }

    #[test]
    fn the_disparities_follow_the_scene() {
        // The synthetic pair's disparities are within 0..=12 px and not all
        // zero; a wrong search direction finds none of them.
        let (_, v) = coded();
        assert!(v.disparities().iter().all(|&d| d <= 16));
        assert!(v.disparities().iter().any(|&d| d >= 4));
    }

    #[test]
    fn truncated_or_corrupt_payloads_are_errors() {
        let (left, v) = coded();
        let payload = v.payload();
        let blocks_end = 4 + u32::from_le_bytes(payload[..4].try_into().unwrap()) as usize;
        // In the length, in the blocks, and just before the mosaic (a
        // coded block without one).
        for cut in [0, 3, 4, 6, blocks_end - 1, blocks_end] {
            let r = StereoView::decode(&payload[..cut], &left);
            assert!(r.is_err(), "cut to {cut} bytes");
        }
        // A declared blocks length beyond the payload.
        let mut long = payload.clone();
        long[..4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            StereoView::decode(&long, &left),
            Err(CodecError::Truncated("stereo view's blocks"))
        );
        // An unknown codec byte.
        let mut bad = payload.clone();
        bad[blocks_end] = 9;
        assert!(matches!(
            StereoView::decode(&bad, &left),
            Err(CodecError::Invalid(m)) if m.contains("codec 9")
        ));
    }

    #[test]
    fn the_left_map_marks_each_left_pixel_its_right_pixel_sees() {
        // One row of 32 px: disparity 2 in its first half, 0 in the other.
        let mut out = Plane::default();
        let d: Vec<u16> = (0..32 / CELL)
            .map(|c| if c * CELL < 16 { 2 } else { 0 })
            .collect();
        left_disparity_into(&d, (32, 1), u16::MAX, &mut out);
        let row = out.row(0);
        // x = 0..16 land on 2..18 (d 2), x = 16..32 on themselves (d 0),
        // except 16 and 17, where the nearer d 2 wins; 0 and 1 are holes
        // filled from their only neighbour.
        assert_eq!(&row[..2], &[2, 2]);
        assert_eq!(&row[2..18], &[2; 16]);
        assert_eq!(&row[18..], &[0; 14]);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        #[test]
        fn any_bytes_decode_or_fail_cleanly(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let left = RgbImage::new(40, 24, [90, 100, 110]);
            let mut d = StereoDecoder::default();
            let mut out = RgbImage::default();
            let _ = d.decode_into(&bytes, &left, &mut out);
        }

        #[test]
        fn blocks_data_round_trips(ds in proptest::collection::vec(0u16..=40, 6), ms in proptest::collection::vec(0u8..3, 6)) {
            let modes = [Mode::Skip, Mode::Residual, Mode::Intra];
            let cs: Vec<Mode> = ms.iter().map(|&m| modes[usize::from(m)]).collect();
            // 48x32 px: 3x2 blocks, 6x4 cells.
            let ds: Vec<u16> = ds.iter().cycle().take(24).copied().collect();
            let bits = write_blocks(&ds, &cs, (48, 32));
            let (mut d, mut c) = (Vec::new(), Vec::new());
            read_blocks(&bits, (48, 32), &mut d, &mut c).unwrap();
            prop_assert_eq!(d, ds);
            prop_assert_eq!(c, cs);
        }
    }
}
