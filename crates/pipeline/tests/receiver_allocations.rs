//! The board's receiver keeps fixed buffers: once it has shown a frame of a
//! size, decoding, matching and rendering the next ones allocates nothing,
//! and its heap peaks below the board's 16 MiB budget. Counted by a global
//! allocator, in a test binary of its own so that no other test allocates
//! meanwhile (tools/arm926/board runs it on the ARM926 too).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use stereolink_image::synth::SynthSpec;
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
}
