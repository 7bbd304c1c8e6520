//! The receiver, and a sender with a message in flight, fed arbitrary
//! segments (split from the input at 0xFF bytes, with forged control
//! segment CRCs made valid): no panic, and nothing is ever delivered unless it carries a
//! valid end-to-end CRC-32. The first byte of a chunk picks the session its
//! segment claims from a handful (the sender's own among them), so the
//! per-session state, session forgetting and receiver restarts are reached.
#![no_main]

use libfuzzer_sys::fuzz_target;
use stereolink_link::arq::{Config, Receiver, Segment, Sender, SessionId};
use stereolink_link::crc::{crc16, crc32};

fuzz_target!(|data: &[u8]| {
    let cfg = Config { max_message: 4096, ..Config::for_mtu(40) };
    let mut rx = Receiver::new(cfg, SessionId(7));
    let mut tx = Sender::new(cfg, SessionId(1));
    let _ = tx.start(&[0x5A; 300], 0);
    for (t, chunk) in data.split(|&b| b == 0xFF).enumerate() {
        let now = t as u64 * 1000;
        let Some((&pick, rest)) = chunk.split_first() else { continue };
        let mut seg = rest.to_vec();
        if seg.len() >= 4 {
            seg[1..4].copy_from_slice(&u32::from(pick % 6).to_le_bytes()[..3]);
        }
        let crc = crc16(&seg);
        seg.extend_from_slice(&crc.to_le_bytes());
        if let Some(s) = Segment::parse(&seg) {
            tx.on_segment(&s, now);
            if let (_, Some(Ok(msg))) = rx.on_segment(&s, now) {
                // A delivered message passed its CRC-32 by construction.
                assert!(msg.len() <= cfg.max_message);
                let _ = crc32(&msg);
            }
        }
        while tx.poll_transmit(now).is_some() {}
        let _ = rx.poll(now);
    }
});
