//! How the sender codes a pair's views, and how it fits the frame in a byte
//! budget: the rate control of `encode --bytes` and `send --bytes`.
//!
//! A coding has one integer setting that trades bytes for fidelity: a lossy
//! codec's quality (both views at the same quality, so that neither view
//! is sacrificed for the other), or the segmentation's levels (the frame
//! grows with the classes, and so does the pair's PSNR). Given a budget, the
//! largest setting whose whole frame fits is found by bisection
//! ([`stereolink_codec::rate::fit`]); without one, the setting asked for is
//! used as is.

use std::ops::RangeInclusive;

use stereolink_codec::lossy::{self, LossyCodec, ViewCoding};
use stereolink_codec::rate;
use stereolink_codec::stereo::{StereoSpec, StereoView};
use stereolink_codec::{container, labels, Message, SegmentationKind, StereoFrame, View};
use stereolink_image::{Calibration, RgbImage};

/// How the sender codes each pair's views.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CodingSpec {
    /// Segmented (the paper's mode) or lossy views.
    pub coding: ViewCoding,
    /// A lossy coding's quality when there is no budget (0-100; JPEG's
    /// lowest is 1).
    pub quality: u8,
    /// The most bytes a frame (the whole message) may take.
    pub budget: Option<usize>,
    /// A lossy right view is predicted from the left one
    /// ([`stereolink_codec::stereo`]) rather than coded on its own.
    pub stereo_prediction: bool,
}

impl Default for CodingSpec {
    /// Segmented views, no budget; lossy views at quality 75 (the JPEG
    /// convention's usual default), the right one stereo-predicted.
    fn default() -> Self {
        CodingSpec {
            coding: ViewCoding::Segmented,
            quality: 75,
            budget: None,
            stereo_prediction: true,
        }
    }
}

impl CodingSpec {
    /// The settings a frame is fitted over: the lossy quality range, or
    /// segmentations of 2 up to `levels` classes, with a budget; the one
    /// setting asked for without.
    pub fn settings(&self, levels: usize) -> RangeInclusive<u8> {
        let top = match self.coding {
            ViewCoding::Segmented => levels.min(255) as u8,
            ViewCoding::Lossy(_) => self.quality,
        };
        match (self.budget, self.coding) {
            (None, _) => top..=top,
            (Some(_), ViewCoding::Segmented) => top.min(2)..=top,
            (Some(_), ViewCoding::Lossy(codec)) => codec.qualities(),
        }
    }
}

/// A frame as sent: its bytes, the frame, and the setting it was made at.
#[derive(Debug)]
pub struct Coded {
    /// The encoded StereoFrame message.
    pub bytes: Vec<u8>,
    /// The frame encoded.
    pub frame: StereoFrame,
    /// The coding's setting (quality or levels).
    pub setting: u8,
}

/// Both views coded lossily with `codec` at `quality`: with
/// `stereo_prediction`, the right view predicted from the left as decoded
/// ([`StereoView`]); else each on its own, in parallel.
pub fn lossy_views(
    (left, right): (&RgbImage, &RgbImage),
    codec: LossyCodec,
    quality: u8,
    stereo_prediction: bool,
) -> anyhow::Result<(View, View)> {
    if stereo_prediction {
        let l = lossy::encode(left, codec, quality)?;
        let spec = StereoSpec::default();
        let r = StereoView::encode(right, (left, l.image()), codec, quality, &spec)?;
        return Ok((View::Lossy(l), View::Stereo(r)));
    }
    let (l, r) = rayon::join(
        || lossy::encode(left, codec, quality),
        || lossy::encode(right, codec, quality),
    );
    Ok((View::Lossy(l?), View::Lossy(r?)))
}

