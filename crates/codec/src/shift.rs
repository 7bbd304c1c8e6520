//! Prediction by shifted cells, block modes and a mosaic: the coding that
//! both [`crate::stereo`] (the right view from the frame's decoded left
//! view, horizontal disparities) and [`crate::motion`] (a view from its own
//! decoded previous view, 2-D motion vectors) use.
//!
//! Each cell of the view carries an integer vector `(dx, dy)`: its
//! prediction is the decoded source view there, `(dx, dy)` px away,
//! clamped at the edges: `pred(x, y) = source(x + dx, y + dy)`. Each
//! [`BLOCK`]×[`BLOCK`] block then has a [`Mode`]: *skipped* (the
//! prediction alone), a *residual* (the prediction's error, offset by 128)
//! or *intra* (its pixels). Coded blocks are packed into one mosaic, coded
//! by the lossy codec, and put over the prediction, as [`crate::temporal`]
//! packs changed blocks.
//!
//! The block data are range coded: each block's mode in raster order,
//! then each cell's vector less the component-wise median of its left,
//! upper and upper-right neighbours', one component (stereo's `dx`) or two
//! (motion's `dx` and `dy`), each as a "moved" flag (by the block's
//! mode), a sign and an Exp-Golomb magnitude. Payload (after whatever the
//! caller puts first):
//!
//! ```text
//! blocks length (u32) | blocks (range coded) | [codec (u8) | mosaic bitstream]  (if any block is coded)
//! ```
//!
//! Decoding allocates nothing once its buffers have grown to a view's
//! size (the lossy decoders aside), and uses integers only: the board has
//! no FPU. A vector decoded out of its range, a mosaic with no coded
//! block, a coded block without a mosaic, and blocks data that end early
//! are a [`CodecError`], never a panic.

use stereolink_image::RgbImage;

use crate::lossy::{self, LossyCodec, LossyView};
use crate::rangecoder::{Decoder, Encoder, Prob};
use crate::temporal::{self, blocks, BLOCK};
use crate::{motion, stereo, CodecError};

/// A cell's vector: `(dx, dy)` px from the cell to its prediction in the
/// source view.
pub type Vector = [i32; 2];

/// What a view is predicted from, which sets its cells and its vectors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Shift {
    /// The right view from the left: [`stereo::CELL`]-px cells, horizontal
    /// disparities in `0..=width` (one component coded).
    Disparity,
    /// A view from its previous one: [`motion::CELL`]-px cells, 2-D
    /// vectors within the view's size.
    Motion,
}

impl Shift {
    /// Side of a cell (px).
    pub(crate) fn cell(self) -> usize {
        match self {
            Shift::Disparity => stereo::CELL,
            Shift::Motion => motion::CELL,
        }
    }

    /// The components coded: `dx`, or `dx` and `dy`.
    fn axes(self) -> usize {
        match self {
            Shift::Disparity => 1,
            Shift::Motion => 2,
        }
    }

    /// Whether component `k` of a vector is valid in a `width`×`height`
    /// view.
    fn allows(self, k: usize, v: i64, (width, height): (usize, usize)) -> bool {
        let size = [width, height][k] as i64;
        match self {
            Shift::Disparity => (0..=size).contains(&v),
            Shift::Motion => (-size..=size).contains(&v),
        }
    }

    /// Weight of a vector's residual bits against its cell's summed
    /// absolute difference in the search: [`LAMBDA`] per 8×8 px.
    fn lambda(self) -> u32 {
        LAMBDA * (self.cell() * self.cell() / 64) as u32
    }

    /// The errors' names: the view, its blocks, its mosaic.
    fn names(self) -> [&'static str; 3] {
        match self {
            Shift::Disparity => [
                "stereo view",
                "stereo view's blocks",
                "stereo view's mosaic",
            ],
            Shift::Motion => [
                "motion view",
                "motion view's blocks",
                "motion view's mosaic",
            ],
        }
    }

