//! The receiver's plane table path: a stereo frame whose left labels decode
//! and which carries a plane table ([`stereolink_codec::planetable`]) has
//! the table resolved against the labels' segments, and every pixel's plane
//! evaluated, as `pipeline::planetable::rebuild_coded_into` does. No panic;
//! a table that does not belong to the labels is an error.
//!
//! Seeds: frames sent with `--disparity planes` (`fuzz/seeds/plane_table`,
//! made by `tools/fuzz/seeds`).
#![no_main]

use std::cell::RefCell;

use libfuzzer_sys::fuzz_target;
use stereolink_codec::container::{self, Body, FrameDecoder};
use stereolink_codec::Limits;
use stereolink_image::segments::components;

thread_local! {
    static DECODER: RefCell<FrameDecoder> = RefCell::default();
}

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_body: 1 << 20, max_pixels: 1 << 16, ..Limits::default() };
    let Ok((_, Body::StereoFrame(frame))) = container::parse(data, &limits) else {
        return;
    };
    let Some(coded) = frame.planes.as_deref() else {
        return;
    };
    DECODER.with(|d| {
        let mut d = d.borrow_mut();
        if d.decode(&frame).is_err() {
            return;
        }
        let Some(labels) = d.left_labels(&frame) else {
            return;
        };
        let (ids, segments) = components(labels, coded.tile() as usize);
        if let Ok(table) = coded.resolve(&ids, segments) {
            let w = ids.width();
            for (p, &s) in ids.as_slice().iter().enumerate() {
                let _ = table.disparity(s as usize, p % w, p / w);
            }
        }
    });
});
