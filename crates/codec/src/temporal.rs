//! Temporal prediction by conditional replenishment: a view predicted from
//! the same view of an earlier frame that the receiver holds, for a fixed
//! rig whose pictures change little from frame to frame. A moving rig's
//! views, whose blocks all change, are predicted by motion instead
//! ([`crate::motion`], view coding 7), from the same [`References`].
//!
//! The view is cut into [`BLOCK`]×[`BLOCK`] blocks. A block whose change
//! since the reference is within sensor noise ([`SkipSpec`]) is skipped:
//! the receiver keeps the reference's pixels there. The changed blocks are
//! packed, in raster order, into a mosaic [`BLOCK`] px high per row of
//! blocks and as wide as the view (at most), which goes through the lossy
//! codec of the key frame ([`crate::lossy`]) and is pasted back. Blocks of
//! 16 px are the macroblocks of both codecs (VP8, and JPEG in 4:2:0), so a
//! block in the mosaic codes as it would in the view.
//!
//! The loop is closed: the sender predicts from the reconstruction the
//! receiver holds (what it decoded, bit for bit), never from its originals,
//! so sender and receiver never drift apart. Which blocks changed is judged
//! against the *basis* of the reference instead: for each block, the
//! original the receiver's pixels were coded from. A scene that drifts
//! slowly is so coded again once it has drifted beyond the noise, however
//! small each frame's step.
//!
//! A segmented view ([`PredictedLabels`]) is predicted as the right view
//! is from the left ([`crate::labels`]): its label map is coded with the
//! reference's labels, in its own numbering through a label table sent
//! with it, as the coder's prediction (no shift: the rig is fixed). Labels
//! the reference already has cost a few thousandths of a bit each.
//!
//! A reference is named by its frame id *and* its time stamp
//! ([`RefId`]), so that a restarted sender's frame ids, which start again,
//! never name a frame of an earlier session that the receiver still holds.
//!
//! Payload of a predicted view (after the container's view header):
//!
//! ```text
//! ref frame id (u32) | ref time stamp (u64, µs) | changed map (1 bit a block,
//! raster order, LSB first) | [codec (u8) | mosaic bitstream]  (if any changed)
//! ```

use stereolink_image::{IndexedImage, LabelMap, Rgb, RgbImage};

use crate::container::{self, Reader};
use crate::lossy::{self, LossyCodec, LossyView};
use crate::{labels, CodecError};

/// Side of a block, in pixels.
pub const BLOCK: usize = 16;

/// How many decoded frames a receiver keeps to predict from.
pub const REFERENCES: usize = 4;

/// The frame a predicted view is predicted from: its id and its time stamp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RefId {
    /// The reference's frame id.
    pub frame_id: u32,
    /// The reference's time stamp (µs), as in its header.
    pub timestamp_us: u64,
}

/// When a block counts as unchanged: both its mean absolute difference
/// (over its pixels and channels) and each of its 8×8 quarters' mean
/// difference per channel within their bounds, in grey levels. The first
/// catches changed texture, the second a small change of brightness that
/// noise would hide in the first. `docs/tuning.md` ("Skipped blocks") gives
/// the measurement behind the defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkipSpec {
    /// Largest mean absolute difference of a skipped block.
    pub max_mad: f32,
    /// Largest difference of an 8×8 quarter's mean (per channel).
    pub max_mean: f32,
}

impl Default for SkipSpec {
    /// Sensor noise up to about σ = 3 grey levels is skipped.
    fn default() -> Self {
        SkipSpec {
            max_mad: 4.0,
            max_mean: 2.5,
        }
    }
}

/// The blocks of a `width`×`height` view: `(columns, rows)`.
pub fn blocks((width, height): (usize, usize)) -> (usize, usize) {
    (width.div_ceil(BLOCK), height.div_ceil(BLOCK))
}