    /// The cells of a `width`×`height` view: `(columns, rows)`.
    pub(crate) fn cells(self, (width, height): (usize, usize)) -> (usize, usize) {
        (width.div_ceil(self.cell()), height.div_ceil(self.cell()))
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

/// How the sender chooses each block's mode. A block is *skipped* (its
/// prediction kept) when the prediction's squared error against the
/// original is at most `skip_ratio` times the source view's coding error
/// (squared, over the pixels the prediction comes from) plus `skip_floor`²
/// per sample. Otherwise it is coded *intra* (its pixels) when the
/// prediction's error exceeds `intra_ratio` times the block's own energy
/// about its mean (the prediction is worse than none: an occlusion, or
/// new content), else as a *residual* (the prediction's error).
/// `docs/tuning.md` ("Stereo prediction") gives the measurement behind the
/// defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModeSpec {
    /// Skipped when the prediction's error is within this many times the
    /// source view's coding error ...
    pub skip_ratio: f32,
    /// ... plus this RMS error (grey levels).
    pub skip_floor: f32,
    /// Coded intra when the prediction's error exceeds this many times the
    /// block's energy about its mean.
    pub intra_ratio: f32,
    /// The coded blocks' quality, less the source view's (the codec's
    /// steps).
    pub quality_drop: u8,
}

impl Default for ModeSpec {
    fn default() -> Self {
        ModeSpec {
            skip_ratio: 2.0,
            skip_floor: 2.0,
            intra_ratio: 1.0,
            quality_drop: 10,
        }
    }
}

/// Bits of the largest vector residual's exponent.
const MAX_EXP: usize = 15;

/// Weight of a vector's residual bits against an 8×8 cell's summed
/// absolute difference in the search (docs/tuning.md, "Stereo
/// prediction"): smooth vectors cost fewer bits, predict about as well,
/// and make a cleaner map.
const LAMBDA: u32 = 48;

/// The vectors and block modes of a view, and its prediction: all the
/// sender decides before coding the blocks (none of it depends on the
/// quality, so a rate control codes the same plan at each quality).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Plan {
    pub(crate) shift: Shift,
    pub(crate) vectors: Vec<Vector>,
    pub(crate) modes: Vec<Mode>,
    predicted: RgbImage,
}

impl Plan {
    /// The plan of `current` predicted from `source_sent` (the source view
    /// as the receiver decoded it; `source` is what it was coded from,
    /// which tells its coding error) by `vectors`.
    ///
    /// # Panics
    /// If the views differ in size.
    pub(crate) fn new(
        current: &RgbImage,
        (source, source_sent): (&RgbImage, &RgbImage),
        shift: Shift,
        vectors: Vec<Vector>,
        spec: &ModeSpec,
    ) -> Self {
        assert_eq!(current.dims(), source.dims(), "views differ in size");
        assert_eq!(source.dims(), source_sent.dims(), "views differ in size");
        let mut predicted = RgbImage::default();
        warp_into(source_sent, &vectors, shift.cell(), &mut predicted);
        let modes = modes(
            current,
            (source, source_sent),
            &predicted,
            &vectors,
            shift,
            spec,
        );
        Plan {
            shift,
            vectors,
            modes,
            predicted,
        }
    }

    /// What each pixel of the view is rebuilt from, among originals:
    /// `current` in the coded blocks, else `source` (the source view's
    /// original) where the prediction takes it.
    pub(crate) fn basis(&self, current: &RgbImage, source: &RgbImage) -> RgbImage {
        let mut out = RgbImage::default();
        warp_into(source, &self.vectors, self.shift.cell(), &mut out);
        let coded: Vec<bool> = self.modes.iter().map(|&m| m != Mode::Skip).collect();
        temporal::paste_blocks(&mut out, current, &coded);
        out
    }
}

/// A view coded by shifted cells: its plan's vectors and modes, the blocks
/// data, the coded blocks' mosaic, and the view it rebuilds.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Shifted {
    pub(crate) vectors: Vec<Vector>,
    pub(crate) modes: Vec<Mode>,
    blocks: Vec<u8>,
    mosaic: Option<LossyView>,
    image: RgbImage,
}

impl Shifted {
    /// Codes `current` by `plan`, the coded blocks with `codec` at
    /// `quality`.
    pub(crate) fn encode(
        current: &RgbImage,
        plan: &Plan,
        codec: LossyCodec,
        quality: u8,
    ) -> Result<Self, CodecError> {
        let (w, h) = current.dims();
        let mut image = plan.predicted.clone();
        let coded: Vec<bool> = plan.modes.iter().map(|&m| m != Mode::Skip).collect();
        let mosaic = if coded.contains(&true) {
            // What each coded block's slot holds: its pixels, or its
            // prediction's error offset by 128.
            let cols = blocks((w, h)).0;
            let source = RgbImage::from_fn(w, h, |x, y| {
                let (r, p) = (current.get(x, y), image.get(x, y));
                match plan.modes[(y / BLOCK) * cols + x / BLOCK] {
                    Mode::Residual => [0, 1, 2]
                        .map(|k| (i32::from(r[k]) - i32::from(p[k]) + 128).clamp(0, 255) as u8),
                    Mode::Skip | Mode::Intra => r,
                }
            });
            let m = lossy::encode(&temporal::mosaic(&source, &coded), codec, quality)?;
            paste(m.image(), &coded, &plan.modes, &mut image);
            Some(m)
        } else {
            None
        };
        Ok(Shifted {
            vectors: plan.vectors.clone(),
            modes: plan.modes.clone(),
            blocks: write_blocks(&plan.vectors, &plan.modes, (w, h), plan.shift),
            mosaic,
            image,
        })
    }

