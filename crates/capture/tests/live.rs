//! Live capture from GStreamer test sources: pairing without drift, and
//! each way a source can fail, named.

#![cfg(feature = "gstreamer")]

use std::time::{Duration, Instant};

use stereolink_capture::{CaptureOptions, Error, Side, SourceSpec, StereoCapture, StopReason};

fn test_source(extra: &str) -> SourceSpec {
    SourceSpec::description(format!(
        "videotestsrc is-live=true pattern=ball {extra} ! video/x-raw,width=160,height=120,framerate=30/1"
    ))
}

fn open(left: &SourceSpec, right: &SourceSpec) -> stereolink_capture::Result<StereoCapture> {
    StereoCapture::open(left, right, CaptureOptions::default())
}

/// Two live 30 fps sources in one pipeline: 300 pairs, each within half a
/// frame interval, timestamps advancing, no frame dropped for skew.
#[test]
fn two_live_test_sources_pair_without_drift() {
    let mut capture = open(&test_source(""), &test_source("")).unwrap();
    let half_interval = Duration::from_secs(1) / 60;
    let mut last_pts = None;
    for i in 0..300 {
        let pair = capture.next_pair(Duration::from_secs(2)).unwrap();
        assert!(
            pair.skew() < half_interval,
            "pair {i}: skew {:?}",
            pair.skew()
        );
        assert_eq!(pair.left.dims(), (160, 120));
        assert_eq!(pair.right.dims(), (160, 120));
        if let Some(last) = last_pts {
            assert!(pair.left_pts > last, "pair {i} is not newer");
        }
        last_pts = Some(pair.left_pts);
    }
    let stats = capture.stats();
    println!(
        "300 pairs: max skew {:.3} ms, mean {:.3} ms, dropped {}/{}, skipped {}",
        stats.max_skew.as_secs_f64() * 1e3,
        stats.mean_skew().as_secs_f64() * 1e3,
        stats.dropped_left,
        stats.dropped_right,
        stats.skipped
    );
    assert!(stats.max_skew < half_interval, "{stats:?}");
    assert!(stats.paired >= 300);
}

