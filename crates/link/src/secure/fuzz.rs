//! The harness that both the cargo-fuzz target (`fuzz/fuzz_targets/
//! secure_open.rs`) and the test suite's property test drive: arbitrary
//! bytes fed to both ends of an established secure channel as messages of
//! a few sessions, some dressed as handshake messages or as changed copies
//! of real sealed ones. It panics if anything opens that the peer did not
//! seal, or if a sealed message opens twice.

use alloc::vec::Vec;

use super::wire::{HANDSHAKE_INIT, HANDSHAKE_RESPONSE};
use super::{public_key, Channel, Keys, Opened, SecureConfig};
use crate::arq::SessionId;

/// Feeds `data` (chunks split at 0xFF; a chunk's first byte picks what the
/// rest becomes and which session it claims) to an established pair.
pub fn drive(data: &[u8]) {
    let (a, b) = ([0x31; 32], [0x42; 32]);
    let cfg = SecureConfig::default();
    let mut tx = Channel::new(Keys::new(a, public_key(&b)), cfg);
    let mut rx = Channel::new(Keys::new(b, public_key(&a)), cfg);
    let (sa, sb) = (SessionId(1), SessionId(2));
    let init = tx.initiate(sa).expect("keys are valid");
    let Opened::Reply(resp) = rx.open(sa, sb, &init, 0) else {
        panic!("the genuine handshake failed")
    };
    assert_eq!(tx.open(sb, sa, &resp, 0), Opened::Established);
    let genuine: Vec<Vec<u8>> = (0..3u8)
        .map(|k| tx.seal(&[k; 40]).expect("established"))
        .collect();
    let mut opened = [false; 3];
    for (t, chunk) in data.split(|&b| b == 0xFF).enumerate() {
        let Some((&pick, rest)) = chunk.split_first() else {
            continue;
        };
        let from = [sa, sb, SessionId(3)][(pick % 3) as usize];
        let mut msg = rest.to_vec();
        match (pick / 3) % 5 {
            0 => {}
            1 => over_word(&mut msg, HANDSHAKE_INIT),
            2 => over_word(&mut msg, HANDSHAKE_RESPONSE),
            3 => msg = init.iter().chain(&resp).copied().take(rest.len()).collect(),
            _ => {
                // A genuine message, changed where `rest` says.
                let g = &genuine[rest.first().map_or(0, |&i| i as usize % 3)];
                let mut changed = g.clone();
                for pair in rest.get(1..).unwrap_or(&[]).chunks(2) {
                    if let [at, x] = *pair {
                        let i = at as usize % changed.len();
                        changed[i] ^= x;
                    }
                }
                msg = changed;
            }
        }
        let now = t as u64 * 1000;
        for (ch, local) in [(&mut rx, sb), (&mut tx, sa)] {
            if let Opened::Message(m) = ch.open(from, local, &msg, now) {
                let k = genuine
                    .iter()
                    .position(|g| *g == msg)
                    .expect("only a genuinely sealed message opens");
                assert!(from == sa && m == [k as u8; 40] && !opened[k]);
                opened[k] = true;
            }
        }
    }
}

fn over_word(msg: &mut Vec<u8>, word: u64) {
    msg.resize(msg.len().max(8), 0);
    msg[..8].copy_from_slice(&word.to_le_bytes());
}
