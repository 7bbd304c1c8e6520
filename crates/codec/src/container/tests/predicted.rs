//! Frames predicted from a reference: temporally (blocks and label maps),
//! from the left view (stereo) and by motion, through both decoders, and
//! their forged and truncated forms as typed errors.

use super::*;

/// A frame predicted from `key` (sent as frame `id`) with no block
/// changed: both views its views.
fn predicted_frame(key: &StereoFrame, id: crate::temporal::RefId) -> StereoFrame {
    use crate::temporal::{blocks, PredictedView};
    let view = |v: &View| {
        let img = v.to_rgb();
        let (cols, rows) = blocks(img.dims());
        let p = PredictedView::encode(
            &img,
            (id, &img),
            vec![false; cols * rows],
            LossyCodec::Webp,
            0,
        );
        View::Predicted(p.unwrap())
    };
    StereoFrame {
        left: view(&key.left),
        right: view(&key.right),
        ..key.clone()
    }
}

#[test]
fn predicted_frames_decode_from_their_reference_only() {
    use crate::temporal::{RefId, References};
    let key = lossy_frame();
    let id = RefId {
        frame_id: 7,
        timestamp_us: 70,
    };
    let p = predicted_frame(&key, id);
    let bytes = encode(&Message::StereoFrame(Box::new(p.clone())), 8, 80);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&bytes, &Limits::default()) else {
        panic!("not a frame")
    };
    assert_eq!(parsed.references().collect::<Vec<_>>(), [id, id]);
    let missing = Err(CodecError::MissingReference {
        frame_id: 7,
        timestamp_us: 70,
    });
    assert_eq!(parsed.decode(), missing);
    let mut refs = References::default();
    // The same id from another session (another time stamp) is not it.
    let (l, r) = (key.left.to_rgb(), key.right.to_rgb());
    refs.keep(
        RefId {
            timestamp_us: 1,
            ..id
        },
        (&l, &r),
    );
    assert_eq!(parsed.decode_with(&refs), missing);
    let mut d = FrameDecoder::default();
    assert_eq!(
        d.decode_with(&parsed, &refs),
        missing.map(|_: StereoFrame| ())
    );
    refs.keep(id, (&l, &r));
    assert_eq!(parsed.decode_with(&refs).unwrap(), p);
    d.decode_with(&parsed, &refs).unwrap();
    d.expand_views();
    assert_eq!(d.views(), (&l, &r));
    // A reference of another size is refused.
    let small = RgbImage::new(16, 16, [0; 3]);
    refs.keep(id, (&small, &small));
    assert!(
        matches!(parsed.decode_with(&refs), Err(CodecError::Invalid(m)) if m.contains("16x16"))
    );
}

#[test]
fn forged_and_truncated_predicted_views_are_typed_errors() {
    use crate::temporal::RefId;
    let id = RefId {
        frame_id: 1,
        timestamp_us: 2,
    };
    let bytes = encode(
        &Message::StereoFrame(Box::new(predicted_frame(&lossy_frame(), id))),
        2,
        3,
    );
    let l = Limits::default();
    assert!(parse(&bytes, &l).is_ok());
    // The right view is last: coding (1), palette count (4), payload
    // length (4), reference (12), changed map (2 blocks: 1 byte).
    let payload_at = bytes.len() - 13;
    assert_eq!(bytes[payload_at - 9], coding::PREDICTED);
    let with = |payload: &[u8]| {
        let mut b = bytes[..payload_at - 4].to_vec();
        b.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        b.extend_from_slice(payload);
        parse(&resealed(b), &l).map(|_| ())
    };
    let good = bytes[payload_at..].to_vec();
    assert_eq!(with(&good), Ok(()));
    assert_eq!(
        with(&good[..12]),
        Err(CodecError::Truncated("changed-block map"))
    );
    assert_eq!(
        with(&good[..5]),
        Err(CodecError::Truncated("predicted view"))
    );
    let mut past = good.clone();
    past[12] = 0b100;
    assert!(matches!(with(&past), Err(CodecError::Invalid(m)) if m.contains("past the view")));
    let mut flagged = good.clone();
    flagged[12] = 0b1;
    assert_eq!(with(&flagged), Err(CodecError::Truncated("mosaic")));
    flagged.push(7);
    assert!(matches!(with(&flagged), Err(CodecError::Invalid(m)) if m.contains("codec 7")));
    let mut trailing = good.clone();
    trailing.push(1);
    assert!(
        matches!(with(&trailing), Err(CodecError::Invalid(m)) if m.contains("no changed block"))
    );
    // A mosaic that is not a bitstream of its size: an error when decoded.
    flagged.pop();
    flagged.extend_from_slice(&[1, 0, 0, 0]);
    let mut b = bytes[..payload_at - 4].to_vec();
    b.extend_from_slice(&(flagged.len() as u32).to_le_bytes());
    b.extend_from_slice(&flagged);
    let b = resealed(b);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&b, &l) else {
        panic!("parses")
    };
    let mut refs = crate::temporal::References::default();
    let img = lossy_frame().left.to_rgb();
    refs.keep(id, (&img, &img));
    assert!(matches!(
        parsed.decode_with(&refs),
        Err(CodecError::Invalid(_))
    ));
}

