//! The board's cost of a lossy 320x240 pair: the Middlebury Cones pair,
//! scaled to 320x240 and coded into 8000 bytes by
//!
//! ```sh
//! stereolink encode left.png right.png -o examples/lossy/cones-320x240-CODEC.slnk \
//!     --view-coding CODEC --bytes 8000 --stereo-prediction off
//! ```
//!
//! decoded `FRAMES` times (argument 1, default 1) with codec `jpeg` or
//! `webp` (argument 2, default jpeg): parsed and both views decoded into the
//! buffers a receiver keeps (`decode`, the default for argument 3), or
//! handled whole by the board's receiver (`receive`: decode, WTA-match with
//! 32 disparities, render the screen). `tools/arm926/board count-lossy`
//! counts its ARM926 instructions per pair under qemu.
//!
//! `webp-stereo` is the WebP pair with its right view stereo-predicted
//! (`stereolink_codec::stereo`; `encode ... --view-coding webp --bytes
//! 8000`, stereo prediction on): its receiver shows the disparities the
//! frame carries instead of matching.
//!
//! `webp-still` and `webp-moving` are predicted pairs
//! (`stereolink_codec::temporal`): the same pair with fresh sensor noise
//! (σ = 2), and with a red rectangle of 80x60 px added, coded by
//! `stereolink encode DIR -o OUT --view-coding webp --bytes 8000` after the
//! WebP key pair `cones-320x240-webp-key.slnk` (of the same pair with other
//! noise), which is decoded once first; each predicted pair is then
//! decoded and kept as a reference, as the receiver does.
//!
//! `webp-pan` is a pair predicted by motion (`stereolink_codec::motion`):
//! the Cones pair scaled to 270 px high, a 320x240 window at (2, 1) px
//! after its key pair `cones-320x240-webp-pan-key.slnk` at (0, 0), each
//! with sensor noise (σ = 2), the two coded by `stereolink encode DIR -o
//! OUT --view-coding webp --bytes 8000`.

use std::time::Duration;

use stereolink_codec::container::{self, Body, FrameDecoder};
use stereolink_codec::temporal::{RefId, References};
use stereolink_codec::Limits;
use stereolink_pipeline::receiver::{BoardReceiver, Event};

const JPEG: &[u8] = include_bytes!("lossy/cones-320x240-jpeg.slnk");
const WEBP: &[u8] = include_bytes!("lossy/cones-320x240-webp.slnk");
const STEREO: &[u8] = include_bytes!("lossy/cones-320x240-webp-stereo.slnk");
const KEY: &[u8] = include_bytes!("lossy/cones-320x240-webp-key.slnk");
const STILL: &[u8] = include_bytes!("lossy/cones-320x240-webp-still.slnk");
const MOVING: &[u8] = include_bytes!("lossy/cones-320x240-webp-moving.slnk");
const PAN_KEY: &[u8] = include_bytes!("lossy/cones-320x240-webp-pan-key.slnk");
const PAN: &[u8] = include_bytes!("lossy/cones-320x240-webp-pan.slnk");

/// Parses and decodes a frame with `refs`, and keeps it there.
fn decode(bytes: &[u8], decoder: &mut FrameDecoder, refs: &mut References) {
    let Ok((header, Body::StereoFrame(frame))) = container::parse(bytes, &Limits::default()) else {
        panic!("not a stereo frame")
    };
    decoder.decode_with(&frame, refs).expect("the pair decodes");
    decoder.expand_views();
    let id = RefId {
        frame_id: header.frame_id,
        timestamp_us: header.timestamp_us,
    };
    refs.keep(id, decoder.views());
}

fn main() {
    let arg = |i| std::env::args().nth(i);
    let frames: u32 = arg(1).and_then(|a| a.parse().ok()).unwrap_or(1);
    let (bytes, key) = match arg(2).as_deref() {
        None | Some("jpeg") => (JPEG, None),
        Some("webp") => (WEBP, None),
        Some("webp-stereo") => (STEREO, None),
        Some("webp-still") => (STILL, Some(KEY)),
        Some("webp-moving") => (MOVING, Some(KEY)),
        Some("webp-pan") => (PAN, Some(PAN_KEY)),
        Some(other) => {
            panic!("codec {other:?}: jpeg, webp, webp-stereo, webp-still, webp-moving or webp-pan")
        }
    };
    let receive = arg(3).as_deref() == Some("receive");
    let mut decoder = FrameDecoder::default();
    let mut refs = References::default();
    let mut board = BoardReceiver::new(31, 9, Duration::from_secs(10));
    if let Some(key) = key {
        if receive {
            assert!(matches!(board.handle(key), Event::Frame { .. }));
        } else {
            decode(key, &mut decoder, &mut refs);
        }
    }
    for _ in 0..frames {
        if receive {
            match board.handle(bytes) {
                Event::Frame { .. } => {}
                other => panic!("unexpected {other:?}"),
            }
        } else if key.is_some() {
            decode(bytes, &mut decoder, &mut refs);
        } else {
            let Ok((_, Body::StereoFrame(frame))) = container::parse(bytes, &Limits::default())
            else {
                panic!("not a stereo frame")
            };
            decoder.decode_rgb(&frame).expect("the pair decodes");
        }
    }
    let (l, _) = decoder.views();
    println!(
        "{frames} pairs of {} bytes {} ({}x{})",
        bytes.len(),
        if receive { "received" } else { "decoded" },
        l.width(),
        l.height()
    );
}