/// The blocks of `current` that changed since `basis` beyond `spec`, in
/// raster order.
///
/// # Panics
/// If the images differ in size.
pub fn changed_blocks(current: &RgbImage, basis: &RgbImage, spec: &SkipSpec) -> Vec<bool> {
    assert_eq!(current.dims(), basis.dims(), "views differ in size");
    let (cols, rows) = blocks(current.dims());
    let (w, h) = current.dims();
    let mut changed = Vec::with_capacity(cols * rows);
    for by in 0..rows {
        for bx in 0..cols {
            let (x0, y0) = (bx * BLOCK, by * BLOCK);
            let (x1, y1) = ((x0 + BLOCK).min(w), (y0 + BLOCK).min(h));
            // Per quarter: the sum of differences per channel, and the
            // count of pixels.
            let mut quarters = [([0i32; 3], 0i32); 4];
            let mut abs = 0u32;
            for y in y0..y1 {
                let (c, b) = (&current.row(y)[x0..x1], &basis.row(y)[x0..x1]);
                for (i, (p, q)) in c.iter().zip(b).enumerate() {
                    let quarter = &mut quarters[usize::from(y - y0 >= 8) * 2 + usize::from(i >= 8)];
                    for k in 0..3 {
                        let d = i32::from(p[k]) - i32::from(q[k]);
                        quarter.0[k] += d;
                        abs += d.unsigned_abs();
                    }
                    quarter.1 += 1;
                }
            }
            let n = ((x1 - x0) * (y1 - y0) * 3) as f32;
            let mean_moved = quarters.iter().any(|(sums, count)| {
                *count > 0
                    && sums
                        .iter()
                        .any(|&s| (s.unsigned_abs() as f32) > spec.max_mean * *count as f32)
            });
            changed.push(abs as f32 > spec.max_mad * n || mean_moved);
        }
    }
    changed
}

/// Copies the blocks marked in `changed` from `from` into `into` (same
/// size).
pub fn paste_blocks(into: &mut RgbImage, from: &RgbImage, changed: &[bool]) {
    let (w, h) = into.dims();
    let (cols, _) = blocks((w, h));
    for (i, _) in changed.iter().enumerate().filter(|(_, &c)| c) {
        let (x0, y0) = ((i % cols) * BLOCK, (i / cols) * BLOCK);
        let x1 = (x0 + BLOCK).min(w);
        for y in y0..(y0 + BLOCK).min(h) {
            into.row_mut(y)[x0..x1].copy_from_slice(&from.row(y)[x0..x1]);
        }
    }
}

/// The size of the mosaic of `n` changed blocks of a view `width` px wide:
/// as many blocks a row as the view has, and as few rows as hold them.
pub(crate) fn mosaic_dims(n: usize, width: usize) -> (usize, usize) {
    let cols = width.div_ceil(BLOCK).min(n).max(1);
    (cols * BLOCK, n.div_ceil(cols) * BLOCK)
}

/// The changed blocks of `view` packed into a mosaic; a slot past the
/// view's edge, or past the last block, repeats the nearest pixel (flat,
/// so it costs the codec almost nothing).
pub(crate) fn mosaic(view: &RgbImage, changed: &[bool]) -> RgbImage {
    let (w, h) = view.dims();
    let (cols, _) = blocks((w, h));
    let picked: Vec<usize> = (0..changed.len()).filter(|&i| changed[i]).collect();
    let (mw, mh) = mosaic_dims(picked.len(), w);
    let per_row = mw / BLOCK;
    RgbImage::from_fn(mw, mh, |x, y| {
        let slot = (y / BLOCK) * per_row + x / BLOCK;
        let block = picked[slot.min(picked.len() - 1)];
        let vx = ((block % cols) * BLOCK + x % BLOCK).min(w - 1);
        let vy = ((block / cols) * BLOCK + y % BLOCK).min(h - 1);
        view.get(vx, vy)
    })
}

/// Pastes the mosaic's blocks back into `out` at the changed blocks'
/// places.
pub(crate) fn unpack(mosaic: &RgbImage, changed: &[bool], out: &mut RgbImage) {
    unpack_with(mosaic, changed, out, |to, from, _| to.copy_from_slice(from));
}

/// Puts each changed block's mosaic slot into `out` at the block's place
/// through `put(out's row part, the slot's row part, block index)`: the
/// part inside the view, row by row.
pub(crate) fn unpack_with(
    mosaic: &RgbImage,
    changed: &[bool],
    out: &mut RgbImage,
    mut put: impl FnMut(&mut [Rgb], &[Rgb], usize),
) {
    let (w, h) = out.dims();
    let (cols, _) = blocks((w, h));
    let per_row = mosaic.width() / BLOCK;
    for (slot, i) in (0..changed.len()).filter(|&i| changed[i]).enumerate() {
        let (mx, my) = ((slot % per_row) * BLOCK, (slot / per_row) * BLOCK);
        let (x0, y0) = ((i % cols) * BLOCK, (i / cols) * BLOCK);
        let x1 = (x0 + BLOCK).min(w);
        for dy in 0..(y0 + BLOCK).min(h) - y0 {
            put(
                &mut out.row_mut(y0 + dy)[x0..x1],
                &mosaic.row(my + dy)[mx..mx + x1 - x0],
                i,
            );
        }
    }
}