#[test]
fn predicted_label_maps_decode_from_their_reference_only() {
    use crate::temporal::{PredictedLabels, RefId, References};
    let key = frame(40, 24);
    let id = RefId {
        frame_id: 3,
        timestamp_us: 30,
    };
    let (Some(kl), Some(kr)) = (key.left.indexed(), key.right.indexed()) else {
        panic!("indexed")
    };
    // The next frame: the key's views, a few labels changed, in another
    // palette order.
    let next = |v: &IndexedImage| {
        let mut labels = v.labels().map(|l| 2 - l);
        labels.set(5, 5, 0);
        let palette = v.palette().iter().rev().copied().collect();
        IndexedImage::new(labels, palette).unwrap()
    };
    let p = StereoFrame {
        left: View::PredictedLabels(PredictedLabels::encode(
            next(kl),
            (id, kl),
            crate::labels::Mode::Fast,
        )),
        right: View::PredictedLabels(PredictedLabels::encode(
            next(kr),
            (id, kr),
            crate::labels::Mode::Fast,
        )),
        ..key.clone()
    };
    let bytes = encode(&Message::StereoFrame(Box::new(p.clone())), 4, 40);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&bytes, &Limits::default()) else {
        panic!("not a frame")
    };
    assert!(matches!(
        parsed.decode(),
        Err(CodecError::MissingReference { frame_id: 3, .. })
    ));
    let mut refs = References::default();
    let (l, r) = (key.left.to_rgb(), key.right.to_rgb());
    // Pixels of frame 3 are not its labels.
    refs.keep(id, (&l, &r));
    assert!(matches!(
        parsed.decode_with(&refs),
        Err(CodecError::MissingReference { .. })
    ));
    refs.keep_labels(
        id,
        [(kl.labels(), kl.palette()), (kr.labels(), kr.palette())],
    );
    let decoded = parsed.decode_with(&refs).unwrap();
    assert_eq!(decoded, p);
    assert_eq!(decoded.left.indexed(), Some(&next(kl)));
    // A label table entry past the view's palette is refused.
    let at = bytes.len()
        - match &p.right {
            View::PredictedLabels(v) => v.payload().len() - 12,
            _ => unreachable!(),
        };
    let mut forged = bytes.clone();
    forged[at] = 9;
    let forged = resealed(forged);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&forged, &Limits::default()) else {
        panic!("parses")
    };
    assert_eq!(
        parsed.decode_with(&refs),
        Err(CodecError::LabelOutOfRange {
            label: 9,
            labels: 3
        })
    );
}

/// A 96x64 frame of two unsegmented views.
#[cfg(feature = "encode")]
fn unsegmented(left: View, right: View) -> StereoFrame {
    StereoFrame {
        kind: SegmentationKind::None,
        levels: 0,
        thresholds: None,
        left,
        right,
        ..frame(96, 64)
    }
}

/// A frame whose right view is stereo-predicted from its WebP left view
/// (the synthetic pair), and the original right view.
#[cfg(feature = "encode")]
fn stereo_frame() -> StereoFrame {
    use crate::stereo::{StereoSpec, StereoView};
    use stereolink_image::synth::{synthesize, SynthSpec};
    let s = synthesize(&SynthSpec {
        width: 96,
        height: 64,
        max_disp: 12,
        seed: 9,
    })
    .unwrap();
    let left = crate::lossy::encode(&s.left, LossyCodec::Webp, 50).unwrap();
    let spec = StereoSpec::default();
    let right = StereoView::encode(
        &s.right,
        (&s.left, left.image()),
        LossyCodec::Webp,
        50,
        &spec,
    )
    .unwrap();
    unsegmented(View::Lossy(left), View::Stereo(right))
}

