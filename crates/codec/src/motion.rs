//! Motion-compensated temporal prediction: a view predicted from the same
//! view of an earlier frame that the receiver holds, shifted per cell by
//! the sender's motion vectors, with what the motion misses coded per
//! block. The sender codes every lossy predicted view so: on a still rig,
//! the blocks within sensor noise are skipped with a zero vector, as
//! conditional replenishment ([`crate::temporal`], view coding 4, which
//! receivers still decode) skips them, and a still view costs a few bytes;
//! on a moving rig, where replenishment finds every block changed, each
//! block follows its motion.
//!
//! Each [`CELL`]×[`CELL`] cell carries an integer vector `(dx, dy)`: its
//! prediction is the reference view as the receiver decoded it, at
//! `(x + dx, y + dy)` (clamped at the edges). Each block is then skipped
//! (the prediction alone: with a zero vector, replenishment's skip; with
//! another, a block predicted by its motion), coded as a residual over the
//! prediction, or coded intra (new content coming into the view), its
//! coded blocks in one mosaic: the coding by shifted cells of
//! [`crate::shift`], which stereo prediction ([`crate::stereo`]) shares.
//! The skip test scales with the reference's coding error where the
//! prediction comes from, measured against the *basis* of the reference
//! (the originals its pixels were coded from, moved with them: see
//! [`MotionPlan::basis`]), so that a scene that drifts is coded again once
//! it has drifted beyond its coding error.
//!
//! The loop is closed: vectors are searched against the reference as the
//! receiver decoded it, so both ends predict the same pixels bit for bit.
//!
//! Cells are 16 px (a codec macroblock, one vector a block), not the 8 px
//! of stereo cells: at the low qualities a thin link affords, the decoded
//! reference is smooth and sensor noise moves 8-px cells' best vectors at
//! random, whose bits then outweigh what they predict; 16-px cells, their
//! rate term scaled with their area, cost a quarter of the vectors and
//! predict a moving rig's views as well (measured on the `pan` sequence:
//! `docs/benchmarks.md`, "Sequences against x264").
//!
//! The search (±[`MotionSpec::range`] px in both directions) is a coarse
//! grid of every 4th vector, plus the median prediction and the left and
//! upper neighbours' vectors, refined by a small diamond (±1 px steps
//! while the cost falls). A rig's motion is smooth over the view, so the
//! neighbours' vectors find most cells' exactly, and the grid finds the
//! first ones and any that move otherwise: about 90 costs a cell instead
//! of 1,089 for a full search of ±16 px, which would take the sender's
//! small CPU 12 times as long. The cost is the cell's summed absolute
//! difference plus [`crate::shift`]'s rate term on the vector's residual.
//!
//! Decoding is a copy per cell row, the mosaic's lossy decode, and an add
//! per residual pixel: integers only, and nothing allocated once the
//! buffers have grown but by the lossy decoder of a mosaic (a still view
//! has none). The coded blocks are coded [`ModeSpec::quality_drop`]
//! quality steps below the frame's, as stereo prediction codes them.
//!
//! Payload of a motion-predicted view (after the container's view header;
//! `docs/wire-format.md`, coding 7):
//!
//! ```text
//! ref frame id (u32) | ref time stamp (u64, µs) | blocks length (u32) |
//! blocks (range coded: each block's mode in raster order, then each cell's
//! dx and dy less the medians of its left, upper and upper-right
//! neighbours') | [codec (u8) | mosaic bitstream]  (if any block is coded)
//! ```
//!
//! A vector component decoded beyond the view's width (dx) or height (dy)
//! is an error, as are a truncated reference or blocks, a mosaic with no
//! coded block and a coded block without a mosaic: a corrupt payload is a
//! [`CodecError`], never a panic.

use stereolink_image::RgbImage;

use crate::lossy::LossyCodec;
use crate::shift::{search, Plan, Shift, ShiftDecoder, Shifted};
pub use crate::shift::{Mode, ModeSpec, Vector};
use crate::temporal::{self, RefId};
use crate::CodecError;

