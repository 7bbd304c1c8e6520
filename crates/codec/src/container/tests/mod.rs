//! Round trips of every message, typed errors on corrupt and foreign
//! bytes, plane table sections, lossy views (stock bitstreams made by
//! Pillow, so that the board, without encoders, runs these too), the golden
//! depth report, and corrupted bodies through both the owning decode and
//! the reusing decoder. Frames predicted from a reference (temporal,
//! stereo, motion) are in [`predicted`].

use proptest::prelude::*;
use stereolink_image::segments::components;
use stereolink_image::{Calibration, IndexedImage, LabelMap, Rgb, RgbImage};

use super::*;
use crate::lossy::{LossyCodec, LossyView};
use crate::{DepthReport, ReportLevel, SegmentationKind, StereoFrame, View};

mod predicted;

/// A 24x16 view as JPEG (4:2:0) and as lossy WebP.
const JPEG_VIEW: &[u8] = include_bytes!("../testdata/view24x16.jpg");
const WEBP_VIEW: &[u8] = include_bytes!("../testdata/view24x16.webp");

/// A frame of two lossy views: a JPEG left and a WebP right.
fn lossy_frame() -> StereoFrame {
    let view = |codec, bits: &[u8]| {
        View::Lossy(LossyView::decode(codec, bits.to_vec(), (24, 16)).unwrap())
    };
    StereoFrame {
        kind: SegmentationKind::None,
        levels: 0,
        thresholds: None,
        left: view(LossyCodec::Jpeg, JPEG_VIEW),
        right: view(LossyCodec::Webp, WEBP_VIEW),
        ..frame(24, 16)
    }
}

/// `bytes` with its body's length and CRC made right again.
fn resealed(mut bytes: Vec<u8>) -> Vec<u8> {
    let body_len = (bytes.len() - HEADER_LEN) as u32;
    bytes[20..24].copy_from_slice(&body_len.to_le_bytes());
    let crc = crc32fast::hash(&bytes[HEADER_LEN..]);
    bytes[24..28].copy_from_slice(&crc.to_le_bytes());
    bytes
}

fn frame(w: usize, h: usize) -> StereoFrame {
    let palette = vec![[10, 20, 30], [200, 100, 0], [0, 255, 0]];
    let left = IndexedImage::new(
        LabelMap::from_fn(w, h, |x, y| ((x / 3 + y / 2) % 3) as u16),
        palette.clone(),
    )
    .unwrap();
    let right = IndexedImage::new(
        LabelMap::from_fn(w, h, |x, y| (((x + 3) / 3 + y / 2) % 3) as u16),
        palette,
    )
    .unwrap();
    StereoFrame {
        kind: SegmentationKind::Fodpso,
        levels: 3,
        params: "alpha=0.6".into(),
        thresholds: Some([vec![80, 160], vec![90], vec![]]),
        calibration: Some(Calibration {
            focal_px: Some(700.0),
            baseline_m: Some(0.12),
            doffs: 0.0,
            ndisp: 64,
        }),
        left: View::Indexed(left),
        right: View::Indexed(right),
        planes: None,
    }
}

#[test]
fn frames_reports_and_control_round_trip() {
    for (w, h) in [(1, 1), (7, 3), (33, 17)] {
        let m = Message::StereoFrame(Box::new(frame(w, h)));
        let bytes = encode(&m, 42, 123_456);
        let (hd, back) = decode(&bytes, &Limits::default()).unwrap();
        assert_eq!(
            (hd.frame_id, hd.timestamp_us, hd.kind),
            (42, 123_456, kind::STEREO_FRAME)
        );
        assert_eq!(back, m);
    }
    let rgb = StereoFrame {
        left: View::Rgb(RgbImage::from_fn(5, 4, |x, y| [x as u8, y as u8, 9])),
        right: View::Rgb(RgbImage::new(5, 4, [1, 2, 3])),
        thresholds: None,
        calibration: None,
        kind: SegmentationKind::None,
        ..frame(5, 4)
    };
    let m = Message::StereoFrame(Box::new(rgb));
    assert_eq!(decode(&encode(&m, 1, 2), &Limits::default()).unwrap().1, m);
    let c = Message::Control(vec![1, 2, 3]);
    assert_eq!(decode(&encode(&c, 1, 2), &Limits::default()).unwrap().1, c);
}

/// The largest palette the default limits accept, 65536 colours (labels
/// are u16), comes back whole.
#[test]
fn largest_palette_round_trips() {
    let palette: Vec<Rgb> = (0..1u32 << 16)
        .map(|i| [i as u8, (i >> 8) as u8, 7])
        .collect();
    let left =
        IndexedImage::new(LabelMap::from_fn(2, 1, |x, _| x as u16 * 65535), palette).unwrap();
    let m = Message::StereoFrame(Box::new(StereoFrame {
        left: View::Indexed(left),
        right: View::Rgb(RgbImage::new(2, 1, [1, 2, 3])),
        ..frame(2, 1)
    }));
    assert_eq!(decode(&encode(&m, 1, 2), &Limits::default()).unwrap().1, m);
}

