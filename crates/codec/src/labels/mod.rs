//! Lossless coding of label maps with an adaptive context model.
//!
//! Each pixel is coded as a short sequence of binary decisions with the
//! range coder (`rangecoder`): "is it the same label as candidate i?"
//! over the distinct labels of a causal template of the map (W, N, NW, NE,
//! WW, NN, NEE, NWW, NNW, NNE, WWW, NEEE) and, when the map is the right view
//! of a pair, of the **stereo prediction** around P, the left view's label at
//! `x + s` (one shift `s` per block of [`BLOCK`] columns of a row, chosen by
//! the encoder and sent with the row): P, its neighbours E, W, S (the row
//! below: the whole left view is known), N and EE. A decision's context is
//! the candidate's rank and which template positions hold the candidate's
//! label, so flat areas cost a few thousandths of a bit per pixel and edges
//! that the left view already shows cost little more. A label matching no
//! candidate is sent explicitly: label by label among the others (context:
//! the W label) for palettes up to 32 colours, as a binary tree above.
//!
//! Two [`Mode`]s: *fast* gives each decision one context; *strong* mixes
//! nine (`mixer`: the two masks at three sizes, an outer ring of
//! the template, runs, the equalities among the neighbours and three hashes
//! of labels) and, for palettes of per-channel classes, four
//! channel models (`channels`), with two weight sets averaged,
//! refines the result with an `Apm`, and mixes the
//! missed-label decisions too: smaller, and far slower to decode, so fast
//! is the default (docs/tuning.md, “The fast mode is the default”).
//! Probabilities are `Counter`s, which learn
//! fast in rare contexts.
//! `docs/wire-format.md` specifies the stream bit for bit.
//!
//! The modules follow the model's parts: `template` gathers the labels
//! around a pixel, `model` holds the adaptive state, `pixel` codes one
//! pixel's candidates and missed label in either mode, `fast` and `strong`
//! hold each mode's contexts (and the fast mode's row loop), `shifts` the
//! stereo prediction's per-block shifts, and `bitio` lets the encoder and
//! the decoder run the same code.

mod bitio;
mod fast;
mod model;
mod pixel;
mod shifts;
mod strong;
mod template;
#[cfg(test)]
mod tests;

pub use shifts::{plan_shifts, BLOCK, MAX_SHIFT};

use stereolink_image::{LabelMap, Rgb};

use crate::rangecoder::{Decoder, Encoder};
use crate::CodecError;
use bitio::BitIo;
use fast::code_row_fast;
use model::Model;
use shifts::code_shifts;
use strong::code_pixel_strong;
use template::{outer_template, ref_template, NONE};

/// How hard the model works, chosen by the sender and sent as the payload's
/// first byte: decode speed against size.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// One context per decision: the fast decoder (what a receiver wants).
    #[default]
    Fast = 0,
    /// Nine contexts and four channel models per decision, logistically
    /// mixed: smaller, much slower.
    Strong = 1,
}

impl Mode {
    /// The mode's name (`fast` or `strong`), as [`str::parse`] reads it.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Fast => "fast",
            Mode::Strong => "strong",
        }
    }
}

impl std::str::FromStr for Mode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "fast" => Ok(Mode::Fast),
            "strong" => Ok(Mode::Strong),
            _ => Err(format!("unknown label coding mode {s:?} (fast or strong)")),
        }
    }
}

/// What [`code_map`] codes: the map, its width, the palette, the reference
/// and the encoder's shifts.
type MapArgs<'a> = (
    &'a mut [u16],
    usize,
    &'a [Rgb],
    Option<&'a LabelMap>,
    &'a [u8],
);

/// Codes a whole map: `data` holds it for the encoder and receives it in
/// the decoder; `plan` holds the encoder's shifts (row-major, one per block).
fn code_map<I: BitIo, const STRONG: bool>(
    io: &mut I,
    model: &mut Model,
    args: MapArgs,
    shifts: &mut Vec<u8>,
) -> Result<(), CodecError> {
    model.reset(args.2, STRONG);
    match args.3 {
        Some(_) => code_rows::<I, STRONG, true>(io, model, args, shifts),
        None => code_rows::<I, STRONG, false>(io, model, args, shifts),
    }
}