/// A view predicted from the same view of a reference frame: which blocks
/// changed, their mosaic as coded, and the view it rebuilds (what the
/// receiver shows and keeps).
#[derive(Clone, Debug, PartialEq)]
pub struct PredictedView {
    reference: RefId,
    changed: Vec<bool>,
    mosaic: Option<LossyView>,
    image: RgbImage,
}

impl PredictedView {
    /// Predicts `current` from `reference` (the receiver's reconstruction of
    /// the reference frame's view, named `id`): the blocks in `changed` are
    /// coded with `codec` at `quality`, the others kept.
    ///
    /// # Panics
    /// If the images differ in size or `changed` is not one flag a block.
    pub fn encode(
        current: &RgbImage,
        (id, reference): (RefId, &RgbImage),
        changed: Vec<bool>,
        codec: LossyCodec,
        quality: u8,
    ) -> Result<Self, CodecError> {
        assert_eq!(current.dims(), reference.dims(), "views differ in size");
        let (cols, rows) = blocks(current.dims());
        assert_eq!(changed.len(), cols * rows, "one flag a block");
        let mut image = reference.clone();
        let mosaic = if changed.contains(&true) {
            let coded = lossy::encode(&mosaic(current, &changed), codec, quality)?;
            unpack(coded.image(), &changed, &mut image);
            Some(coded)
        } else {
            None
        };
        Ok(PredictedView {
            reference: id,
            changed,
            mosaic,
            image,
        })
    }

    /// The reference frame.
    pub fn reference(&self) -> RefId {
        self.reference
    }

    /// One flag a block, raster order: coded (true) or kept.
    pub fn changed(&self) -> &[bool] {
        &self.changed
    }

    /// The codec of the changed blocks, if any changed.
    pub fn codec(&self) -> Option<LossyCodec> {
        self.mosaic.as_ref().map(LossyView::codec)
    }

    /// The view rebuilt.
    pub fn image(&self) -> &RgbImage {
        &self.image
    }

    /// The view's payload in the container.
    pub(crate) fn payload(&self) -> Vec<u8> {
        let mut out = reference_bytes(self.reference);
        let mut map = vec![0u8; self.changed.len().div_ceil(8)];
        for (i, _) in self.changed.iter().enumerate().filter(|(_, &c)| c) {
            map[i / 8] |= 1 << (i % 8);
        }
        out.extend_from_slice(&map);
        if let Some(m) = &self.mosaic {
            out.push(m.codec() as u8);
            out.extend_from_slice(m.bytes());
        }
        out
    }
}

/// A segmented view predicted from the same view of a reference frame:
/// the label map as sent, and its payload (reference, label table from
/// the reference's palette to this view's, labels coded).
#[derive(Clone, Debug, PartialEq)]
pub struct PredictedLabels {
    reference: RefId,
    image: IndexedImage,
    payload: Vec<u8>,
}

impl PredictedLabels {
    /// Codes `current` predicted from `reference` (the reference frame's
    /// same view, named `id`), label maps in `mode`.
    ///
    /// # Panics
    /// If the views differ in size.
    pub fn encode(
        current: IndexedImage,
        (id, reference): (RefId, &IndexedImage),
        mode: labels::Mode,
    ) -> Self {
        let mut payload = reference_bytes(id);
        payload.extend(container::predicted_payload(reference, &current, 0, mode));
        PredictedLabels {
            reference: id,
            image: current,
            payload,
        }
    }

    /// A view decoded from its payload.
    pub(crate) fn decoded(reference: RefId, image: IndexedImage, payload: Vec<u8>) -> Self {
        PredictedLabels {
            reference,
            image,
            payload,
        }
    }

    /// The reference frame.
    pub fn reference(&self) -> RefId {
        self.reference
    }

    /// The view: labels and palette.
    pub fn image(&self) -> &IndexedImage {
        &self.image
    }

    /// The view's payload in the container.
    pub(crate) fn payload(&self) -> &[u8] {
        &self.payload
    }
}

/// A reference view's size is the predicted view's (`width`×`height`),
/// or the error.
pub(crate) fn same_size(reference: &RgbImage, (w, h): (usize, usize)) -> Result<(), CodecError> {
    match reference.dims() == (w, h) {
        true => Ok(()),
        false => Err(CodecError::Invalid(format!(
            "a {w}x{h} view predicted from a {}x{} one",
            reference.width(),
            reference.height()
        ))),
    }
}

