//! The board's receiver keeps fixed buffers: once it has shown a frame of a
//! size, decoding, matching and rendering the next ones allocates nothing,
//! and its heap peaks below the board's 16 MiB budget; a still lossy pair
//! predicted by motion (what a fixed rig sends) allocates nothing either.
//! Counted by a global allocator, in a test binary of its own so that no
//! other test allocates meanwhile (tools/arm926/board runs it on the ARM926
//! too, but for the lossy pairs, which need the sender's encoders).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use stereolink_image::synth::SynthSpec;
#[cfg(not(target_arch = "arm"))]
use stereolink_image::RgbImage;
use stereolink_pipeline::receiver::{synthetic_frame, BoardReceiver, Event};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
/// Bytes allocated and not freed, and their peak.
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(bytes: usize) {
    let live = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    PEAK.fetch_max(live, Ordering::Relaxed);
}

// SAFETY: forwards to the system allocator, only counting.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        grew(layout.size());
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
        grew(new_size);
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

#[test]
fn frames_after_the_first_allocate_nothing() {
    let bytes = synthetic_frame(&SynthSpec {
        width: 480,
        height: 272,
        max_disp: 32,
        seed: 4,
    })
    .unwrap();
    // The receiver's own peak: from what the sender's side left live.
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let mut board = BoardReceiver::new(31, 9, Duration::from_secs(10));
    let shown = |e: Event| matches!(e, Event::Frame { .. });
    let start = ALLOCATIONS.load(Ordering::Relaxed);
    assert!(shown(board.handle(&bytes)), "the first frame is shown");
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    // The counter counts: the first frame sizes the buffers.
    assert!(before > start);
    for _ in 0..3 {
        assert!(shown(board.handle(&bytes)));
    }
    let after = ALLOCATIONS.load(Ordering::Relaxed);
    assert_eq!(
        after - before,
        0,
        "allocations in three frames after the first"
    );
    let peak = PEAK.load(Ordering::Relaxed) - base;
    eprintln!(
        "receiver peak heap: {:.2} MiB",
        peak as f64 / (1 << 20) as f64
    );
    assert!(peak <= 16 << 20, "peak heap {peak} bytes");
    // And the frame shown is the one sent.
    let (left, _) = board.pair().unwrap();
    assert_eq!(left.dims(), (480, 272));
    #[cfg(not(target_arch = "arm"))]
    {
        let [key, still] = still_stream();
        let mut board = BoardReceiver::new(31, 9, Duration::from_secs(10));
        assert!(shown(board.handle(&key)) && shown(board.handle(&still)));
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        for _ in 0..3 {
            assert!(shown(board.handle(&still)));
        }
        let after = ALLOCATIONS.load(Ordering::Relaxed);
        assert_eq!(after - before, 0, "allocations in three still pairs");
    }
}

/// A lossy key pair (WebP) and a pair predicted from it by motion with
/// every block still: what a fixed rig sends.
#[cfg(not(target_arch = "arm"))]
fn still_stream() -> [Vec<u8>; 2] {
    use stereolink_codec::lossy::LossyCodec;
    use stereolink_codec::motion::{MotionPlan, MotionSpec, MotionView};
    use stereolink_codec::temporal::{blocks, RefId};
    use stereolink_codec::{container, Message, View};
    use stereolink_pipeline::coding::{lossy_frame, lossy_views};
    let scene = stereolink_image::synth::synthesize(&SynthSpec {
        width: 320,
        height: 240,
        max_disp: 24,
        seed: 4,
    })
    .unwrap();
    let webp = LossyCodec::Webp;
    let views = lossy_views((&scene.left, &scene.right), webp, 40, false).unwrap();
    let sent = [views.0.to_rgb(), views.1.to_rgb()];
    let frame = |views, id| {
        let f = lossy_frame(webp, 40, views, None);
        container::encode(&Message::StereoFrame(Box::new(f)), id, u64::from(id))
    };
    let (cols, rows) = blocks((320, 240));
    let id = RefId {
        frame_id: 1,
        timestamp_us: 1,
    };
    let still = |v: &RgbImage| {
        let plan = MotionPlan::new(v, (v, v), &vec![true; cols * rows], &MotionSpec::default());
        View::Motion(MotionView::encode(v, (id, &plan), webp, 40).unwrap())
    };
    [
        frame(views, 1),
        frame((still(&sent[0]), still(&sent[1])), 2),
    ]
}