#[test]
fn a_source_that_cannot_link_is_named() {
    // videotestsrc makes raw video, never JPEG.
    let err = open(
        &SourceSpec::description("videotestsrc ! image/jpeg"),
        &test_source(""),
    )
    .err()
    .expect("a description that cannot link");
    assert!(
        matches!(
            err,
            Error::Description {
                side: Side::Left,
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("image/jpeg"), "{err}");
}

#[test]
fn an_absent_device_is_named() {
    let err = open(
        &SourceSpec::v4l2("/dev/video99"),
        &SourceSpec::v4l2("/dev/video0"),
    )
    .err()
    .expect("/dev/video99 should not exist");
    assert_eq!(
        err,
        Error::NoDevice {
            side: Side::Left,
            device: "/dev/video99".into()
        }
    );
    assert!(
        err.to_string()
            .starts_with("left camera /dev/video99: no such device"),
        "{err}"
    );
}

#[test]
fn an_unparsable_description_is_named() {
    let err = open(
        &test_source(""),
        &SourceSpec::description("videotestsrc ! nosuchelement"),
    )
    .err()
    .expect("a bad description");
    assert!(
        matches!(
            err,
            Error::Description {
                side: Side::Right,
                ..
            }
        ),
        "{err}"
    );
    let text = err.to_string();
    assert!(
        text.starts_with("right source `videotestsrc ! nosuchelement`"),
        "{text}"
    );
    assert!(text.contains("nosuchelement"), "{text}");
}

#[test]
fn a_source_that_ends_mid_stream_is_named() {
    let mut capture = open(&test_source(""), &test_source("num-buffers=10")).unwrap();
    let start = Instant::now();
    let mut pairs = 0;
    let err = loop {
        match capture.next_pair(Duration::from_secs(2)) {
            Ok(_) => pairs += 1,
            Err(e) => break e,
        }
        assert!(pairs <= 10, "more pairs than the right source has frames");
    };
    assert!(pairs >= 1, "no pair before the end");
    assert!(start.elapsed() < Duration::from_secs(10));
    let Error::Stopped { side, reason, .. } = &err else {
        panic!("{err}");
    };
    assert_eq!((*side, reason), (Side::Right, &StopReason::EndOfStream));
    assert!(
        err.to_string().starts_with("right camera `videotestsrc"),
        "{err}"
    );
}

#[test]
fn a_source_that_falls_silent_is_named_after_the_timeout() {
    // A frame every 10 s: the first pairs, then the left camera is silent.
    let slow = SourceSpec::description(
        "videotestsrc is-live=true ! video/x-raw,width=160,height=120,framerate=1/10",
    );
    let mut capture = open(&slow, &test_source("")).unwrap();
    capture.next_pair(Duration::from_secs(2)).unwrap();
    let start = Instant::now();
    let err = capture.next_pair(Duration::from_secs(1)).unwrap_err();
    assert!(start.elapsed() >= Duration::from_secs(1));
    assert!(start.elapsed() < Duration::from_secs(5));
    assert!(
        matches!(&err, Error::Stopped { side: Side::Left, reason: StopReason::NoFrame(d), .. } if *d >= Duration::from_secs(1)),
        "{err}"
    );
    assert!(
        err.to_string().contains("stopped: no frame for 1."),
        "{err}"
    );
}

#[test]
fn caps_a_source_cannot_deliver_are_named() {
    // The PNG's size shows only once it is decoded, as a camera's modes do
    // only once it is opened: 80 pixels wide, asked for 160.
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("small.png");
    stereolink_image::io::write_rgb(&png, &stereolink_image::RgbImage::new(80, 60, [9, 9, 9]))
        .unwrap();
    let desc = format!(
        "filesrc location={} ! pngdec ! video/x-raw,width=160",
        png.display()
    );
    let jpeg = SourceSpec::description(desc.as_str());
    let start = Instant::now();
    let err = match open(&jpeg, &test_source("")) {
        Err(e) => e,
        Ok(mut capture) => capture.next_pair(Duration::from_secs(2)).unwrap_err(),
    };
    assert!(start.elapsed() < Duration::from_secs(10));
    assert!(
        matches!(
            err,
            Error::Caps {
                side: Side::Left,
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string()
            .starts_with(&format!("left camera `{desc}` cannot deliver")),
        "{err}"
    );
}

#[test]
fn views_of_different_sizes_are_an_error() {
    let small = SourceSpec::description(
        "videotestsrc is-live=true ! video/x-raw,width=80,height=60,framerate=30/1",
    );
    let mut capture = open(&test_source(""), &small).unwrap();
    let err = capture.next_pair(Duration::from_secs(2)).unwrap_err();
    assert_eq!(
        err,
        Error::SizeMismatch {
            left: (160, 120),
            right: (80, 60)
        }
    );
}

/// Odd widths: RGB rows are padded to 4 bytes in GStreamer; the images
/// must not be.
#[test]
fn padded_rows_are_copied_right() {
    let odd = |pattern: &str| {
        SourceSpec::description(format!(
            "videotestsrc is-live=true pattern={pattern} ! video/x-raw,width=75,height=9,framerate=30/1"
        ))
    };
    let mut capture = open(&odd("red"), &odd("blue")).unwrap();
    let pair = capture.next_pair(Duration::from_secs(2)).unwrap();
    assert_eq!(pair.left.dims(), (75, 9));
    assert!(
        pair.left.as_slice().iter().all(|&p| p == [255, 0, 0]),
        "{:?}",
        &pair.left.as_slice()[70..80]
    );
    assert!(pair.right.as_slice().iter().all(|&p| p == [0, 0, 255]));
}