/// The reference as a payload starts: frame id, then time stamp.
pub(crate) fn reference_bytes(id: RefId) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&id.frame_id.to_le_bytes());
    out.extend_from_slice(&id.timestamp_us.to_le_bytes());
    out
}

/// The reference a predicted payload names, and the rest of the payload.
pub(crate) fn split_reference(payload: &[u8]) -> Result<(RefId, &[u8]), CodecError> {
    let (id, rest) = payload
        .split_first_chunk::<4>()
        .ok_or(CodecError::Truncated("predicted view"))?;
    let (stamp, rest) = rest
        .split_first_chunk::<8>()
        .ok_or(CodecError::Truncated("predicted view"))?;
    let id = RefId {
        frame_id: u32::from_le_bytes(*id),
        timestamp_us: u64::from_le_bytes(*stamp),
    };
    Ok((id, rest))
}

/// A predicted view's payload, parsed: the reference, the changed map and
/// the mosaic's codec and bitstream.
pub(crate) struct Coded<'a> {
    pub(crate) reference: RefId,
    dims: (usize, usize),
    map: &'a [u8],
    blocks: usize,
    mosaic: Option<(LossyCodec, &'a [u8])>,
}

impl<'a> Coded<'a> {
    /// Checks and splits the payload of a `width`×`height` predicted view.
    pub(crate) fn parse(payload: &'a [u8], dims: (usize, usize)) -> Result<Self, CodecError> {
        let (reference, rest) = split_reference(payload)?;
        let mut r = Reader { data: rest, pos: 0 };
        let (cols, rows) = blocks(dims);
        let blocks = cols * rows;
        let map = r.take(blocks.div_ceil(8), "changed-block map")?;
        if blocks % 8 != 0 && map.last().is_some_and(|&b| b >> (blocks % 8) != 0) {
            return Err(CodecError::Invalid(
                "changed-block map flags blocks past the view".into(),
            ));
        }
        let any = map.iter().any(|&b| b != 0);
        let rest = &rest[r.pos..];
        let mosaic = match (any, rest.split_first()) {
            (false, None) => None,
            (false, Some(_)) => {
                return Err(CodecError::Invalid("a mosaic with no changed block".into()))
            }
            (true, None) => return Err(CodecError::Truncated("mosaic")),
            (true, Some((&codec, bits))) => Some((
                LossyCodec::from_u8(codec)
                    .ok_or_else(|| CodecError::Invalid(format!("lossy codec {codec}")))?,
                bits,
            )),
        };
        Ok(Coded {
            reference,
            dims,
            map,
            blocks,
            mosaic,
        })
    }

    /// Whether any block changed.
    pub(crate) fn any_changed(&self) -> bool {
        self.mosaic.is_some()
    }

    /// The changed flags into `out`.
    pub(crate) fn changed_into(&self, out: &mut Vec<bool>) {
        out.clear();
        out.extend((0..self.blocks).map(|i| self.map[i / 8] >> (i % 8) & 1 == 1));
    }

    /// Rebuilds the view into `out` from `reference` (the reference
    /// frame's same view), decoding the mosaic into `scratch`; `changed`
    /// holds [`changed_into`](Self::changed_into)'s flags. Nothing is
    /// allocated once the buffers have the size.
    pub(crate) fn decode_into(
        &self,
        reference: &RgbImage,
        changed: &[bool],
        scratch: &mut RgbImage,
        out: &mut RgbImage,
    ) -> Result<(), CodecError> {
        let (w, h) = self.dims;
        same_size(reference, (w, h))?;
        if out.dims() != (w, h) {
            out.reset(w, h, [0; 3]);
        }
        out.as_mut_slice().copy_from_slice(reference.as_slice());
        if let Some((codec, bits)) = self.mosaic {
            let n = changed.iter().filter(|&&c| c).count();
            lossy::decode_into(codec, bits, mosaic_dims(n, w), scratch)?;
            unpack(scratch, changed, out);
        }
        Ok(())
    }

    /// The view as an owned [`PredictedView`], rebuilt from `reference`.
    pub(crate) fn decode(&self, reference: &RgbImage) -> Result<PredictedView, CodecError> {
        let mut changed = Vec::new();
        self.changed_into(&mut changed);
        let (mut scratch, mut image) = (RgbImage::default(), RgbImage::default());
        self.decode_into(reference, &changed, &mut scratch, &mut image)?;
        let mosaic = self
            .mosaic
            .map(|(codec, bits)| LossyView::decoded(codec, bits.to_vec(), scratch));
        Ok(PredictedView {
            reference: self.reference,
            changed,
            mosaic,
            image,
        })
    }
}