    /// Decodes a payload predicted from `source`.
    pub(crate) fn decode(
        payload: &[u8],
        source: &RgbImage,
        shift: Shift,
    ) -> Result<Self, CodecError> {
        let mut d = ShiftDecoder::default();
        let mut image = RgbImage::default();
        d.decode_into(payload, source, shift, &mut image)?;
        let parsed = parse(payload, shift)?;
        let mosaic = parsed
            .mosaic
            .map(|(codec, bits)| LossyView::decoded(codec, bits.to_vec(), d.mosaic));
        Ok(Shifted {
            vectors: d.vectors,
            modes: d.modes,
            blocks: parsed.blocks.to_vec(),
            mosaic,
            image,
        })
    }

    /// The codec of the coded blocks, if any is coded.
    pub(crate) fn codec(&self) -> Option<LossyCodec> {
        self.mosaic.as_ref().map(LossyView::codec)
    }

    /// The view rebuilt.
    pub(crate) fn image(&self) -> &RgbImage {
        &self.image
    }

    /// Appends the payload to `out`.
    pub(crate) fn payload_into(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&(self.blocks.len() as u32).to_le_bytes());
        out.extend_from_slice(&self.blocks);
        if let Some(m) = &self.mosaic {
            out.push(m.codec() as u8);
            out.extend_from_slice(m.bytes());
        }
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

fn parse(payload: &[u8], shift: Shift) -> Result<Parsed<'_>, CodecError> {
    let [view, blocks_name, _] = shift.names();
    let (len, rest) = payload
        .split_first_chunk::<4>()
        .ok_or(CodecError::Truncated(view))?;
    let (blocks, rest) = rest
        .split_at_checked(u32::from_le_bytes(*len) as usize)
        .ok_or(CodecError::Truncated(blocks_name))?;
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

/// Decodes views coded by shifted cells into buffers it keeps: after the
/// first view of a size it allocates nothing (the lossy decoders aside,
/// as for any lossy view).
#[derive(Default)]
pub(crate) struct ShiftDecoder {
    pub(crate) vectors: Vec<Vector>,
    modes: Vec<Mode>,
    coded: Vec<bool>,
    mosaic: RgbImage,
}

impl ShiftDecoder {
    /// Rebuilds the view of `payload` into `out` from `source` (its size
    /// is the view's).
    pub(crate) fn decode_into(
        &mut self,
        payload: &[u8],
        source: &RgbImage,
        shift: Shift,
        out: &mut RgbImage,
    ) -> Result<(), CodecError> {
        let parsed = parse(payload, shift)?;
        let (w, _) = source.dims();
        read_blocks(
            parsed.blocks,
            source.dims(),
            shift,
            &mut self.vectors,
            &mut self.modes,
        )?;
        self.coded.clear();
        self.coded
            .extend(self.modes.iter().map(|&m| m != Mode::Skip));
        let any = self.coded.contains(&true);
        warp_into(source, &self.vectors, shift.cell(), out);
        match (any, parsed.mosaic) {
            (false, None) => Ok(()),
            (false, Some(_)) => Err(CodecError::Invalid("a mosaic with no coded block".into())),
            (true, None) => Err(CodecError::Truncated(shift.names()[2])),
            (true, Some((codec, bits))) => {
                let n = self.coded.iter().filter(|&&c| c).count();
                lossy::decode_into(codec, bits, temporal::mosaic_dims(n, w), &mut self.mosaic)?;
                paste(&self.mosaic, &self.coded, &self.modes, out);
                Ok(())
            }
        }
    }
}

/// The source pixel that pixel `(x, y)` of a `w`×`h` view is predicted
/// from by `v` (clamped at the edges).
fn source_of(x: usize, y: usize, v: Vector, (w, h): (usize, usize)) -> (usize, usize) {
    let at = |p: usize, d: i32, n: usize| (p as i64 + i64::from(d)).clamp(0, n as i64 - 1) as usize;
    (at(x, v[0], w), at(y, v[1], h))
}

/// `source` shifted per `cell`-px cell by `vectors` into `out` (resized if
/// need be): out(x, y) = source(x + dx, y + dy), clamped at the edges.
fn warp_into(source: &RgbImage, vectors: &[Vector], cell: usize, out: &mut RgbImage) {
    let (w, h) = source.dims();
    if out.dims() != (w, h) {
        out.reset(w, h, [0; 3]);
    }
    let cols = w.div_ceil(cell);
    for y in 0..h {
        let to = out.row_mut(y);
        for cx in 0..cols {
            let v = vectors[(y / cell) * cols + cx];
            let from = source.row(source_of(0, y, v, (w, h)).1);
            let (x0, x1) = (cx * cell, ((cx + 1) * cell).min(w));
            // Inside: the x whose x + dx is within 0..w.
            let dx = i64::from(v[0]);
            let lo = (-dx).clamp(x0 as i64, x1 as i64) as usize;
            let hi = (w as i64 - dx).clamp(lo as i64, x1 as i64) as usize;
            to[x0..lo].fill(from[0]);
            if hi > lo {
                let s = (lo as i64 + dx) as usize;
                to[lo..hi].copy_from_slice(&from[s..s + hi - lo]);
            }
            to[hi..x1].fill(from[w - 1]);
        }
    }
}

/// The component-wise median of a cell's causal neighbours' vectors (left,
/// upper, upper-right, or upper-left at the right edge); one neighbour
/// alone is taken as is, none gives 0.
fn predictor(v: &[Vector], cols: usize, i: usize) -> Vector {
    let (bx, by) = (i % cols, i / cols);
    match (bx > 0, by > 0) {
        (false, false) => [0, 0],
        (true, false) => v[i - 1],
        (false, true) => v[i - cols],
        (true, true) => {
            let corner = if bx + 1 < cols {
                v[i - cols + 1]
            } else {
                v[i - cols - 1]
            };
            let (a, b, c) = (v[i - 1], v[i - cols], corner);
            [0, 1].map(|k| a[k].max(b[k]).min(a[k].min(b[k]).max(c[k])))
        }
    }
}

/// One vector component's adaptive models.
#[derive(Default)]
struct Component {
    /// Whether it differs from its prediction, by the block's mode.
    moved: [Prob; 3],
    sign: Prob,
    /// Exp-Golomb exponent, one probability a bit of its unary code.
    exp: [Prob; MAX_EXP],
}

/// The adaptive models of the blocks' data.
#[derive(Default)]
struct Model {
    /// A block's mode, by how many of its left and upper neighbours are
    /// coded.
    mode: [Prob; 3],
    /// A coded block's: intra or residual.
    intra: Prob,
    axes: [Component; 2],
}

/// The mode context of block `i`: coded neighbours, left and above.
fn mode_context(modes: &[Mode], cols: usize, i: usize) -> usize {
    let left = i % cols > 0 && modes[i - 1] != Mode::Skip;
    let up = i >= cols && modes[i - cols] != Mode::Skip;
    usize::from(left) + usize::from(up)
}

/// Range codes the modes of a `width`×`height` view's blocks, then its
/// cells' vectors.
pub(crate) fn write_blocks(
    vectors: &[Vector],
    modes: &[Mode],
    dims: (usize, usize),
    shift: Shift,
) -> Vec<u8> {
    let (bcols, ccols) = (blocks(dims).0, shift.cells(dims).0);
    let mut enc = Encoder::new();
    let mut m = Model::default();
    for (i, &mode) in modes.iter().enumerate() {
        enc.bit(
            &mut m.mode[mode_context(modes, bcols, i)],
            mode != Mode::Skip,
        );
        if mode != Mode::Skip {
            enc.bit(&mut m.intra, mode == Mode::Intra);
        }
    }
    for (i, &v) in vectors.iter().enumerate() {
        let mode = modes[block_of(i, ccols, bcols, shift.cell())];
        let p = predictor(vectors, ccols, i);
        for (k, c) in m.axes[..shift.axes()].iter_mut().enumerate() {
            let r = v[k] - p[k];
            enc.bit(&mut c.moved[mode as usize], r != 0);
            if r != 0 {
                enc.bit(&mut c.sign, r < 0);
                let mag = r.unsigned_abs();
                let e = (31 - mag.leading_zeros()) as usize;
                for p in &mut c.exp[..e] {
                    enc.bit(p, true);
                }
                if e < MAX_EXP {
                    enc.bit(&mut c.exp[e], false);
                }
                enc.direct(mag - (1 << e), e as u32);
            }
        }
    }
    enc.finish()
}

/// The block holding cell `i` (of `ccols` a row; `bcols` blocks a row).
fn block_of(i: usize, ccols: usize, bcols: usize, cell: usize) -> usize {
    let (cx, cy) = (i % ccols, i / ccols);
    (cy * cell / BLOCK) * bcols + cx * cell / BLOCK
}

/// Decodes the block modes and cell vectors of a `width`×`height` view
/// into `vectors` and `modes`.
pub(crate) fn read_blocks(
    bits: &[u8],
    dims: (usize, usize),
    shift: Shift,
    vectors: &mut Vec<Vector>,
    modes: &mut Vec<Mode>,
) -> Result<(), CodecError> {
    let (bcols, brows) = blocks(dims);
    let (ccols, crows) = shift.cells(dims);
    vectors.clear();
    modes.clear();
    let mut dec = Decoder::new(bits);
    let mut m = Model::default();
    for i in 0..bcols * brows {
        let mode = match dec.bit(&mut m.mode[mode_context(modes, bcols, i)]) {
            false => Mode::Skip,
            true if dec.bit(&mut m.intra) => Mode::Intra,
            true => Mode::Residual,
        };
        modes.push(mode);
    }
    for i in 0..ccols * crows {
        let mode = modes[block_of(i, ccols, bcols, shift.cell())];
        let p = predictor(vectors, ccols, i);
        let mut v = [0; 2];
        for (k, c) in m.axes[..shift.axes()].iter_mut().enumerate() {
            let mut d = i64::from(p[k]);
            if dec.bit(&mut c.moved[mode as usize]) {
                let negative = dec.bit(&mut c.sign);
                let mut e = 0;
                while e < MAX_EXP && dec.bit(&mut c.exp[e]) {
                    e += 1;
                }
                let mag = (1i64 << e) + i64::from(dec.direct(e as u32));
                d += if negative { -mag } else { mag };
            }
            if !shift.allows(k, d, dims) {
                return Err(CodecError::Invalid(format!(
                    "a cell shift of {d} px in a {}x{} view",
                    dims.0, dims.1
                )));
            }
            v[k] = d as i32;
        }
        vectors.push(v);
    }
    if dec.overrun() {
        return Err(CodecError::Truncated(shift.names()[1]));
    }
    Ok(())
}

/// Whether `payload` predicts its `width`×`height` view as the source
/// alone, unmoved: every block skipped, every vector zero (read as
/// [`read_blocks`] reads it, without allocating).
pub(crate) fn unmoved(payload: &[u8], dims: (usize, usize), shift: Shift) -> bool {
    let Ok(parsed) = parse(payload, shift) else {
        return false;
    };
    let (bcols, brows) = blocks(dims);
    let (ccols, crows) = shift.cells(dims);
    let mut dec = Decoder::new(parsed.blocks);
    let mut m = Model::default();
    // With no block coded so far, every mode's context is 0; with every
    // vector zero so far, every prediction is zero.
    let skipped = (0..bcols * brows).all(|_| !dec.bit(&mut m.mode[0]));
    let zero = skipped
        && (0..ccols * crows).all(|_| {
            let axes = &mut m.axes[..shift.axes()];
            axes.iter_mut()
                .all(|c| !dec.bit(&mut c.moved[Mode::Skip as usize]))
        });
    parsed.mosaic.is_none() && zero && !dec.overrun()
}

/// The summed absolute difference of the pixels of cell `(x0, y0)` of
/// `current` (`cell` px, cut at the edge) against `source` shifted by `v`.
fn sad(
    current: &RgbImage,
    source: &RgbImage,
    (x0, y0): (usize, usize),
    cell: usize,
    v: Vector,
) -> u32 {
    let (w, h) = current.dims();
    let (x1, y1) = ((x0 + cell).min(w), (y0 + cell).min(h));
    let mut sad = 0u32;
    for y in y0..y1 {
        let (c, s) = (current.row(y), source.row(source_of(0, y, v, (w, h)).1));
        for x in x0..x1 {
            let q = s[source_of(x, 0, v, (w, h)).0];
            for k in 0..3 {
                sad += u32::from(c[x][k].abs_diff(q[k]));
            }
        }
    }
    sad
}

/// Each cell's vector, in raster order: the one `choose(prediction,
/// vectors found so far, cell index, cost)` returns, given the median
/// prediction and the cost of a vector: the cell's [`sad`] plus
/// [`Shift::lambda`] a bit of its residual from the prediction.
pub(crate) fn search(
    current: &RgbImage,
    source: &RgbImage,
    shift: Shift,
    mut choose: impl FnMut(Vector, &[Vector], usize, &dyn Fn(Vector) -> u32) -> Vector,
) -> Vec<Vector> {
    let (cols, rows) = shift.cells(current.dims());
    let cell = shift.cell();
    let mut vectors = Vec::with_capacity(cols * rows);
    for i in 0..cols * rows {
        let origin = ((i % cols) * cell, (i / cols) * cell);
        let pred = predictor(&vectors, cols, i);
        let cost = |v: Vector| {
            let bits: u32 = (0..shift.axes())
                .map(|k| residual_bits(v[k] - pred[k]))
                .sum();
            sad(current, source, origin, cell, v) + shift.lambda() * bits
        };
        let v = choose(pred, &vectors, i, &cost);
        vectors.push(v);
    }
    vectors
}

/// About the bits a vector component's residual takes.
fn residual_bits(r: i32) -> u32 {
    match r.unsigned_abs() {
        0 => 1,
        m => 3 + 2 * (31 - m.leading_zeros()),
    }
}

/// Each block's mode ([`ModeSpec`]): skipped when its prediction's
/// squared error is within what the source view's coding error where the
/// prediction comes from allows; else intra when the prediction is worse
/// than the block's own energy about its mean allows, else a residual.
fn modes(
    current: &RgbImage,
    (source, source_sent): (&RgbImage, &RgbImage),
    predicted: &RgbImage,
    vectors: &[Vector],
    shift: Shift,
    spec: &ModeSpec,
) -> Vec<Mode> {
    let (w, h) = current.dims();
    let (cols, rows) = blocks((w, h));
    let (ccols, cell) = (shift.cells((w, h)).0, shift.cell());
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
                    let r = current.get(x, y);
                    err += sq(r, predicted.get(x, y));
                    let v = vectors[(y / cell) * ccols + x / cell];
                    let (xs, ys) = source_of(x, y, v, (w, h));
                    noise += sq(source.get(xs, ys), source_sent.get(xs, ys));
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_warp_takes_each_cell_from_its_vector_clamped_at_the_edges() {
        let source = RgbImage::from_fn(20, 12, |x, y| [x as u8, y as u8, 0]);
        let cell = 8;
        // 3x2 cells: each its own vector, some past the edges.
        let vectors = [[0, 0], [3, -2], [5, 1], [-9, 0], [0, 7], [-2, -2]];
        let mut out = RgbImage::default();
        warp_into(&source, &vectors, cell, &mut out);
        for y in 0..12 {
            for x in 0..20 {
                let v = vectors[(y / cell) * 3 + x / cell];
                let (xs, ys) = source_of(x, y, v, (20, 12));
                assert_eq!(out.get(x, y), source.get(xs, ys), "({x}, {y})");
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(100))]
        #[test]
        fn motion_blocks_data_round_trip(
            vs in proptest::collection::vec((-48i32..=48, -32i32..=32), 24),
            ms in proptest::collection::vec(0u8..3, 6),
        ) {
            let modes = [Mode::Skip, Mode::Residual, Mode::Intra];
            let cs: Vec<Mode> = ms.iter().map(|&m| modes[usize::from(m)]).collect();
            // 48x32 px: 3x2 blocks, and 6x4 cells of 8 px or 3x2 of 16.
            let n = Shift::Motion.cells((48, 32));
            let vs: Vec<Vector> = vs.iter().take(n.0 * n.1).map(|&(x, y)| [x, y]).collect();
            let bits = write_blocks(&vs, &cs, (48, 32), Shift::Motion);
            let (mut v, mut c) = (Vec::new(), Vec::new());
            read_blocks(&bits, (48, 32), Shift::Motion, &mut v, &mut c).unwrap();
            prop_assert_eq!(v, vs);
            prop_assert_eq!(c, cs);
        }
    }
}
