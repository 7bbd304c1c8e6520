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
//! A predicted frame's lossy views are predicted by motion
//! ([`stereolink_codec::motion`]): the blocks that changed within sensor
//! noise since their basis ([`SkipSpec`]) are skipped, as conditional
//! replenishment skips them; the others follow their motion vector in the
//! reference, and only what the motion misses is coded, at the quality of
//! the last key frame (at most: a budget may lower it), so that the picture
//! keeps one quality. A still rig's views cost a few bytes; a moving rig's
//! cost what comes into view.
//!
//! A predicted segmented frame codes each label map from
//! the reference's, its segments first made to keep the reference's labels
//! where the colours allow (the noise would otherwise move their edges).

use std::collections::{BTreeMap, VecDeque};

use stereolink_codec::lossy::{LossyCodec, ViewCoding};
use stereolink_codec::motion::{MotionPlan, MotionSpec, MotionView};
use stereolink_codec::temporal::{self, PredictedLabels, RefId, SkipSpec, REFERENCES};
use stereolink_codec::{container, labels, View};
use stereolink_image::{Calibration, IndexedImage, RgbImage};
use stereolink_segment::carry::{carry_over, default_margin};
use stereolink_segment::Segmentation;

use crate::sender::{prepare_with, Predict, Prepared, SegmentedPair, SenderConfig};

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
    kept: Kept,
}

/// What a frame sent left the receiver with, per view.
enum Kept {
    /// Lossy views: the pixels rebuilt, and the originals each block was
    /// coded from.
    Pixels {
        rebuilt: [RgbImage; 2],
        basis: [RgbImage; 2],
    },
    /// Segmented views: the label maps and palettes.
    Labels([IndexedImage; 2]),
}

impl Kept {
    fn dims(&self) -> (usize, usize) {
        match self {
            Kept::Pixels { rebuilt, .. } => rebuilt[0].dims(),
            Kept::Labels(views) => views[0].labels().dims(),
        }
    }
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
    /// ([`crate::sender::prepare`]): a key frame if `want_key` or if no
    /// acknowledged frame of the same coding and size is held; else
    /// predicted from the newest acknowledged frame.
    pub fn prepare(
        &mut self,
        (left, right): (&RgbImage, &RgbImage),
        calib: &Calibration,
        cfg: &SenderConfig,
        ids: (u32, u64),
        want_key: bool,
    ) -> anyhow::Result<(Prepared, FrameKind)> {
        let reference = self
            .reference()
            .filter(|_| !want_key)
            .map(|id| {
                (
                    id,
                    &self.sent[self.position(id.frame_id).expect("held")].kept,
                )
            })
            .filter(|(_, kept)| kept.dims() == left.dims());
        let (prepared, kept) = match cfg.coding.coding {
            ViewCoding::Segmented => {
                let reference = reference.and_then(|(id, kept)| match kept {
                    Kept::Labels(views) => Some((id, views)),
                    Kept::Pixels { .. } => None,
                });
                segmented((left, right), calib, cfg, ids, reference)?
            }
            ViewCoding::Lossy(codec) => {
                let reference =
                    reference
                        .zip(self.key_quality)
                        .and_then(|((id, kept), q)| match kept {
                            Kept::Pixels { rebuilt, basis } => Some((id, rebuilt, basis, q)),
                            Kept::Labels(_) => None,
                        });
                let skip = &self.skip;
                lossy((left, right), calib, cfg, ids, (codec, skip), reference)?
            }
        };
        let kind = match prepared.1 {
            Some(id) => FrameKind::Predicted {
                reference: id.frame_id,
            },
            None => {
                self.last_key_us = Some(ids.1);
                if let ViewCoding::Lossy(_) = cfg.coding.coding {
                    self.key_quality = Some(prepared.0.setting);
                }
                FrameKind::Key
            }
        };
        if self.sent.len() == REFERENCES {
            self.sent.pop_front();
        }
        self.sent.push_back(Sent {
            id: RefId {
                frame_id: ids.0,
                timestamp_us: ids.1,
            },
            kept,
        });
        Ok((prepared.0, kind))
    }
}

