//! The sender's side of temporal prediction: a stream of frames, each a key
//! frame or predicted from the last frame the receiver acknowledged
//! ([`stereolink_codec::temporal`]).
//!
//! The loop is closed. For each frame it sent, the [`StreamEncoder`] keeps
//! what the receiver rebuilds from it, bit for bit (the lossy decoders are
//! the board's), and the basis of each block (the original it was coded
//! from). A frame the link delivered is acknowledged
//! ([`StreamEncoder::acknowledge`]); the next frame is predicted from the
//! newest acknowledged one while it is among the last
//! [`REFERENCES`](stereolink_codec::temporal::REFERENCES) sent, which the
//! receiver, keeping as many, still holds. Anything else, a key frame:
//! at the start, when the caller wants one (on request, after a restart of
//! either end, every so often), and when nothing acknowledged is held.
//!
//! A predicted frame codes each view's changed blocks at the quality of the
//! last key frame (at most: a budget may lower it), so that the picture
//! keeps one quality; a view whose blocks mostly changed is coded whole,
//! as in a key frame. Only lossy views are predicted: segmented frames are
//! all key frames.

use std::collections::VecDeque;

use stereolink_codec::lossy::{self, LossyCodec, ViewCoding};
use stereolink_codec::temporal::{self, PredictedView, RefId, SkipSpec, REFERENCES};
use stereolink_codec::View;
use stereolink_image::{Calibration, RgbImage};

use crate::sender::{prepare_with, Predict, Prepared, SenderConfig};

/// What a frame of the stream is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    /// Coded on its own.
    Key,
    /// Predicted from frame `reference`.
    Predicted {
        /// The reference's frame id.
        reference: u32,
    },
}

impl FrameKind {
    /// `key` or `predicted`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Key => "key",
            Self::Predicted { .. } => "predicted",
        }
    }

    /// The reference of a predicted frame.
    pub fn reference(self) -> Option<u32> {
        match self {
            Self::Key => None,
            Self::Predicted { reference } => Some(reference),
        }
    }
}

/// A frame sent: its id, and per view what the receiver rebuilt and the
/// originals its blocks were coded from.
struct Sent {
    id: RefId,
    rebuilt: [RgbImage; 2],
    basis: [RgbImage; 2],
}

/// The sender's stream state: the frames sent that a predicted frame may
/// reference, and which the receiver acknowledged.
pub struct StreamEncoder {
    skip: SkipSpec,
    /// The last frames sent, oldest first (at most `REFERENCES`).
    sent: VecDeque<Sent>,
    acknowledged: Option<u32>,
    /// Quality of the last key frame (lossy).
    key_quality: Option<u8>,
    /// Time stamp of the last key frame (µs).
    last_key_us: Option<u64>,
}

impl StreamEncoder {
    /// A stream that skips blocks within `skip`; its first frame is a key
    /// frame.
    pub fn new(skip: SkipSpec) -> Self {
        StreamEncoder {
            skip,
            sent: VecDeque::new(),
            acknowledged: None,
            key_quality: None,
            last_key_us: None,
        }
    }

    /// The link delivered frame `frame_id`: the receiver holds it, and
    /// later frames may be predicted from it (a frame not among the last
    /// sent is ignored).
    pub fn acknowledge(&mut self, frame_id: u32) {
        let newer = |a: u32| self.position(frame_id) > self.position(a);
        if self.position(frame_id).is_some() && self.acknowledged.is_none_or(newer) {
            self.acknowledged = Some(frame_id);
        }
    }

    /// Forgets every frame sent: the next frame is a key frame (a new
    /// session, or the receiver restarted or asked for one).
    pub fn reset(&mut self) {
        self.sent.clear();
        self.acknowledged = None;
    }

    /// The time stamp of the last key frame sent, to send the next one
    /// after a period.
    pub fn last_key_us(&self) -> Option<u64> {
        self.last_key_us
    }

    /// The frame the next one would be predicted from, if any.
    pub fn reference(&self) -> Option<RefId> {
        let i = self.position(self.acknowledged?)?;
        Some(self.sent[i].id)
    }

