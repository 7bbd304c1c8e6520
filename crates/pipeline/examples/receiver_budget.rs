//! The board's per-frame cost: decode a 480x272 StereoFrame, WTA-match it
//! with 32 disparities (one thread, as on the ARM9) and render the screen,
//! `FRAMES` times (argument 1, default 1; add `portable` as argument 2 to
//! match with the portable kernel, as a CPU without SIMD does). Run it under
//! callgrind twice, with 1 and with 11 frames, and divide the difference by
//! 10 to get the cost of one frame after the first:
//!
//! ```sh
//! cargo build --release --example receiver_budget
//! RAYON_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=/tmp/cg1 target/release/examples/receiver_budget 1
//! RAYON_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=/tmp/cg11 target/release/examples/receiver_budget 11
//! RAYON_NUM_THREADS=1 valgrind --tool=dhat target/release/examples/receiver_budget 11   # peak heap
//! ```

use std::time::Duration;

use stereolink_image::synth::SynthSpec;
use stereolink_pipeline::receiver::{synthetic_frame, BoardReceiver, Event};

fn main() {
    let frames: u32 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(1);
    let bytes = synthetic_frame(&SynthSpec {
        width: 480,
        height: 272,
        max_disp: 32,
        seed: 1,
    })
    .expect("a synthetic frame");
    let mut board = BoardReceiver::new(31, 9, Duration::from_secs(10));
    if std::env::args().nth(2).as_deref() == Some("portable") {
        board = board.portable_kernel();
    }
    for _ in 0..frames {
        match board.handle(&bytes) {
            Event::Frame { .. } => {}
            other => panic!("unexpected {other:?}"),
        }
    }
    println!(
        "{frames} frames of {} bytes decoded, matched and rendered",
        bytes.len()
    );
}