/// Side of a motion vector's cell, in pixels: the blocks'
/// ([`temporal::BLOCK`]), so that a cell is a block.
pub const CELL: usize = 16;
const _: () = assert!(CELL == temporal::BLOCK);

/// How the sender searches motion and chooses each block's mode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionSpec {
    /// Largest vector component searched (px).
    pub range: usize,
    /// The block modes.
    pub modes: ModeSpec,
}

impl Default for MotionSpec {
    /// ±16 px, and stereo prediction's modes: coded blocks 10 quality
    /// steps below the frame's (measured on the `pan` sequence against 0,
    /// 5 and 20: `docs/benchmarks.md`, "Sequences against x264").
    fn default() -> Self {
        MotionSpec {
            range: 16,
            modes: ModeSpec::default(),
        }
    }
}

/// The motion vectors and block modes of a view, and its prediction: what
/// the sender decides before coding the blocks, at any quality.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionPlan {
    plan: Plan,
    quality_drop: u8,
}

impl MotionPlan {
    /// The plan of `current` predicted from the reference view as the
    /// receiver decoded it (`rebuilt`), whose pixels were coded from
    /// `basis`. The blocks `still` flags (one flag a block, raster order:
    /// those that changed within sensor noise since `basis`,
    /// [`temporal::changed_blocks`]) are skipped with a zero vector, as
    /// conditional replenishment skips them.
    ///
    /// # Panics
    /// If the views differ in size, or `still` is not one flag a block.
    pub fn new(
        current: &RgbImage,
        (basis, rebuilt): (&RgbImage, &RgbImage),
        still: &[bool],
        spec: &MotionSpec,
    ) -> Self {
        assert_eq!(current.dims(), rebuilt.dims(), "views differ in size");
        let (cols, rows) = Shift::Motion.cells(current.dims());
        assert_eq!(still.len(), cols * rows, "one flag a block");
        let r = spec.range as i32;
        let vectors = search(current, rebuilt, Shift::Motion, |pred, found, i, cost| {
            if still[i] {
                return [0, 0];
            }
            let mut best = ([0, 0], cost([0, 0]));
            let consider = |best: &mut (Vector, u32), v: Vector| {
                let v = v.map(|c| c.clamp(-r, r));
                let c = cost(v);
                if c < best.1 {
                    *best = (v, c);
                }
            };
            consider(&mut best, pred);
            if i % cols > 0 {
                consider(&mut best, found[i - 1]);
            }
            if i >= cols {
                consider(&mut best, found[i - cols]);
            }
            for dy in (-r..=r).step_by(4) {
                for dx in (-r..=r).step_by(4) {
                    consider(&mut best, [dx, dy]);
                }
            }
            // A small diamond, while the cost falls (bounded: each step
            // lowers it).
            loop {
                let [x, y] = best.0;
                for v in [[x + 1, y], [x - 1, y], [x, y + 1], [x, y - 1]] {
                    consider(&mut best, v);
                }
                if best.0 == [x, y] {
                    return best.0;
                }
            }
        });
        let mut plan = Plan::new(
            current,
            (basis, rebuilt),
            Shift::Motion,
            vectors,
            &spec.modes,
        );
        for (mode, _) in plan.modes.iter_mut().zip(still).filter(|(_, &s)| s) {
            *mode = Mode::Skip;
        }
        MotionPlan {
            plan,
            quality_drop: spec.modes.quality_drop,
        }
    }

    /// What each pixel of the view will be rebuilt from, among originals:
    /// `current` in the coded blocks, else the reference's `basis` where
    /// its motion takes it. The next frame's skip test measures against it.
    pub fn basis(&self, current: &RgbImage, basis: &RgbImage) -> RgbImage {
        self.plan.basis(current, basis)
    }

    /// Each cell's vector, raster order.
    pub fn vectors(&self) -> &[Vector] {
        &self.plan.vectors
    }

    /// Each block's mode, raster order.
    pub fn modes(&self) -> &[Mode] {
        &self.plan.modes
    }
}

