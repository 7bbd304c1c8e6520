//! The board's path: one [`FrameDecoder`] kept across all inputs (as the
//! receiver keeps it from frame to frame) decodes every stereo frame that
//! parses. It never panics, and it agrees with the owned decoder: both fail,
//! or both give the same views, whatever frames it decoded before.
//!
//! Lossy views (JPEG, WebP bitstreams) are out of a blind fuzzer's reach;
//! seed it with the two lossy frames of the board's budget example:
//! `tools/fuzz/run-ci` does (`fuzz/seeds/frame_decoder`).
#![no_main]

use std::cell::RefCell;

use libfuzzer_sys::fuzz_target;
use stereolink_codec::container::{self, Body, FrameDecoder};
use stereolink_codec::{Limits, Message};

thread_local! {
    static DECODER: RefCell<FrameDecoder> = RefCell::new(FrameDecoder::default());
}

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_body: 1 << 20, max_pixels: 1 << 16, ..Limits::default() };
    let Ok((_, Body::StereoFrame(frame))) = container::parse(data, &limits) else {
        return;
    };
    let reused = DECODER.with(|d| {
        let mut d = d.borrow_mut();
        d.decode_rgb(&frame).map(|()| {
            let (l, r) = d.views();
            (l.clone(), r.clone())
        })
    });
    let owned = match container::decode(data, &limits) {
        Ok((_, Message::StereoFrame(f))) => Ok((f.left.to_rgb(), f.right.to_rgb())),
        Ok(_) => panic!("a stereo frame parsed as another message"),
        Err(e) => Err(e),
    };
    match (reused, owned) {
        (Ok(a), Ok(b)) => assert!(a == b, "the reused decoder's views differ"),
        (Err(_), Err(_)) => {}
        // The owned decoder also resolves the plane table, which the
        // receiver reads apart from the views (the `plane_table` target).
        (Ok(_), Err(_)) if frame.planes.is_some() => {}
        (a, b) => panic!("reused {:?} but owned {:?}", a.err(), b.err()),
    }
});