/// The decoded frames a receiver predicts from: the last [`REFERENCES`]
/// kept, each both views. Once full, a frame kept takes the buffers of the
/// oldest, so nothing is allocated after the first frames of a size.
#[derive(Default)]
pub struct References {
    slots: Vec<Slot>,
    /// Counts frames kept, to find the oldest slot.
    clock: u64,
}

struct Slot {
    id: Option<RefId>,
    kept_at: u64,
    /// Segmented views are kept as their labels and palettes, others as
    /// their pixels.
    indexed: bool,
    views: [RgbImage; 2],
    labels: [LabelMap; 2],
    palettes: [Vec<Rgb>; 2],
    /// The cell disparities the frame carried ([`crate::stereo`]), or
    /// those of the pair it repeats.
    disparities: Vec<u16>,
    carried: bool,
}

impl References {
    /// The views of frame `id`, if held (and not segmented).
    pub fn get(&self, id: RefId) -> Option<&[RgbImage; 2]> {
        self.slots
            .iter()
            .find(|s| s.id == Some(id) && !s.indexed)
            .map(|s| &s.views)
    }

    /// The label maps and palettes of segmented frame `id`, if held.
    pub fn get_labels(&self, id: RefId) -> Option<[(&LabelMap, &[Rgb]); 2]> {
        let s = self.slots.iter().find(|s| s.id == Some(id) && s.indexed)?;
        Some([
            (&s.labels[0], &s.palettes[0][..]),
            (&s.labels[1], &s.palettes[1][..]),
        ])
    }

    /// Keeps the views of frame `id` (replacing a frame of the same id,
    /// else the oldest once [`REFERENCES`] are held).
    pub fn keep(&mut self, id: RefId, (left, right): (&RgbImage, &RgbImage)) {
        self.make_slots();
        // Every slot grows with the first frame of a size: none later.
        for view in self.slots.iter_mut().flat_map(|s| &mut s.views) {
            if view.dims() != left.dims() {
                view.reset(left.width(), left.height(), [0; 3]);
            }
        }
        let slot = self.slot(id);
        slot.indexed = false;
        for (into, from) in slot.views.iter_mut().zip([left, right]) {
            if into.dims() != from.dims() {
                into.reset(from.width(), from.height(), [0; 3]);
            }
            into.as_mut_slice().copy_from_slice(from.as_slice());
        }
    }

    /// Keeps the label maps and palettes of segmented frame `id` (as
    /// [`keep`](Self::keep)).
    pub fn keep_labels(&mut self, id: RefId, views: [(&LabelMap, &[Rgb]); 2]) {
        self.make_slots();
        let dims = views[0].0.dims();
        for labels in self.slots.iter_mut().flat_map(|s| &mut s.labels) {
            if labels.dims() != dims {
                labels.reset(dims.0, dims.1, 0);
            }
        }
        let slot = self.slot(id);
        slot.indexed = true;
        for ((labels, palette), (from, colours)) in
            slot.labels.iter_mut().zip(&mut slot.palettes).zip(views)
        {
            if labels.dims() != from.dims() {
                labels.reset(from.width(), from.height(), 0);
            }
            labels.as_mut_slice().copy_from_slice(from.as_slice());
            palette.clear();
            palette.extend_from_slice(colours);
        }
    }

    /// The [`REFERENCES`] slots, empty, on the first frame kept.
    fn make_slots(&mut self) {
        if self.slots.is_empty() {
            self.slots.extend((0..REFERENCES).map(|_| Slot {
                id: None,
                kept_at: 0,
                indexed: false,
                views: Default::default(),
                labels: Default::default(),
                palettes: Default::default(),
                disparities: Vec::new(),
                carried: false,
            }));
        }
    }

    /// The slot frame `id` goes into (the one of its id, else an empty
    /// one, else the oldest), named and stamped.
    fn slot(&mut self, id: RefId) -> &mut Slot {
        self.clock += 1;
        let same = self
            .slots
            .iter()
            .position(|s| s.id.is_some_and(|k| k.frame_id == id.frame_id));
        let i = same.unwrap_or_else(|| {
            (0..self.slots.len())
                .min_by_key(|&i| self.slots[i].kept_at)
                .expect("the slots are made")
        });
        let slot = &mut self.slots[i];
        slot.id = Some(id);
        slot.kept_at = self.clock;
        slot.carried = false;
        slot
    }

