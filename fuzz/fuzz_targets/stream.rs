//! The board's stream path: frames that may be predicted from earlier ones
//! ([`stereolink_codec::temporal`]), decoded in turn with the references the
//! receiver keeps. The input is a run of frames, each after its length
//! (u16, little-endian). No panic; a predicted frame whose reference is not
//! held is an error, never a picture; whatever decodes is kept as the next
//! frames' reference, as the receiver (`pipeline::receiver`) keeps it.
//!
//! Seeds: a key WebP pair followed by a still, a moving and a panned
//! pair predicted by motion ([`stereolink_codec::motion`]), and a
//! segmented key pair followed by predicted label maps (`fuzz/seeds/stream`,
//! made by the pipeline's `fuzz_seeds` example).
#![no_main]

use std::cell::RefCell;

use libfuzzer_sys::fuzz_target;
use stereolink_codec::container::{self, Body, FrameDecoder};
use stereolink_codec::temporal::{RefId, References};
use stereolink_codec::Limits;

thread_local! {
    static DECODER: RefCell<(FrameDecoder, References)> = RefCell::default();
}

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_body: 1 << 20, max_pixels: 1 << 17, ..Limits::default() };
    DECODER.with(|d| {
        let (decoder, refs) = &mut *d.borrow_mut();
        refs.clear();
        let mut rest = data;
        while let Some((len, tail)) = rest.split_first_chunk::<2>() {
            let len = usize::from(u16::from_le_bytes(*len)).min(tail.len());
            let (msg, tail) = tail.split_at(len);
            rest = tail;
            let Ok((h, Body::StereoFrame(frame))) = container::parse(msg, &limits) else {
                continue;
            };
            let held = frame.references().all(|r| refs.get(r).is_some() || refs.get_labels(r).is_some());
            let decoded = decoder.decode_with(&frame, refs);
            assert!(held || decoded.is_err(), "a frame decoded without its reference");
            if decoded.is_err() {
                continue;
            }
            let id = RefId { frame_id: h.frame_id, timestamp_us: h.timestamp_us };
            match decoder.indexed_views() {
                Some(views) => refs.keep_labels(id, views),
                None => {
                    decoder.expand_views();
                    refs.keep(id, decoder.views());
                }
            }
        }
    });
});
