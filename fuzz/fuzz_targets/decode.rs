//! Any byte string decodes to a message or a typed error, never a panic, and
//! a decoded message re-encodes to bytes that decode to the same message.
//! (Built with `cfg(fuzzing)`, the decoder skips the body CRC so that the
//! fuzzer reaches the body parsers.)
//!
//! Lossy views (JPEG, WebP bitstreams) are out of a blind fuzzer's reach;
//! seed it with the two lossy frames of the board's budget example:
//! `tools/fuzz/run-ci` does (`fuzz/seeds/decode` holds them).
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereolink_codec::{container, Limits};

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_body: 1 << 20, max_pixels: 1 << 16, ..Limits::default() };
    if let Ok((h, msg)) = container::decode(data, &limits) {
        let again = container::encode(&msg, h.frame_id, h.timestamp_us);
        let (_, back) = container::decode(&again, &Limits::default()).expect("re-encoded message decodes");
        // Compare bytes, not values: a NaN distance is not equal to itself.
        assert_eq!(container::encode(&back, h.frame_id, h.timestamp_us), again);
    }
});