/// A view predicted by motion from the same view of a reference frame.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionView {
    reference: RefId,
    shifted: Shifted,
}

impl MotionView {
    /// Codes `current` by `plan`, predicted from the reference frame `id`
    /// the plan was made against; the coded blocks with `codec` at
    /// `quality` (less the plan's quality drop).
    pub fn encode(
        current: &RgbImage,
        (id, plan): (RefId, &MotionPlan),
        codec: LossyCodec,
        quality: u8,
    ) -> Result<Self, CodecError> {
        let q = quality.saturating_sub(plan.quality_drop);
        Ok(MotionView {
            reference: id,
            shifted: Shifted::encode(current, &plan.plan, codec, q)?,
        })
    }

    /// Decodes a payload (its reference named first) predicted from
    /// `reference`, the reference frame's same view.
    pub fn decode(payload: &[u8], reference: &RgbImage) -> Result<Self, CodecError> {
        let (id, rest) = temporal::split_reference(payload)?;
        Ok(MotionView {
            reference: id,
            shifted: Shifted::decode(rest, reference, Shift::Motion)?,
        })
    }

    /// The reference frame.
    pub fn reference(&self) -> RefId {
        self.reference
    }

    /// The view rebuilt.
    pub fn image(&self) -> &RgbImage {
        self.shifted.image()
    }

    /// Each cell's vector and each block's mode, raster order.
    pub fn blocks(&self) -> (&[Vector], &[Mode]) {
        (&self.shifted.vectors, &self.shifted.modes)
    }

    /// The view's payload in the container.
    pub fn payload(&self) -> Vec<u8> {
        let mut out = temporal::reference_bytes(self.reference);
        self.shifted.payload_into(&mut out);
        out
    }
}

/// The reference of a `width`×`height` view's payload if the view is the
/// reference's, unmoved (every block skipped, every vector zero): a still
/// view.
pub(crate) fn still_reference(payload: &[u8], dims: (usize, usize)) -> Option<RefId> {
    let (id, rest) = temporal::split_reference(payload).ok()?;
    crate::shift::unmoved(rest, dims, Shift::Motion).then_some(id)
}

/// Decodes motion-predicted views into buffers it keeps: after the first
/// view of a size it allocates nothing (the lossy decoders aside).
#[derive(Default)]
pub struct MotionDecoder {
    shift: ShiftDecoder,
}

impl MotionDecoder {
    /// Rebuilds the view of `payload` into `out` from `reference`, the
    /// reference frame's same view (which `payload` names first; the
    /// caller looks it up with [`ViewRef::reference`](crate::container::ViewRef::reference)).
    pub fn decode_into(
        &mut self,
        payload: &[u8],
        reference: &RgbImage,
        out: &mut RgbImage,
    ) -> Result<(), CodecError> {
        let (_, rest) = temporal::split_reference(payload)?;
        self.shift.decode_into(rest, reference, Shift::Motion, out)
    }
}

#[cfg(all(test, feature = "encode"))]
mod tests {
    use super::*;
    use crate::lossy;
    use proptest::prelude::*;
    use stereolink_image::synth::{synthesize, SynthSpec};

    /// A 128x96 window on a synthetic scene at `(x, y)`.
    fn window(x: usize, y: usize) -> RgbImage {
        let s = synthesize(&SynthSpec {
            width: 200,
            height: 140,
            max_disp: 8,
            seed: 3,
        })
        .unwrap();
        RgbImage::from_fn(128, 96, |i, j| s.left.get(x + i, y + j))
    }

    const ID: RefId = RefId {
        frame_id: 7,
        timestamp_us: 700,
    };

    /// The view at (5, 3) predicted from the one at (0, 0), as sent at
    /// quality 60.
    fn coded() -> (RgbImage, RgbImage, MotionView, MotionPlan) {
        let (first, next) = (window(0, 0), window(5, 3));
        let sent = lossy::encode(&first, LossyCodec::Webp, 60).unwrap();
        let still = vec![false; 8 * 6];
        let plan = MotionPlan::new(
            &next,
            (&first, sent.image()),
            &still,
            &MotionSpec::default(),
        );
        let v = MotionView::encode(&next, (ID, &plan), LossyCodec::Webp, 60).unwrap();
        (sent.image().clone(), next, v, plan)
    }