#[test]
fn corrupt_and_foreign_bytes_are_typed_errors() {
    let bytes = encode(&Message::StereoFrame(Box::new(frame(20, 10))), 1, 1);
    let l = Limits::default();
    let mut bad = bytes.clone();
    bad[HEADER_LEN + 5] ^= 0x10;
    assert_eq!(decode(&bad, &l).unwrap_err(), CodecError::Crc);
    let mut v1 = bytes.clone();
    v1[4] = 1;
    assert_eq!(
        decode(&v1, &l).unwrap_err(),
        CodecError::UnsupportedVersion(1)
    );
    assert_eq!(decode(b"PNG....", &l).unwrap_err(), CodecError::BadMagic);
    assert!(matches!(
        decode(&bytes[..bytes.len() - 1], &l),
        Err(CodecError::Truncated(_))
    ));
    // A left view coded conditioned (the left view's coding byte is the
    // body's tenth without params, thresholds and calibration), even
    // after a frame that left labels behind in a reused decoder.
    let plain = StereoFrame {
        params: String::new(),
        thresholds: None,
        calibration: None,
        ..frame(20, 10)
    };
    let good = encode(&Message::StereoFrame(Box::new(plain)), 1, 1);
    let mut cond = good.clone();
    assert_eq!(cond[HEADER_LEN + 9], coding::LABELS);
    cond[HEADER_LEN + 9] = coding::LABELS_CONDITIONED;
    let crc = crc32fast::hash(&cond[HEADER_LEN..]);
    cond[24..28].copy_from_slice(&crc.to_le_bytes());
    assert!(matches!(decode(&cond, &l), Err(CodecError::Invalid(_))));
    let mut reused = FrameDecoder::default();
    for (bytes, ok) in [(&good, true), (&cond, false)] {
        let result = parse(bytes, &l).and_then(|(_, body)| match body {
            Body::StereoFrame(f) => reused.decode_rgb(&f),
            _ => unreachable!("a stereo frame"),
        });
        assert_eq!(result.is_ok(), ok);
    }
    let tight = Limits { max_body: 10, ..l };
    assert!(matches!(
        decode(&bytes, &tight),
        Err(CodecError::TooLarge { .. })
    ));
    let tiny = Limits {
        max_pixels: 100,
        ..l
    };
    assert!(matches!(
        decode(&bytes, &tiny),
        Err(CodecError::TooLarge { .. })
    ));
}

/// [`frame`] with a plane table: five planes over the segments of its
/// left labels.
fn with_planes(w: usize, h: usize) -> StereoFrame {
    let f = frame(w, h);
    let View::Indexed(left) = &f.left else {
        unreachable!("an indexed left view")
    };
    let (ids, count) = components(left.labels(), 0);
    let per: Vec<[f32; 3]> = (0..count).map(|s| [0.5, -0.25, (s % 5) as f32]).collect();
    let coding = crate::planetable::TableCoding::default();
    StereoFrame {
        planes: Some(crate::planetable::PlaneTable::quantise(
            0,
            (0, 15),
            coding,
            Some(&ids),
            &per,
        )),
        ..f
    }
}

#[test]
fn plane_tables_round_trip_and_unknown_sections_are_skipped() {
    let l = Limits::default();
    let m = Message::StereoFrame(Box::new(with_planes(21, 9)));
    let bytes = encode(&m, 3, 4);
    assert_eq!(decode(&bytes, &l).unwrap().1, m);
    // Without the table, the frame is the plain frame's bytes: the
    // section is appended, so a decoder before sections sees trailing
    // bytes and refuses the frame.
    let plain = encode(&Message::StereoFrame(Box::new(frame(21, 9))), 3, 4);
    assert_eq!(&bytes[HEADER_LEN..plain.len()], &plain[HEADER_LEN..]);
    let mut body = bytes[HEADER_LEN..].to_vec();
    // An unknown section (tag 9) and plane tables of versions 1 (the
    // old raw indices) and 2 (every index coded) are skipped.
    body.extend([9, 1, 2, 0, 0, 0, 0xAA, 0xBB]);
    body.extend([1, 1, 0, 0, 0, 0, 1, 2, 0, 0, 0, 0]);
    let reframe = |body: &[u8]| {
        let mut out = bytes[..HEADER_LEN].to_vec();
        out[20..24].copy_from_slice(&(body.len() as u32).to_le_bytes());
        out[24..28].copy_from_slice(&crc32fast::hash(body).to_le_bytes());
        out.extend_from_slice(body);
        out
    };
    assert_eq!(decode(&reframe(&body), &l).unwrap().1, m);
    // A second table, a truncated section and a table on an RGB left
    // view are errors.
    let section = &bytes[plain.len()..];
    let mut two = body.clone();
    two.extend_from_slice(section);
    assert!(matches!(
        decode(&reframe(&two), &l),
        Err(CodecError::Invalid(_))
    ));
    assert!(matches!(
        decode(&reframe(&body[..body.len() - 1]), &l),
        Err(CodecError::Truncated(_))
    ));
    let rgb = StereoFrame {
        left: View::Rgb(RgbImage::new(21, 9, [1, 2, 3])),
        ..with_planes(21, 9)
    };
    let rgb = encode(&Message::StereoFrame(Box::new(rgb)), 1, 1);
    assert!(matches!(decode(&rgb, &l), Err(CodecError::Invalid(_))));
}