/// [`code_map`] once the model is reset, compiled apart for a map coded
/// conditioned (`COND`, with a reference) and alone, where the prediction's
/// template is all NONE: its reads and masks then vanish.
#[inline(always)]
fn code_rows<I: BitIo, const STRONG: bool, const COND: bool>(
    io: &mut I,
    model: &mut Model,
    (data, w, palette, reference, plan): MapArgs,
    shifts: &mut Vec<u8>,
) -> Result<(), CodecError> {
    let n_labels = palette.len();
    let blocks = w.div_ceil(BLOCK);
    shifts.clear();
    shifts.resize(blocks, 0);
    let h = data.len().checked_div(w).unwrap_or(0);
    if STRONG {
        model.column_runs.clear();
        model.column_runs.resize(w, 0);
    }
    for y in 0..h {
        // How many pixels left of W hold W's label.
        let mut row_run = 0u32;
        if reference.is_some() {
            code_shifts(io, model, plan.get(y * blocks..).unwrap_or(&[]), shifts);
        }
        if !STRONG {
            code_row_fast::<I, COND>(io, model, n_labels, (data, w, y), reference, shifts)?;
        }
        for x in (0..w).filter(|_| STRONG) {
            let rf = match reference {
                Some(r) if COND => ref_template(r, x + shifts[x / BLOCK] as usize, y),
                _ => [NONE; 6],
            };
            let i = y * w + x;
            let v = data[i] as u32;
            // Bit length of a run, up to 7.
            let q = |n: u32| (u32::BITS - n.leading_zeros()).min(7) as usize;
            model.runs = q(row_run) << 3 | q(model.column_runs[x]);
            model.outer = outer_template(data, w, x, y);
            data[i] = code_pixel_strong::<I, COND>(io, model, n_labels, (data, w, x, y), &rf, v)?;
            let (l, runs) = (data[i], &mut model.column_runs[x]);
            row_run = if x > 0 && l == data[i - 1] {
                row_run + 1
            } else {
                0
            };
            *runs = if y > 0 && l == data[i - w] {
                *runs + 1
            } else {
                0
            };
        }
        if io.overrun() {
            return Err(CodecError::Truncated("label stream"));
        }
    }
    Ok(())
}

/// Codes `map` (labels index `palette`, whose colours inform the strong
/// mode's channel models (`channels`)); with `reference`, predicts
/// from it through per-block shifts searched up to `max_shift`.
pub fn encode(
    map: &LabelMap,
    palette: &[Rgb],
    reference: Option<&LabelMap>,
    max_shift: usize,
    mode: Mode,
) -> Vec<u8> {
    let w = map.width();
    let plan = reference.map_or_else(Vec::new, |r| plan_shifts(map, r, max_shift));
    let mut enc = Encoder::new();
    let mut data = map.as_slice().to_vec();
    let (model, shifts) = (&mut Model::new(), &mut Vec::new());
    let args = (&mut data[..], w, palette, reference, &plan[..]);
    match mode {
        Mode::Fast => code_map::<_, false>(&mut enc, model, args, shifts),
        Mode::Strong => code_map::<_, true>(&mut enc, model, args, shifts),
    }
    .expect("the encoder codes its own labels");
    let mut out = vec![mode as u8];
    out.extend(enc.finish());
    out
}

/// Decodes a `w`×`h` map written by [`encode`] (with the same palette and
/// reference).
///
/// Fails if a decoded label does not index `palette` or the stream ends too early.
pub fn decode(
    bytes: &[u8],
    w: usize,
    h: usize,
    palette: &[Rgb],
    reference: Option<&LabelMap>,
) -> Result<LabelMap, CodecError> {
    let mut out = LabelMap::new(w, h, 0);
    decode_into(bytes, palette, reference, &mut out)?;
    Ok(out)
}

/// [`decode`] into a caller-provided map (its size gives `w`×`h`).
pub fn decode_into(
    bytes: &[u8],
    palette: &[Rgb],
    reference: Option<&LabelMap>,
    out: &mut LabelMap,
) -> Result<(), CodecError> {
    LabelDecoder::default().decode_into(bytes, palette, reference, out)
}

/// Decodes map after map with one model and buffers, so that a receiver
/// decoding frame after frame allocates nothing once they have grown.
pub struct LabelDecoder {
    model: Model,
    shifts: Vec<u8>,
}

impl Default for LabelDecoder {
    fn default() -> Self {
        LabelDecoder {
            model: Model::new(),
            shifts: Vec::new(),
        }
    }
}

impl LabelDecoder {
    /// [`decode`] into a caller-provided map (its size gives `w`×`h`).
    pub fn decode_into(
        &mut self,
        bytes: &[u8],
        palette: &[Rgb],
        reference: Option<&LabelMap>,
        out: &mut LabelMap,
    ) -> Result<(), CodecError> {
        let (w, h) = out.dims();
        if let Some(r) = reference {
            if r.dims() != (w, h) {
                return Err(CodecError::Invalid("reference view size differs".into()));
            }
        }
        let (&mode, coded) = bytes
            .split_first()
            .ok_or(CodecError::Truncated("label stream"))?;
        let mut dec = Decoder::new(coded);
        let (model, shifts) = (&mut self.model, &mut self.shifts);
        let args = (out.as_mut_slice(), w, palette, reference, &[][..]);
        match mode {
            0 => code_map::<_, false>(&mut dec, model, args, shifts),
            1 => code_map::<_, true>(&mut dec, model, args, shifts),
            m => Err(CodecError::Invalid(format!("label coding mode {m}"))),
        }
    }
}