/// A prepared frame and the reference it was predicted from (none: a key
/// frame).
type Made = (Prepared, Option<RefId>);

/// A lossy frame: key, or predicted from `reference` (its id, the
/// receiver's views, their basis, and the key frame's quality).
fn lossy(
    (left, right): (&RgbImage, &RgbImage),
    calib: &Calibration,
    cfg: &SenderConfig,
    ids: (u32, u64),
    (codec, skip): (LossyCodec, &SkipSpec),
    reference: Option<(RefId, &[RgbImage; 2], &[RgbImage; 2], u8)>,
) -> anyhow::Result<(Made, Kept)> {
    let Some((id, rebuilt, basis, key_quality)) = reference else {
        let p = prepare_with(left, right, calib, cfg, ids, None)?;
        let rebuilt = [p.sent.0.clone(), p.sent.1.clone()];
        let basis = [left.clone(), right.clone()];
        return Ok(((p, None), Kept::Pixels { rebuilt, basis }));
    };
    // Each view's plan: the blocks within sensor noise of their basis
    // skipped, the others following their motion; in a view whose blocks
    // mostly changed (the rig moves), every block follows its motion (a
    // zero vector amid the rig's motion would cost more than it saves). It
    // does not depend on the quality.
    let plan = |v: &RgbImage, k: usize| {
        let changed = temporal::changed_blocks(v, &basis[k], skip);
        let moving = 2 * changed.iter().filter(|&&c| c).count() > changed.len();
        let still: Vec<bool> = changed.into_iter().map(|c| !c && !moving).collect();
        MotionPlan::new(v, (&basis[k], &rebuilt[k]), &still, &MotionSpec::default())
    };
    let plans = {
        let (l, r) = rayon::join(|| plan(left, 0), || plan(right, 1));
        [l, r]
    };
    let mut views = |q| {
        let view = |v: &RgbImage, k: usize| MotionView::encode(v, (id, &plans[k]), codec, q);
        let (l, r) = rayon::join(|| view(left, 0), || view(right, 1));
        Ok((View::Motion(l?), View::Motion(r?)))
    };
    let lowest = *codec.qualities().start();
    let predict = Predict::Lossy {
        qualities: lowest..=key_quality.max(lowest),
        views: &mut views,
    };
    let p = prepare_with(left, right, calib, cfg, ids, Some(predict))?;
    // Each view's basis: the original where it was coded, else the
    // reference's basis where the prediction takes it.
    let basis = [(left, 0), (right, 1)].map(|(v, k)| plans[k].basis(v, &basis[k]));
    let rebuilt = [p.sent.0.clone(), p.sent.1.clone()];
    Ok(((p, Some(id)), Kept::Pixels { rebuilt, basis }))
}

/// A segmented frame: key, or predicted from `reference` (its id and its
/// views). A predicted frame's segmentations take the reference's labels
/// (in their own numbering) wherever their colours allow, within the
/// stereo carry's margin ([`carry_over`]), so that noise does not move
/// the segments' edges from frame to frame.
fn segmented(
    (left, right): (&RgbImage, &RgbImage),
    calib: &Calibration,
    cfg: &SenderConfig,
    ids: (u32, u64),
    reference: Option<(RefId, &[IndexedImage; 2])>,
) -> anyhow::Result<(Made, Kept)> {
    let margin = cfg
        .carry_margin
        .unwrap_or_else(|| default_margin(&cfg.method));
    let mut sent = BTreeMap::new();
    let mut carry = |(sl, sr): SegmentedPair| match reference {
        None => (sl, sr),
        Some((_, views)) => {
            let carried = |view: &RgbImage, seg: Segmentation, k: usize| {
                let from = container::right_prediction(&views[k], &seg.image);
                carry_over(view, &seg, &from, margin)
            };
            (carried(left, sl, 0), carried(right, sr, 1))
        }
    };
    let mut views = |levels: u8, l: IndexedImage, r: IndexedImage| {
        sent.insert(levels, [l.clone(), r.clone()]);
        match reference {
            None => (View::Indexed(l), View::Indexed(r)),
            Some((id, views)) => {
                let view = |v: IndexedImage, k: usize| {
                    let from = (id, &views[k]);
                    View::PredictedLabels(PredictedLabels::encode(v, from, labels::Mode::default()))
                };
                (view(l, 0), view(r, 1))
            }
        }
    };
    let predict = Predict::Labels {
        carry: &mut carry,
        views: &mut views,
    };
    let p = prepare_with(left, right, calib, cfg, ids, Some(predict))?;
    let kept = sent
        .remove(&p.setting)
        .expect("the views of the setting chosen");
    Ok(((p, reference.map(|(id, _)| id)), Kept::Labels(kept)))
}