    #[test]
    fn the_payload_rebuilds_the_senders_view_bit_for_bit() {
        let (reference, _, v, _) = coded();
        let payload = v.payload();
        assert_eq!(MotionView::decode(&payload, &reference).unwrap(), v);
        let mut d = MotionDecoder::default();
        let mut out = RgbImage::default();
        d.decode_into(&payload, &reference, &mut out).unwrap();
        assert_eq!(&out, v.image());
    }

    #[test]
    fn the_vectors_follow_the_motion_and_the_blocks_are_mostly_predicted() {
        let (_, _, v, _) = coded();
        // The window moved 5 px right and 3 down: the content is found 5 px
        // right and 3 px down in the reference. Cells inside the view find
        // it (the edge ones may not: their content is new).
        let inside = v.blocks().0.iter().filter(|&&m| m == [5, 3]).count();
        assert!(
            inside * 10 > v.blocks().0.len() * 8,
            "{inside} of {}",
            v.blocks().0.len()
        );
        let skipped = v.blocks().1.iter().filter(|&&m| m == Mode::Skip).count();
        assert!(
            skipped * 2 > v.blocks().1.len(),
            "{skipped} of {}",
            v.blocks().1.len()
        );
    }

    #[test]
    fn a_moved_view_costs_far_less_than_coding_it_again() {
        let (_, next, v, _) = coded();
        let again = lossy::encode(&next, LossyCodec::Webp, 60).unwrap();
        assert!(
            v.payload().len() * 4 < again.bytes().len(),
            "{} B against {} B",
            v.payload().len(),
            again.bytes().len()
        );
    }

    #[test]
    fn the_basis_moves_with_the_prediction() {
        let (first, next) = (window(0, 0), window(5, 3));
        let (_, _, _, plan) = coded();
        let basis = plan.basis(&next, &first);
        // A skipped block's basis is the original its pixels come from:
        // the first view, moved; inside the view, that is the next view.
        let (w, h) = next.dims();
        let cols = temporal::blocks((w, h)).0;
        for (i, _) in plan
            .modes()
            .iter()
            .enumerate()
            .filter(|(_, &m)| m == Mode::Skip)
        {
            let (x, y) = ((i % cols) * 16 + 4, (i / cols) * 16 + 4);
            if x + 5 < w
                && y + 3 < h
                && plan.vectors()[(y / CELL) * (w / CELL) + x / CELL] == [5, 3]
            {
                assert_eq!(basis.get(x, y), next.get(x, y), "block {i}");
            }
        }
    }

    #[test]
    fn truncated_or_corrupt_payloads_are_errors() {
        let (reference, _, v, _) = coded();
        let payload = v.payload();
        let blocks_end = 16 + u32::from_le_bytes(payload[12..16].try_into().unwrap()) as usize;
        for cut in [0, 5, 12, 15, 16, blocks_end - 1, blocks_end] {
            assert!(
                MotionView::decode(&payload[..cut], &reference).is_err(),
                "cut to {cut} bytes"
            );
        }
        let mut long = payload.clone();
        long[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            MotionView::decode(&long, &reference),
            Err(CodecError::Truncated("motion view's blocks"))
        );
        let mut bad = payload.clone();
        bad[blocks_end] = 9;
        assert!(matches!(
            MotionView::decode(&bad, &reference),
            Err(CodecError::Invalid(m)) if m.contains("codec 9")
        ));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        #[test]
        fn any_bytes_decode_or_fail_cleanly(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let reference = RgbImage::new(40, 24, [90, 100, 110]);
            let mut d = MotionDecoder::default();
            let mut out = RgbImage::default();
            let _ = d.decode_into(&bytes, &reference, &mut out);
        }
    }
}