/// Pins the wire format: a depth report's exact bytes (checked independently
/// with Python's `struct` and `zlib.crc32`).
#[test]
fn golden_depth_report() {
    let r = DepthReport {
        target_distance_m: 0.5,
        target_region: [1, 2, 3, 4],
        levels: vec![ReportLevel {
            disparity: 2.0,
            distance_m: 1.0,
            share: 0.5,
        }],
        histogram: vec![7],
    };
    let bytes = encode(&Message::DepthReport(r), 0x0102_0304, 5);
    let hex: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
    assert_eq!(
        hex,
        "534c4e4b02020000040302010500000000000000210000006237a12c\
         0000003f01000200030004000100000040\
         0000803f0000003f0100000007000000"
    );
}

/// Encodes `f`, and checks that the owned decoder gives it back and that
/// a [`FrameDecoder`] rebuilds its views; returns that decoder and the
/// parsed frame's bytes.
fn through_both_decoders(f: &StereoFrame) -> (FrameDecoder, Vec<u8>) {
    let m = Message::StereoFrame(Box::new(f.clone()));
    let bytes = encode(&m, 5, 6);
    assert_eq!(decode(&bytes, &Limits::default()).unwrap().1, m);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&bytes, &Limits::default()) else {
        panic!("not a frame")
    };
    let mut d = FrameDecoder::default();
    d.decode_rgb(&parsed).unwrap();
    assert_eq!(d.views(), (&f.left.to_rgb(), &f.right.to_rgb()));
    (d, bytes)
}

#[test]
fn lossy_views_round_trip_through_both_decoders() {
    let f = lossy_frame();
    let (d, bytes) = through_both_decoders(&f);
    let Ok((_, Body::StereoFrame(parsed))) = parse(&bytes, &Limits::default()) else {
        panic!("not a frame")
    };
    assert!(d.indexed_views().is_none() && d.left_labels(&parsed).is_none());
    // The views are the pictures, not black: the mean of a channel is
    // far from zero.
    let mean = f
        .left
        .to_rgb()
        .as_slice()
        .iter()
        .map(|p| p[0] as u32)
        .sum::<u32>()
        / (24 * 16);
    assert!(mean > 40, "mean red {mean}");
}

