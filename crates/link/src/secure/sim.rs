//! The secure layer over the simulated 802.15.4 link, in simulated time:
//! the handshake (INIT one way, RESPONSE back, each one ARQ message) and a
//! sealed message, with real keys and real ciphertext, so the cost of the
//! layer on the radio can be measured beside the unsealed transfer.

use super::{public_key, Channel, Keys, Opened, SecureConfig};
use crate::arq::{Config, SessionId};
use crate::sim::{transfer, SimConfig, TransferReport};

/// What a handshake and one sealed message took.
#[derive(Clone, Debug, PartialEq)]
pub struct SealedReport {
    /// Simulated time from the INIT sent to the RESPONSE delivered, s.
    pub handshake_seconds: f64,
    /// The handshake completed (both messages delivered and accepted).
    pub handshake_done: bool,
    /// The sealed message's transfer; its goodput counts plaintext bytes.
    pub message: TransferReport,
    /// The delivered ciphertext opened to the plaintext.
    pub opened: bool,
}

/// Runs a handshake and sends `message` sealed; the seeds of the three
/// transfers derive from `sim.seed`. Keys are fixed: the figures depend on
/// sizes, not on key values.
pub fn sealed_transfer(sim: SimConfig, arq: Config, message: &[u8]) -> SealedReport {
    let (a, b) = ([0x11; 32], [0x22; 32]);
    let cfg = SecureConfig::default();
    let mut init = Channel::new(Keys::new(a, public_key(&b)), cfg);
    let mut resp = Channel::new(Keys::new(b, public_key(&a)), cfg);
    let (ia, rb) = (SessionId(1), SessionId(2));
    let seeded = |k: u64| SimConfig {
        seed: sim.seed.wrapping_mul(3).wrapping_add(k),
        ..sim
    };
    let msg1 = init.initiate(ia).unwrap_or_default();
    let t1 = transfer(seeded(0), arq, &msg1);
    let Opened::Reply(msg2) = resp.open(ia, rb, &msg1, 0) else {
        return failed(t1);
    };
    let t2 = transfer(seeded(1), arq, &msg2);
    let done = t1.delivered && t2.delivered && init.open(rb, ia, &msg2, 0) == Opened::Established;
    let Ok(sealed) = init.seal(message) else {
        return failed(t2);
    };
    let mut m = transfer(seeded(2), arq, &sealed);
    m.goodput_bps = if m.delivered {
        message.len() as f64 * 8.0 / m.seconds.max(1e-9)
    } else {
        0.0
    };
    SealedReport {
        handshake_seconds: t1.seconds + t2.seconds,
        handshake_done: done,
        opened: resp.open(ia, rb, &sealed, 0) == Opened::Message(message.to_vec()),
        message: m,
    }
}

fn failed(t: TransferReport) -> SealedReport {
    SealedReport {
        handshake_seconds: t.seconds,
        handshake_done: false,
        message: t,
        opened: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_handshake_and_a_sealed_frame_cross_the_simulated_link() {
        let msg: Vec<u8> = (0..5000u32).map(|i| i as u8).collect();
        let r = sealed_transfer(SimConfig::default(), Config::for_mtu(100), &msg);
        assert!(r.handshake_done && r.message.delivered && r.opened, "{r:?}");
        // Two one-fragment messages and their ACKs at 115200 baud.
        assert!(
            r.handshake_seconds > 0.02 && r.handshake_seconds < 0.15,
            "{r:?}"
        );
    }
}