    fn position(&self, frame_id: u32) -> Option<usize> {
        self.sent.iter().position(|s| s.id.frame_id == frame_id)
    }

    /// Prepares pair `frame_id` captured at `captured_us`
    /// ([`crate::sender::prepare`]): a key frame if `want_key`, if the
    /// views are segmented, or if no acknowledged frame is held; else
    /// predicted from the newest acknowledged frame.
    pub fn prepare(
        &mut self,
        (left, right): (&RgbImage, &RgbImage),
        calib: &Calibration,
        cfg: &SenderConfig,
        (frame_id, captured_us): (u32, u64),
        want_key: bool,
    ) -> anyhow::Result<(Prepared, FrameKind)> {
        let ids = (frame_id, captured_us);
        let ViewCoding::Lossy(codec) = cfg.coding.coding else {
            self.reset();
            let p = prepare_with(left, right, calib, cfg, ids, None)?;
            self.last_key_us = Some(captured_us);
            return Ok((p, FrameKind::Key));
        };
        let reference = self.reference().zip(self.key_quality).filter(|_| !want_key);
        let (prepared, kind, basis) = match reference {
            None => {
                let p = prepare_with(left, right, calib, cfg, ids, None)?;
                self.key_quality = Some(p.setting);
                self.last_key_us = Some(captured_us);
                (p, FrameKind::Key, [left.clone(), right.clone()])
            }
            Some((id, key_quality)) => {
                let i = self.position(id.frame_id).expect("the reference is held");
                let r = &self.sent[i];
                let changed = [(left, 0), (right, 1)]
                    .map(|(v, k)| temporal::changed_blocks(v, &r.basis[k], &self.skip));
                let mut views = |q| predicted_views((left, right), r, &changed, codec, q);
                let lowest = *codec.qualities().start();
                let predict = Predict {
                    qualities: lowest..=key_quality.max(lowest),
                    views: &mut views,
                };
                let p = prepare_with(left, right, calib, cfg, ids, Some(predict))?;
                // Each view's basis: the original where it was coded.
                let r = &self.sent[i];
                let basis = [(left, 0), (right, 1)].map(|(v, k)| {
                    let mut b = r.basis[k].clone();
                    let all = vec![true; changed[k].len()];
                    let coded = if coded_whole(&changed[k]) {
                        &all
                    } else {
                        &changed[k]
                    };
                    temporal::paste_blocks(&mut b, v, coded);
                    b
                });
                let kind = FrameKind::Predicted {
                    reference: id.frame_id,
                };
                (p, kind, basis)
            }
        };
        if self.sent.len() == REFERENCES {
            self.sent.pop_front();
        }
        self.sent.push_back(Sent {
            id: RefId {
                frame_id,
                timestamp_us: captured_us,
            },
            rebuilt: [prepared.sent.0.clone(), prepared.sent.1.clone()],
            basis,
        });
        Ok((prepared, kind))
    }
}

/// Whether a view whose blocks `changed` is coded whole: when most of its
/// blocks changed.
fn coded_whole(changed: &[bool]) -> bool {
    2 * changed.iter().filter(|&&c| c).count() > changed.len()
}

/// Both views predicted from `reference` at quality `q`; a view whose
/// blocks mostly changed is coded whole.
fn predicted_views(
    (left, right): (&RgbImage, &RgbImage),
    reference: &Sent,
    changed: &[Vec<bool>; 2],
    codec: LossyCodec,
    q: u8,
) -> anyhow::Result<(View, View)> {
    let view = |current: &RgbImage, k: usize| -> anyhow::Result<View> {
        if coded_whole(&changed[k]) {
            return Ok(View::Lossy(lossy::encode(current, codec, q)?));
        }
        let from = (reference.id, &reference.rebuilt[k]);
        Ok(View::Predicted(PredictedView::encode(
            current,
            from,
            changed[k].clone(),
            codec,
            q,
        )?))
    };
    let (l, r) = rayon::join(|| view(left, 0), || view(right, 1));
    Ok((l?, r?))
}