#[test]
fn forged_and_truncated_lossy_views_are_typed_errors() {
    let l = Limits::default();
    let bytes = encode(&Message::StereoFrame(Box::new(lossy_frame())), 1, 1);
    // The left view's codec byte comes just before its bitstream, after
    // its coding (1 byte), palette count (4) and payload length (4).
    let at = bytes
        .windows(JPEG_VIEW.len())
        .position(|w| w == JPEG_VIEW)
        .unwrap();
    let mut codec = bytes.clone();
    codec[at - 1] = 9;
    assert_eq!(
        decode(&resealed(codec), &l).unwrap_err(),
        CodecError::Invalid("lossy codec 9".into())
    );
    // The bitstream cut short inside a consistent message: the JPEG's
    // scan loses its end, the WebP its RIFF chunk's.
    for (codec, bits, keep) in [
        (LossyCodec::Jpeg, JPEG_VIEW, 200),
        (LossyCodec::Webp, WEBP_VIEW, 100),
    ] {
        let forged = StereoFrame {
            left: View::Lossy(LossyView::decoded(
                codec,
                bits[..keep].to_vec(),
                RgbImage::new(24, 16, [0; 3]),
            )),
            ..lossy_frame()
        };
        let bytes = encode(&Message::StereoFrame(Box::new(forged)), 1, 1);
        let e = decode(&bytes, &l);
        assert!(matches!(e, Err(CodecError::Invalid(_))), "{codec:?}: {e:?}");
    }
    // A scan on which zune-jpeg ends early without an error (from the
    // fuzzer): a reused view decodes to what a fresh one does, not to
    // what it held before.
    let early_end = include_bytes!("../testdata/view64x48-early-end.jpg");
    let mut fresh = RgbImage::new(0, 0, [0; 3]);
    crate::lossy::decode_into(LossyCodec::Jpeg, early_end, (64, 48), &mut fresh).unwrap();
    let mut reused = RgbImage::new(64, 48, [7; 3]);
    crate::lossy::decode_into(LossyCodec::Jpeg, early_end, (64, 48), &mut reused).unwrap();
    assert!(
        fresh == reused,
        "the reused view kept pixels of the last frame"
    );
    // A view of another size than the frame's.
    let other = StereoFrame {
        right: View::Lossy(
            LossyView::decode(LossyCodec::Jpeg, JPEG_VIEW.to_vec(), (24, 16)).unwrap(),
        ),
        ..lossy_frame()
    };
    let mut bytes = encode(&Message::StereoFrame(Box::new(other)), 1, 1);
    bytes[HEADER_LEN] = 23; // the frame's width
    let e = decode(&resealed(bytes), &l).unwrap_err();
    assert!(
        matches!(&e, CodecError::Invalid(m) if m.contains("JPEG view")),
        "{e}"
    );
    // A lossy view with a palette (its count's low byte set).
    let mut p = encode(&Message::StereoFrame(Box::new(lossy_frame())), 1, 1);
    p[at - 9] = 1;
    assert!(decode(&resealed(p), &l).is_err());
}

proptest! {
    /// Corrupted bodies with a correct CRC reach every body parser and
    /// the view decoders: a typed error or a message, never a panic;
    /// the owning decode and the reusing decoder (with the plane table
    /// resolved against its labels, as the board does) agree.
    #[test]
    fn corrupt_bodies_are_errors_or_messages(
        flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
        cut in any::<usize>(),
        lossy in any::<bool>(),
    ) {
        let f = if lossy { lossy_frame() } else { with_planes(21, 9) };
        let mut bytes = encode(&Message::StereoFrame(Box::new(f)), 1, 2);
        for (at, x) in flips {
            let i = HEADER_LEN + at % (bytes.len() - HEADER_LEN);
            bytes[i] ^= x | 1;
        }
        bytes.truncate(HEADER_LEN + cut % (bytes.len() - HEADER_LEN + 1));
        let bytes = resealed(bytes);
        let owned = decode(&bytes, &Limits::default());
        if let Ok((_, Body::StereoFrame(f))) = parse(&bytes, &Limits::default()) {
            let mut decoder = FrameDecoder::default();
            let reused = decoder.decode_rgb(&f).and_then(|()| {
                if let (Some(t), Some(labels)) = (&f.planes, decoder.left_labels(&f)) {
                    let (ids, count) = components(labels, t.tile() as usize);
                    t.resolve(&ids, count)?;
                }
                Ok(decoder.views())
            });
            match (&owned, reused) {
                (Ok((_, Message::StereoFrame(m))), Ok((l, r))) => {
                    prop_assert_eq!(&m.left.to_rgb(), l);
                    prop_assert_eq!(&m.right.to_rgb(), r);
                }
                (Err(_), Err(_)) => {}
                (a, b) => prop_assert!(false, "owned {:?} but reused {:?}", a.is_ok(), b.is_ok()),
            }
        }
    }
}

/// A report fitted to a budget encodes within it, keeps the distance and
/// region, and keeps as many of the nearest levels as fit.
#[test]
fn a_fitted_report_encodes_within_its_budget() {
    let level = ReportLevel {
        disparity: 12.5,
        distance_m: 1.25,
        share: 0.5,
    };
    let r = DepthReport {
        target_distance_m: 1.5,
        target_region: [1, 2, 3, 4],
        levels: vec![level; 5],
        histogram: vec![7; 64],
    };
    let len = |r: &DepthReport| encode(&Message::DepthReport(r.clone()), 1, 2).len();
    assert_eq!(len(&r), report_len(5, 64));
    for budget in [44, 45, 49, 56, 57, 65, 200, 1000] {
        let Some(f) = r.fitted(budget) else {
            assert!(budget < report_len(0, 0), "{budget}");
            continue;
        };
        assert!(len(&f) <= budget, "{budget}: {}", len(&f));
        assert_eq!((f.target_distance_m, f.target_region), (1.5, [1, 2, 3, 4]));
        assert!(f.histogram.is_empty());
        let kept = f.levels.len();
        assert!(
            kept == 5 || len(&f) + REPORT_LEVEL_LEN > budget,
            "{budget}: {kept}"
        );
    }
}
