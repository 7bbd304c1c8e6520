//! The streaming XBee parser on arbitrary bytes, in both API modes: no
//! panic, and every frame it yields re-encodes to bytes it parses again.
//! The same bytes as frame data: whatever [`Frame::parse`] accepts re-emits
//! as a prefix of them that parses to the same frame.
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereolink_link::xbee::{ApiMode, Frame, Parser};

fuzz_target!(|data: &[u8]| {
    for mode in [ApiMode::Plain, ApiMode::Escaped] {
        let mut p = Parser::new(mode);
        for &b in data {
            if let Some(Ok(frame)) = p.push(b) {
                let mut q = Parser::new(mode);
                let again: Vec<_> = frame.encode(mode).into_iter().filter_map(|b| q.push(b)).collect();
                assert_eq!(again, vec![Ok(frame)]);
            }
        }
    }
    if let Ok(frame) = Frame::parse(data) {
        let emitted = frame.frame_data();
        assert!(data.starts_with(&emitted));
        assert_eq!(Frame::parse(&emitted), Ok(frame));
    }
});