#[cfg(feature = "encode")]
#[test]
fn stereo_predicted_views_rebuild_the_senders_pair_through_both_decoders() {
    let f = stereo_frame();
    let (mut d, _) = through_both_decoders(&f);
    let View::Stereo(right) = &f.right else {
        unreachable!("built stereo")
    };
    assert_eq!(d.stereo_disparities(), Some(right.disparities()));
    // A frame without stereo prediction carries no disparities.
    let plain = encode(&Message::StereoFrame(Box::new(lossy_frame())), 7, 8);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&plain, &Limits::default()) else {
        panic!("not a frame")
    };
    d.decode_rgb(&parsed).unwrap();
    assert_eq!(d.stereo_disparities(), None);
}

#[cfg(feature = "encode")]
#[test]
fn misplaced_or_truncated_stereo_views_are_typed_errors() {
    let l = Limits::default();
    let f = stereo_frame();
    // The right view's coding byte: after the left view (coding, palette
    // count, payload length, payload).
    let bytes = encode(&Message::StereoFrame(Box::new(f.clone())), 1, 1);
    let View::Lossy(left) = &f.left else {
        unreachable!("built lossy")
    };
    let left_at = bytes
        .windows(left.bytes().len())
        .position(|w| w == left.bytes())
        .unwrap();
    let right_at = left_at + left.bytes().len();
    assert_eq!(bytes[right_at], coding::STEREO);
    // A stereo-predicted left view (from nothing).
    let mut forged = bytes.clone();
    forged[left_at - 10] = coding::STEREO;
    assert_eq!(
        decode(&resealed(forged), &l).unwrap_err(),
        CodecError::Invalid("the left view is stereo-predicted (from nothing)".into())
    );
    // After a segmented left view.
    let View::Stereo(right) = f.right else {
        unreachable!("built stereo")
    };
    let segmented = StereoFrame {
        right: View::Stereo(right.clone()),
        ..frame(96, 64)
    };
    let e = decode(
        &encode(&Message::StereoFrame(Box::new(segmented)), 1, 1),
        &l,
    );
    assert_eq!(
        e.unwrap_err(),
        CodecError::Invalid("a stereo-predicted right view with a segmented left view".into())
    );
    // The payload cut inside its blocks, in a consistent message.
    let payload = right.payload();
    let mut cut = bytes[..right_at + 5].to_vec();
    let keep = 6usize;
    cut.extend_from_slice(&(keep as u32).to_le_bytes());
    cut.extend_from_slice(&payload[..keep]);
    assert!(matches!(
        decode(&resealed(cut), &l),
        Err(CodecError::Truncated(_))
    ));
}

/// A synthetic key pair (WebP, as decoded) and the pair moved 3 px right
/// and 2 px down, its views predicted by motion from the key's as frame
/// `id`.
#[cfg(feature = "encode")]
fn motion_frames(id: crate::temporal::RefId) -> ([RgbImage; 2], StereoFrame) {
    use crate::motion::{MotionPlan, MotionSpec, MotionView};
    use stereolink_image::synth::{synthesize, SynthSpec};
    let s = synthesize(&SynthSpec {
        width: 100,
        height: 70,
        max_disp: 8,
        seed: 4,
    })
    .unwrap();
    let window = |v: &RgbImage, x, y| RgbImage::from_fn(96, 64, |i, j| v.get(x + i, y + j));
    let mut key = Vec::new();
    let mut views = Vec::new();
    for v in [&s.left, &s.right] {
        let (first, next) = (window(v, 0, 0), window(v, 3, 2));
        let sent = crate::lossy::encode(&first, LossyCodec::Webp, 50).unwrap();
        let still = vec![false; 6 * 4];
        let plan = MotionPlan::new(
            &next,
            (&first, sent.image()),
            &still,
            &MotionSpec::default(),
        );
        let view = MotionView::encode(&next, (id, &plan), LossyCodec::Webp, 50).unwrap();
        key.push(sent.image().clone());
        views.push(View::Motion(view));
    }
    let right = views.pop().unwrap();
    let left = views.pop().unwrap();
    (key.try_into().unwrap(), unsegmented(left, right))
}