/// A frame of two lossy views (no segmentation), its parameters naming the
/// codec and the quality, as the sender, `encode` and the report build it.
pub fn lossy_frame(
    codec: LossyCodec,
    quality: u8,
    (left, right): (View, View),
    calibration: Option<Calibration>,
) -> StereoFrame {
    StereoFrame {
        kind: SegmentationKind::None,
        levels: 0,
        params: format!("{} q={quality}", codec.name()),
        thresholds: None,
        calibration,
        left,
        right,
        planes: None,
    }
}

/// The frame `make` builds at a setting, encoded (as `frame_id` at
/// `timestamp_us`, label maps in `mode`): with a `budget`, at the largest
/// setting in `settings` whose message fits it (an error naming the
/// smallest frame when none does); without, at the end of `settings`.
pub fn encode_fitted(
    settings: RangeInclusive<u8>,
    budget: Option<usize>,
    (frame_id, timestamp_us, mode): (u32, u64, labels::Mode),
    mut make: impl FnMut(u8) -> anyhow::Result<StereoFrame>,
) -> anyhow::Result<Coded> {
    let mut encode = |setting: u8| {
        let frame = make(setting)?;
        let msg = Message::StereoFrame(Box::new(frame));
        let bytes = container::encode_with(&msg, frame_id, timestamp_us, mode);
        let Message::StereoFrame(frame) = msg else {
            unreachable!("built as a frame")
        };
        anyhow::Ok((bytes, *frame))
    };
    let (setting, bytes, frame) = match budget {
        Some(budget) => {
            let f = rate::fit(settings, budget, &mut encode)?;
            (f.setting, f.bytes, f.extra)
        }
        None => {
            let setting = *settings.end();
            let (bytes, frame) = encode(setting)?;
            (setting, bytes, frame)
        }
    };
    Ok(Coded {
        bytes,
        frame,
        setting,
    })
}

#[cfg(all(test, not(target_arch = "arm")))]
mod tests {
    use super::*;
    use stereolink_codec::{CodecError, SegmentationKind};
    use stereolink_image::metrics::psnr_pair;
    use stereolink_image::synth::{synthesize, SynthSpec};

    fn frame(left: View, right: View) -> StereoFrame {
        StereoFrame {
            kind: SegmentationKind::None,
            levels: 0,
            params: String::new(),
            thresholds: None,
            calibration: None,
            left,
            right,
            planes: None,
        }
    }

    #[test]
    fn a_budget_is_met_with_the_highest_quality_that_fits() {
        let s = synthesize(&SynthSpec {
            width: 160,
            height: 120,
            max_disp: 16,
            seed: 2,
        })
        .unwrap();
        let pair = (&s.left, &s.right);
        let make = |q| lossy_views(pair, LossyCodec::Jpeg, q, false).map(|(l, r)| frame(l, r));
        let ids = (1, 0, labels::Mode::Fast);
        let mut last = (0, 0.0);
        for budget in [3_000, 6_000, 12_000] {
            let c = encode_fitted(LossyCodec::Jpeg.qualities(), Some(budget), ids, make).unwrap();
            assert!(c.bytes.len() <= budget, "{} B over {budget}", c.bytes.len());
            // One quality step more no longer fits (or is the top).
            let next = encode_fitted(c.setting + 1..=c.setting + 1, None, ids, make);
            assert!(c.setting == 100 || next.unwrap().bytes.len() > budget);
            let psnr = psnr_pair(pair, (&c.frame.left.to_rgb(), &c.frame.right.to_rgb())).unwrap();
            assert!(
                c.setting > last.0 && psnr > last.1,
                "{budget}: q{} {psnr} dB",
                c.setting
            );
            last = (c.setting, psnr);
        }
        let smallest = encode_fitted(1..=1, None, ids, make).unwrap().bytes.len();
        let e =
            encode_fitted(LossyCodec::Jpeg.qualities(), Some(smallest - 1), ids, make).unwrap_err();
        assert_eq!(
            e.downcast_ref::<CodecError>(),
            Some(&CodecError::BudgetTooSmall {
                budget: smallest - 1,
                minimum: smallest
            })
        );
    }
}