#[cfg(all(test, not(target_arch = "arm")))]
mod tests {
    use super::*;
    use crate::coding::CodingSpec;
    use crate::receiver::{BoardReceiver, Event};
    use stereolink_image::metrics::psnr_pair;
    use stereolink_image::synth::{synthesize, SynthSpec};
    use stereolink_segment::Method;
    use stereolink_stereo::depth::LevelSpec;
    use stereolink_stereo::{Algorithm, MatchSpec};

    fn config(budget: Option<usize>) -> SenderConfig {
        SenderConfig {
            method: Method::KMeans,
            levels: 3,
            seed: 1,
            carry_margin: None,
            matcher: MatchSpec::new(Algorithm::Wta, 0, 16).unwrap(),
            roi: None,
            levels_spec: LevelSpec::default(),
            plane_table: Default::default(),
            coding: CodingSpec {
                coding: ViewCoding::Lossy(LossyCodec::Webp),
                quality: 60,
                budget,
                stereo_prediction: true,
            },
        }
    }

    /// `view` with sensor noise (about σ = 2 grey levels: the sum of four
    /// uniform draws), seeded.
    fn noisy(view: &RgbImage, seed: u32) -> RgbImage {
        let mut s = seed.wrapping_mul(2_654_435_761) | 1;
        let mut draw = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            (s % 5) as i32 - 2
        };
        let mut out = view.clone();
        for p in out.as_mut_slice() {
            for c in p.iter_mut() {
                let n = (0..4).map(|_| draw()).sum::<i32>() / 2;
                *c = (i32::from(*c) + n).clamp(0, 255) as u8;
            }
        }
        out
    }

    /// A fixed rig filmed 8 times with sensor noise, a square moving
    /// through the last 3 pairs.
    fn sequence() -> Vec<(RgbImage, RgbImage)> {
        let s = synthesize(&SynthSpec {
            width: 160,
            height: 120,
            max_disp: 16,
            seed: 6,
        })
        .unwrap();
        (0..8u32)
            .map(|i| {
                let (mut l, mut r) = (noisy(&s.left, 2 * i + 1), noisy(&s.right, 2 * i + 2));
                if i >= 5 {
                    let x0 = 20 + 12 * i as usize;
                    for y in 40..70 {
                        for x in x0..x0 + 30 {
                            l.set(x, y, [250, 30, 30]);
                            r.set(x - 8, y, [250, 30, 30]);
                        }
                    }
                }
                (l, r)
            })
            .collect()
    }

    fn calib() -> Calibration {
        Calibration {
            focal_px: None,
            baseline_m: None,
            doffs: 0.0,
            ndisp: 16,
        }
    }

    /// Sends `pairs` through a stream (frame ids from 1, each acknowledged)
    /// to a board, which must show each frame as the sender rebuilt it, bit
    /// for bit; each frame's kind and what the sender prepared.
    fn closed_loop(
        pairs: &[(RgbImage, RgbImage)],
        cfg: &SenderConfig,
    ) -> Vec<(FrameKind, Prepared)> {
        let mut stream = StreamEncoder::new(SkipSpec::default());
        let mut board = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        let mut sent = Vec::new();
        for (i, (l, r)) in pairs.iter().enumerate() {
            let id = i as u32 + 1;
            let (p, kind) = stream
                .prepare((l, r), &calib(), cfg, (id, 1_000 * u64::from(id)), false)
                .unwrap();
            let event = board.handle(&p.frame_bytes);
            assert!(matches!(event, Event::Frame { .. }), "{id}: {event:?}");
            assert_eq!(board.pair().unwrap(), (&p.sent.0, &p.sent.1), "frame {id}");
            stream.acknowledge(id);
            sent.push((kind, p));
        }
        sent
    }

    /// The board rebuilds every frame, key or predicted, bit for bit as
    /// the sender's reconstruction; on a still noisy rig a predicted pair
    /// costs far less than a key pair at about its PSNR, and a moving
    /// square is coded (the picture follows it).
    #[test]
    fn the_board_rebuilds_the_senders_reconstruction_bit_for_bit() {
        let pairs = sequence();
        let seen: Vec<_> = closed_loop(&pairs, &config(Some(4_000)))
            .into_iter()
            .zip(&pairs)
            .map(|((kind, p), (l, r))| {
                let psnr = psnr_pair((l, r), (&p.sent.0, &p.sent.1)).unwrap();
                (kind, p.frame_bytes.len(), psnr)
            })
            .collect();
        assert_eq!(seen[0].0, FrameKind::Key);
        let (key_bytes, key_psnr) = (seen[0].1, seen[0].2);
        for (i, &(kind, bytes, psnr)) in seen.iter().enumerate().skip(1) {
            assert_eq!(
                kind,
                FrameKind::Predicted {
                    reference: i as u32
                },
                "{i}"
            );
            assert!(
                psnr > key_psnr - 0.5,
                "frame {}: {psnr} against {key_psnr} dB",
                i + 1
            );
            if i < 5 {
                assert!(
                    bytes * 8 < key_bytes,
                    "still frame {}: {bytes} B against {key_bytes}",
                    i + 1
                );
            } else {
                // The square's blocks are coded, and only they.
                assert!(
                    bytes * 8 > key_bytes / 2 && bytes < key_bytes,
                    "moving frame {}: {bytes} B",
                    i + 1
                );
            }
        }
    }

    /// A rig panning over a scene: 8 pairs of a 160x120 window sliding
    /// 2 px right and 1 px down a pair, with sensor noise.
    fn panning() -> Vec<(RgbImage, RgbImage)> {
        let s = synthesize(&SynthSpec {
            width: 200,
            height: 140,
            max_disp: 16,
            seed: 8,
        })
        .unwrap();
        let window =
            |v: &RgbImage, i: usize| RgbImage::from_fn(160, 120, |x, y| v.get(x + 2 * i, y + i));
        (0..8u32)
            .map(|i| {
                let (l, r) = (window(&s.left, i as usize), window(&s.right, i as usize));
                (noisy(&l, 2 * i + 1), noisy(&r, 2 * i + 2))
            })
            .collect()
    }

    /// On a panning rig, every predicted view follows the motion: the
    /// board rebuilds each frame bit for bit as the sender's
    /// reconstruction, and a predicted pair costs under half the key pair
    /// (which re-coding every pair would cost), a quarter on average, at
    /// about its PSNR.
    #[test]
    fn a_panning_rig_is_predicted_by_motion_bit_for_bit() {
        let pairs = panning();
        let mut seen = Vec::new();
        for ((kind, p), (l, r)) in closed_loop(&pairs, &config(Some(6_000))).iter().zip(&pairs) {
            let psnr = psnr_pair((l, r), (&p.sent.0, &p.sent.1)).unwrap();
            let Ok((_, container::Body::StereoFrame(f))) =
                container::parse(&p.frame_bytes, &Default::default())
            else {
                panic!("not a frame")
            };
            let motion = [f.left.is_motion(), f.right.is_motion()];
            seen.push((*kind, motion, p.frame_bytes.len(), psnr));
        }
        let (key_bytes, key_psnr) = (seen[0].2, seen[0].3);
        assert_eq!(seen[0].0, FrameKind::Key);
        for (i, &(kind, motion, bytes, psnr)) in seen.iter().enumerate().skip(1) {
            assert_eq!(kind.name(), "predicted", "{i}");
            assert_eq!(motion, [true; 2], "frame {}", i + 1);
            assert!(
                bytes * 2 < key_bytes,
                "frame {}: {bytes} B against {key_bytes}",
                i + 1
            );
            assert!(
                psnr > key_psnr - 1.0,
                "frame {}: {psnr} against {key_psnr} dB",
                i + 1
            );
        }
        // The content coming into the view is coded: on average a quarter
        // of the key pair.
        let predicted: usize = seen[1..].iter().map(|s| s.2).sum();
        assert!(
            predicted * 4 < key_bytes * (seen.len() - 1),
            "{predicted} B in {} predicted pairs against {key_bytes} B",
            seen.len() - 1
        );
    }

    /// A still pair predicted from the pair on the screen is not matched
    /// again (it is that pair); one predicted from another pair is.
    #[test]
    fn a_still_pair_keeps_the_disparity_of_the_pair_it_repeats() {
        let pairs = sequence();
        let cfg = config(None);
        let mut stream = StreamEncoder::new(SkipSpec::default());
        let frame = |stream: &mut StreamEncoder, i: usize, id: u32| {
            let (l, r) = &pairs[i];
            let (p, _) = stream
                .prepare((l, r), &calib(), &cfg, (id, u64::from(id)), false)
                .unwrap();
            p.frame_bytes
        };
        let key = frame(&mut stream, 0, 1);
        stream.acknowledge(1);
        // Frame 2 (the square in) is not acknowledged: frame 3, the still
        // pair, is predicted from frame 1.
        let moving = frame(&mut stream, 5, 2);
        let still = frame(&mut stream, 1, 3);
        let board = || BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        let shown = |b: &mut BoardReceiver, bytes: &[u8]| {
            assert!(matches!(b.handle(bytes), Event::Frame { .. }));
        };
        let mut only_key = board();
        shown(&mut only_key, &key);
        let (mut repeated, mut after_moving) = (board(), board());
        shown(&mut repeated, &key);
        shown(&mut repeated, &still);
        for bytes in [&key, &moving, &still] {
            shown(&mut after_moving, bytes);
        }
        let mut moving_only = board();
        shown(&mut moving_only, &key);
        shown(&mut moving_only, &moving);
        assert_ne!(
            moving_only.disparity(),
            only_key.disparity(),
            "the square moves the map"
        );
        for b in [&repeated, &after_moving] {
            assert_eq!(b.disparity(), only_key.disparity());
        }
        assert_eq!(repeated.pair(), only_key.pair());
        assert_eq!(after_moving.pair(), only_key.pair());
    }

    /// Segmented frames too: the board rebuilds each predicted label map
    /// as sent, a predicted pair costs under a quarter of the key pair at
    /// about its PSNR, and without the reference it is refused.
    #[test]
    fn segmented_frames_are_predicted_from_the_reference_labels() {
        let pairs = &sequence()[..5];
        let cfg = SenderConfig {
            coding: CodingSpec::default(),
            ..config(None)
        };
        let mut stream = StreamEncoder::new(SkipSpec::default());
        let mut board = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        let mut seen = Vec::new();
        for (i, (l, r)) in pairs.iter().enumerate() {
            let id = i as u32 + 1;
            let (p, kind) = stream
                .prepare((l, r), &calib(), &cfg, (id, u64::from(id)), false)
                .unwrap();
            let event = board.handle(&p.frame_bytes);
            assert!(matches!(event, Event::Frame { .. }), "{id}: {event:?}");
            assert_eq!(board.pair().unwrap(), (&p.sent.0, &p.sent.1), "frame {id}");
            stream.acknowledge(id);
            let psnr = psnr_pair((l, r), (&p.sent.0, &p.sent.1)).unwrap();
            seen.push((kind, p.frame_bytes.len(), psnr, p.frame_bytes));
        }
        let (key_bytes, key_psnr) = (seen[0].1, seen[0].2);
        assert_eq!(seen[0].0, FrameKind::Key);
        for (i, (kind, bytes, psnr, _)) in seen.iter().enumerate().skip(1) {
            assert_eq!(kind.name(), "predicted");
            assert!(
                bytes * 4 < key_bytes,
                "frame {}: {bytes} B against {key_bytes}",
                i + 1
            );
            assert!(
                *psnr > key_psnr - 0.5,
                "frame {}: {psnr} against {key_psnr} dB",
                i + 1
            );
        }
        let mut fresh = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        let e = fresh.handle(&seen[2].3);
        assert!(
            matches!(&e, Event::Rejected(why) if why.contains("reference frame 2")),
            "{e:?}"
        );
    }

    /// A receiver that lacks the reference (restarted, or a new one)
    /// rejects a predicted frame, shows nothing wrong and asks for a key
    /// frame; the sender's key frame, when wanted, is taken.
    #[test]
    fn a_missing_reference_is_rejected_until_a_key_frame() {
        let pairs = sequence();
        let cfg = config(None);
        let mut stream = StreamEncoder::new(SkipSpec::default());
        let mut prepare = |i: usize, want_key| {
            let id = i as u32 + 1;
            let (p, kind) = stream
                .prepare(
                    (&pairs[i].0, &pairs[i].1),
                    &calib(),
                    &cfg,
                    (id, u64::from(id)),
                    want_key,
                )
                .unwrap();
            stream.acknowledge(id);
            (p, kind)
        };
        let (key, _) = prepare(0, false);
        let (predicted, kind) = prepare(1, false);
        assert_eq!(kind, FrameKind::Predicted { reference: 1 });
        let mut restarted = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        let e = restarted.handle(&predicted.frame_bytes);
        assert!(
            matches!(&e, Event::Rejected(why) if why.contains("reference frame 1")),
            "{e:?}"
        );
        assert!(restarted.needs_key() && restarted.pair().is_none());
        let (again, kind) = prepare(2, true);
        assert_eq!(kind, FrameKind::Key);
        assert!(matches!(
            restarted.handle(&again.frame_bytes),
            Event::Frame { .. }
        ));
        assert!(!restarted.needs_key());
        // A receiver that forgot its references (a new session) rejects
        // what it held before.
        let mut board = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        assert!(matches!(
            board.handle(&key.frame_bytes),
            Event::Frame { .. }
        ));
        assert!(matches!(
            board.handle(&predicted.frame_bytes),
            Event::Frame { .. }
        ));
        board.reset_references();
        assert!(matches!(
            board.handle(&predicted.frame_bytes),
            Event::Rejected(_)
        ));
    }

    /// Only a frame among the last sent is acknowledged, and a reset makes
    /// the next frame a key frame.
    #[test]
    fn acknowledgements_choose_the_reference() {
        let pairs = sequence();
        let cfg = config(None);
        let mut stream = StreamEncoder::new(SkipSpec::default());
        let send = |stream: &mut StreamEncoder, id: u32| {
            let (l, r) = &pairs[id as usize % pairs.len()];
            stream
                .prepare((l, r), &calib(), &cfg, (id, u64::from(id)), false)
                .unwrap()
                .1
        };
        assert_eq!(send(&mut stream, 1), FrameKind::Key);
        assert_eq!(send(&mut stream, 2), FrameKind::Key, "nothing acknowledged");
        stream.acknowledge(2);
        stream.acknowledge(1);
        stream.acknowledge(99);
        assert_eq!(send(&mut stream, 3), FrameKind::Predicted { reference: 2 });
        for id in 4..=7 {
            send(&mut stream, id);
        }
        // Frame 2 is no longer among the last sent: a key frame.
        assert_eq!(stream.reference(), None);
        assert_eq!(send(&mut stream, 8), FrameKind::Key);
        stream.acknowledge(8);
        stream.reset();
        assert_eq!(send(&mut stream, 9), FrameKind::Key);
    }
}
