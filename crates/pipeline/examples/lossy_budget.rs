//! The board's cost of a lossy 320x240 pair: the Middlebury Cones pair,
//! scaled to 320x240 and coded into 8000 bytes by
//!
//! ```sh
//! stereolink encode left.png right.png -o examples/lossy/cones-320x240-CODEC.slnk \
//!     --view-coding CODEC --bytes 8000
//! ```
//!
//! decoded `FRAMES` times (argument 1, default 1) with codec `jpeg` or
//! `webp` (argument 2, default jpeg): parsed and both views decoded into the
//! buffers a receiver keeps (`decode`, the default for argument 3), or
//! handled whole by the board's receiver (`receive`: decode, WTA-match with
//! 32 disparities, render the screen). `tools/arm926/board count-lossy`
//! counts its ARM926 instructions per pair under qemu.

use std::time::Duration;

use stereolink_codec::container::{self, Body, FrameDecoder};
use stereolink_codec::Limits;
use stereolink_pipeline::receiver::{BoardReceiver, Event};

const JPEG: &[u8] = include_bytes!("lossy/cones-320x240-jpeg.slnk");
const WEBP: &[u8] = include_bytes!("lossy/cones-320x240-webp.slnk");

fn main() {
    let arg = |i| std::env::args().nth(i);
    let frames: u32 = arg(1).and_then(|a| a.parse().ok()).unwrap_or(1);
    let bytes = match arg(2).as_deref() {
        None | Some("jpeg") => JPEG,
        Some("webp") => WEBP,
        Some(other) => panic!("codec {other:?}: jpeg or webp"),
    };
    let receive = arg(3).as_deref() == Some("receive");
    let mut decoder = FrameDecoder::default();
    let mut board = BoardReceiver::new(31, 9, Duration::from_secs(10));
    for _ in 0..frames {
        if receive {
            match board.handle(bytes) {
                Event::Frame { .. } => {}
                other => panic!("unexpected {other:?}"),
            }
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
