//! Stereo prediction: the right view coded as the left view, as the
//! receiver decoded it, shifted by the sender's disparity, with what the
//! shift misses coded per block.
//!
//! Each [`CELL`]×[`CELL`] cell of the right view carries an integer
//! disparity `d`: its prediction is the decoded left view `d` px to the
//! right (rectified views: right(x, y) = left(x + d, y), clamped at the
//! edge). Each block then has a [`Mode`] (skipped, residual or intra), and
//! the coded blocks go in one mosaic coded by the left view's lossy codec a
//! few quality steps coarser: the coding by shifted cells of
//! [`crate::shift`], which temporal prediction by motion
//! ([`crate::motion`]) shares, with one vector component (`dy` = 0).
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
//!   prediction comes from ([`ModeSpec`]), so it follows the quality rate
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

use crate::lossy::LossyCodec;
use crate::shift::{search, Plan, Shift, ShiftDecoder, Shifted};
pub use crate::shift::{Mode, ModeSpec};
use crate::CodecError;

/// How the sender searches disparities and chooses each block's mode
/// ([`ModeSpec`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StereoSpec {
    /// Largest disparity searched (px); `None`: a quarter of the width.
    pub max_disp: Option<usize>,
    /// The block modes.
    pub modes: ModeSpec,
}

/// Side of a disparity's cell, in pixels: each cell of the right view has
/// one disparity. The modes stay per [`BLOCK`](crate::temporal::BLOCK)
/// (the codecs' macroblock).
pub const CELL: usize = 8;

/// The disparity cells of a `width`×`height` view: `(columns, rows)`.
pub fn cells(dims: (usize, usize)) -> (usize, usize) {
    Shift::Disparity.cells(dims)
}

/// A right view predicted from the left: the cells' disparities, the
/// blocks' modes, the coded blocks' mosaic, and the view it rebuilds.
#[derive(Clone, Debug, PartialEq)]
pub struct StereoView {
    disparities: Vec<u16>,
    shifted: Shifted,
}

impl StereoView {
    /// Codes `right` predicted from the left view as the receiver decoded
    /// it (`left_sent`; `left` is its original, which tells the left view's
    /// coding error), the coded blocks with `codec` at `quality` less
    /// `spec.modes.quality_drop`.
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
        assert_eq!(left.dims(), left_sent.dims(), "views differ in size");
        let w = right.width();
        let max_disp = spec.max_disp.unwrap_or(w / 4).min(w.saturating_sub(1));
        // Every disparity in 0..=max_disp, the first of the least cost.
        let vectors = search(right, left_sent, Shift::Disparity, |_, _, _, cost| {
            (0..=max_disp as i32)
                .map(|d| [d, 0])
                .min_by_key(|&v| cost(v))
                .expect("0 is searched")
        });
        let plan = Plan::new(
            right,
            (left, left_sent),
            Shift::Disparity,
            vectors,
            &spec.modes,
        );
        let q = quality.saturating_sub(spec.modes.quality_drop);
        Ok(Self::of(Shifted::encode(right, &plan, codec, q)?))
    }

    /// Decodes a payload predicted from `left` (the frame's decoded left
    /// view).
    pub fn decode(payload: &[u8], left: &RgbImage) -> Result<Self, CodecError> {
        Ok(Self::of(Shifted::decode(payload, left, Shift::Disparity)?))
    }

    fn of(shifted: Shifted) -> Self {
        let disparities = shifted.vectors.iter().map(|v| v[0] as u16).collect();
        StereoView {
            disparities,
            shifted,
        }
    }

    /// Each cell's disparity (px), raster order ([`cells`]).
    pub fn disparities(&self) -> &[u16] {
        &self.disparities
    }

    /// Each block's mode, raster order.
    pub fn modes(&self) -> &[Mode] {
        &self.shifted.modes
    }

    /// The codec of the coded blocks, if any is coded.
    pub fn codec(&self) -> Option<LossyCodec> {
        self.shifted.codec()
    }

    /// The right view rebuilt.
    pub fn image(&self) -> &RgbImage {
        self.shifted.image()
    }

    /// The view's payload in the container.
    pub fn payload(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.shifted.payload_into(&mut out);
        out
    }
}

/// Decodes stereo-predicted right views into buffers it keeps: after the
/// first view of a size it allocates nothing (the lossy decoders aside,
/// as for any lossy view).
#[derive(Default)]
pub struct StereoDecoder {
    shift: ShiftDecoder,
    disparities: Vec<u16>,
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
        self.disparities.clear();
        self.shift
            .decode_into(payload, left, Shift::Disparity, out)?;
        // Checked in 0..=width (a u16) by the decoder.
        let vectors = self.shift.vectors.iter();
        self.disparities.extend(vectors.map(|v| v[0] as u16));
        Ok(())
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

#[cfg(all(test, feature = "encode"))]
mod tests {
    use super::*;
    use crate::lossy;
    use crate::shift::{read_blocks, write_blocks};
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
        fn blocks_data_round_trips(ds in proptest::collection::vec(0i32..=40, 6), ms in proptest::collection::vec(0u8..3, 6)) {
            let modes = [Mode::Skip, Mode::Residual, Mode::Intra];
            let cs: Vec<Mode> = ms.iter().map(|&m| modes[usize::from(m)]).collect();
            // 48x32 px: 3x2 blocks, 6x4 cells.
            let ds: Vec<[i32; 2]> = ds.iter().cycle().take(24).map(|&d| [d, 0]).collect();
            let bits = write_blocks(&ds, &cs, (48, 32), Shift::Disparity);
            let (mut d, mut c) = (Vec::new(), Vec::new());
            read_blocks(&bits, (48, 32), Shift::Disparity, &mut d, &mut c).unwrap();
            prop_assert_eq!(d, ds);
            prop_assert_eq!(c, cs);
        }
    }
}