    /// Keeps the cell disparities frame `id` (kept already) carried, or
    /// those of the pair it repeats ([`crate::stereo`]).
    pub fn keep_disparities(&mut self, id: RefId, disparities: &[u16]) {
        if let Some(s) = self.slots.iter_mut().find(|s| s.id == Some(id)) {
            s.disparities.clear();
            s.disparities.extend_from_slice(disparities);
            s.carried = true;
        }
    }

    /// The cell disparities kept with frame `id`, if any.
    pub fn disparities(&self, id: RefId) -> Option<&[u16]> {
        let s = self.slots.iter().find(|s| s.id == Some(id) && s.carried)?;
        Some(&s.disparities)
    }

    /// Forgets frame `frame_id` (a frame of that id was rejected: whatever
    /// was held under its id is not what the sender believes delivered).
    pub fn forget(&mut self, frame_id: u32) {
        for s in &mut self.slots {
            if s.id.is_some_and(|k| k.frame_id == frame_id) {
                s.id = None;
                s.kept_at = 0;
            }
        }
    }

    /// Forgets every frame (a new session).
    pub fn clear(&mut self) {
        for s in &mut self.slots {
            s.id = None;
            s.kept_at = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy(w: usize, h: usize, seed: u32) -> RgbImage {
        let mut s = seed.wrapping_mul(2_654_435_761).max(1);
        RgbImage::from_fn(w, h, |x, y| {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            let n = (s % 5) as i32 - 2;
            let v = ((x * 7 + y * 3) % 200) as i32 + 20 + n;
            [v as u8, (v / 2) as u8, (255 - v) as u8]
        })
    }

    #[test]
    fn noise_is_skipped_and_a_change_is_not() {
        let (a, mut b) = (noisy(40, 24, 1), noisy(40, 24, 2));
        let spec = SkipSpec::default();
        assert_eq!(changed_blocks(&b, &a, &spec), vec![false; 6]);
        // A small brightness step in one quarter of the last (partial)
        // block: within the MAD bound, beyond the quarter-mean bound.
        for y in 16..24 {
            for x in 32..40 {
                let p = b.get(x, y);
                b.set(x, y, [p[0] + 6, p[1], p[2]]);
            }
        }
        let changed = changed_blocks(&b, &a, &spec);
        assert_eq!(changed, [false, false, false, false, false, true]);
    }

    #[test]
    fn mosaics_unpack_to_their_blocks_at_any_size() {
        for (w, h) in [(40, 24), (16, 16), (33, 50)] {
            let view = noisy(w, h, 3);
            let n = blocks((w, h)).0 * blocks((w, h)).1;
            let changed: Vec<bool> = (0..n).map(|i| i % 3 != 1).collect();
            let mut out = RgbImage::new(w, h, [0; 3]);
            unpack(&mosaic(&view, &changed), &changed, &mut out);
            let mut want = RgbImage::new(w, h, [0; 3]);
            paste_blocks(&mut want, &view, &changed);
            assert_eq!(out, want, "{w}x{h}");
            assert_ne!(out, RgbImage::new(w, h, [0; 3]));
        }
    }

    #[test]
    fn references_keep_the_newest_and_name_frames_by_time_stamp() {
        let mut refs = References::default();
        let id = |frame_id| RefId {
            frame_id,
            timestamp_us: u64::from(frame_id) * 10,
        };
        let view = noisy(16, 16, 4);
        refs.keep(id(1), (&view, &view));
        // The first frame sizes every slot: the next ones allocate nothing.
        assert!(refs.slots.iter().all(|s| s.views[1].dims() == (16, 16)));
        for f in 2..=6 {
            refs.keep(id(f), (&view, &view));
        }
        assert!(refs.get(id(2)).is_none() && refs.get(id(3)).is_some());
        assert_eq!(refs.slots.len(), REFERENCES);
        // A frame of the same id and another time stamp (a restarted
        // sender) replaces it.
        let restarted = RefId {
            frame_id: 4,
            timestamp_us: 7,
        };
        refs.keep(restarted, (&view, &view));
        assert!(refs.get(id(4)).is_none() && refs.get(restarted).is_some());
        assert!(refs.get(id(3)).is_some(), "the oldest stays");
        refs.forget(4);
        assert!(refs.get(restarted).is_none());
    }
}