#[cfg(feature = "encode")]
#[test]
fn motion_predicted_views_decode_from_their_reference_through_both_decoders() {
    use crate::temporal::{RefId, References};
    let id = RefId {
        frame_id: 3,
        timestamp_us: 30,
    };
    let ([l, r], f) = motion_frames(id);
    let bytes = encode(&Message::StereoFrame(Box::new(f.clone())), 4, 40);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&bytes, &Limits::default()) else {
        panic!("not a frame")
    };
    assert_eq!(parsed.references().collect::<Vec<_>>(), [id, id]);
    assert_eq!(parsed.unchanged(), None, "the views moved");
    let missing = Err(CodecError::MissingReference {
        frame_id: 3,
        timestamp_us: 30,
    });
    assert_eq!(parsed.decode(), missing);
    let mut d = FrameDecoder::default();
    assert_eq!(d.decode(&parsed), missing.map(|_: StereoFrame| ()));
    let mut refs = References::default();
    refs.keep(id, (&l, &r));
    assert_eq!(parsed.decode_with(&refs).unwrap(), f);
    d.decode_with(&parsed, &refs).unwrap();
    d.expand_views();
    assert_eq!(d.views(), (&f.left.to_rgb(), &f.right.to_rgb()));
    // A reference of another size is refused by both.
    let small = RgbImage::new(16, 16, [0; 3]);
    refs.keep(id, (&small, &small));
    let other_size = |e: &CodecError| matches!(e, CodecError::Invalid(m) if m.contains("16x16"));
    assert!(parsed.decode_with(&refs).is_err_and(|e| other_size(&e)));
    assert!(d.decode_with(&parsed, &refs).is_err_and(|e| other_size(&e)));
}

/// A pair predicted by motion with every block still is the reference's
/// pair (a still pair); one with a block coded, or a vector not zero, is
/// not.
#[cfg(feature = "encode")]
#[test]
fn a_still_motion_pair_is_unchanged() {
    use crate::motion::{MotionPlan, MotionSpec, MotionView};
    use crate::temporal::RefId;
    let id = RefId {
        frame_id: 5,
        timestamp_us: 50,
    };
    let ([l, _], _) = motion_frames(id);
    let unchanged = |still: &[bool], current: &RgbImage| {
        let plan = MotionPlan::new(current, (&l, &l), still, &MotionSpec::default());
        let v =
            View::Motion(MotionView::encode(current, (id, &plan), LossyCodec::Webp, 50).unwrap());
        let bytes = encode(
            &Message::StereoFrame(Box::new(unsegmented(v.clone(), v))),
            6,
            60,
        );
        let Ok((_, Body::StereoFrame(parsed))) = parse(&bytes, &Limits::default()) else {
            panic!("not a frame")
        };
        parsed.unchanged()
    };
    assert_eq!(unchanged(&[true; 24], &l), Some(id));
    // The same view, nothing still: searched, every vector zero, every
    // block skipped (the prediction is exact).
    assert_eq!(unchanged(&[false; 24], &l), Some(id));
    let mut moved = l.clone();
    for p in &mut moved.as_mut_slice()[..96 * 8] {
        *p = [255, 0, 0];
    }
    assert_eq!(unchanged(&[false; 24], &moved), None);
}

#[cfg(feature = "encode")]
#[test]
fn truncated_motion_views_are_typed_errors() {
    use crate::temporal::{RefId, References};
    let id = RefId {
        frame_id: 1,
        timestamp_us: 2,
    };
    let ([l, r], f) = motion_frames(id);
    let View::Motion(right) = &f.right else {
        unreachable!("built by motion")
    };
    let payload = right.payload();
    let bytes = encode(&Message::StereoFrame(Box::new(f.clone())), 2, 3);
    // The right view is last: coding (1), palette count (4), payload
    // length (4), payload.
    let payload_at = bytes.len() - payload.len();
    assert_eq!(bytes[payload_at - 9], coding::MOTION);
    let with = |payload: &[u8]| {
        let mut b = bytes[..payload_at - 4].to_vec();
        b.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        b.extend_from_slice(payload);
        resealed(b)
    };
    let l_ = Limits::default();
    // Too short to name its reference: refused by the parse.
    assert_eq!(
        parse(&with(&payload[..7]), &l_).map(|_| ()),
        Err(CodecError::Truncated("predicted view"))
    );
    let mut refs = References::default();
    refs.keep(id, (&l, &r));
    let blocks_end = 16 + u32::from_le_bytes(payload[12..16].try_into().unwrap()) as usize;
    for cut in [14, 16, blocks_end - 1, blocks_end] {
        let b = with(&payload[..cut]);
        let Ok((_, Body::StereoFrame(parsed))) = parse(&b, &l_) else {
            panic!("parses")
        };
        let mut d = FrameDecoder::default();
        assert!(d.decode_with(&parsed, &refs).is_err(), "cut to {cut}");
        assert!(parsed.decode_with(&refs).is_err(), "cut to {cut}");
    }
}
