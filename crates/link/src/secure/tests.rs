//! The secure channel against every tampering the issue lists, in memory:
//! two channels with real keys, messages passed by hand.

use proptest::prelude::*;

use super::*;
use crate::arq::SessionId;

fn keypair(seed: u8) -> ([u8; 32], [u8; 32]) {
    let private = [seed; 32];
    (private, public_key(&private))
}

/// A paired initiator and responder, and a stranger with its own key.
fn devices() -> (Keys, Keys, Keys) {
    let ((a, a_pub), (b, b_pub), (m, _)) = (keypair(1), keypair(2), keypair(3));
    (
        Keys::new(a, b_pub),
        Keys::new(b, a_pub),
        Keys::new(m, b_pub),
    )
}

const A: SessionId = SessionId(0xA1);
const B: SessionId = SessionId(0xB2);

/// Runs a handshake from session `a` to session `b`.
fn connect(init: &mut Channel, resp: &mut Channel, a: SessionId, b: SessionId, now: u64) {
    let msg1 = init.initiate(a).unwrap();
    assert_eq!(msg1.len(), wire::INIT_LEN);
    let Opened::Reply(msg2) = resp.open(a, b, &msg1, now) else {
        panic!("no response")
    };
    assert_eq!(msg2.len(), wire::RESPONSE_LEN);
    assert_eq!(init.open(b, a, &msg2, now), Opened::Established);
    assert_eq!(init.established(), Some((a, b)));
}

fn pair() -> (Channel, Channel) {
    let (a, b, _) = devices();
    let (mut i, mut r) = (
        Channel::new(a, SecureConfig::default()),
        Channel::new(b, SecureConfig::default()),
    );
    connect(&mut i, &mut r, A, B, 0);
    (i, r)
}

#[test]
fn messages_cost_24_bytes_and_arrive_once() {
    let (mut i, mut r) = pair();
    let sealed = i.seal(b"depth report").unwrap();
    assert_eq!(sealed.len(), 12 + wire::OVERHEAD);
    assert_eq!(
        r.open(A, B, &sealed, 1),
        Opened::Message(b"depth report".to_vec())
    );
    assert_eq!(
        r.open(A, B, &sealed, 2),
        Opened::Rejected(Rejection::Replay)
    );
    // The responder's session is now confirmed: it can answer.
    let back = r.seal(b"ok").unwrap();
    assert_eq!(i.open(B, A, &back, 3), Opened::Message(b"ok".to_vec()));
    assert_eq!(r.rejections().replay, 1);
}

#[test]
fn frames_beyond_the_noise_message_limit_are_sealed() {
    let (mut i, mut r) = pair();
    let frame: Vec<u8> = (0..100_000u32).map(|j| (j * 7) as u8).collect();
    let sealed = i.seal(&frame).unwrap();
    assert_eq!(r.open(A, B, &sealed, 1), Opened::Message(frame));
}

#[test]
fn reordered_messages_are_taken_once_each() {
    let (mut i, mut r) = pair();
    let m: Vec<Vec<u8>> = (0..4u8).map(|k| i.seal(&[k; 5]).unwrap()).collect();
    for k in [2, 0, 3, 1] {
        assert_eq!(r.open(A, B, &m[k], 1), Opened::Message(vec![k as u8; 5]));
    }
    for k in [3, 1] {
        assert_eq!(r.open(A, B, &m[k], 1), Opened::Rejected(Rejection::Replay));
    }
}

#[test]
fn truncation_flips_and_wrong_sessions_are_refused() {
    let (mut i, mut r) = pair();
    let sealed = i.seal(&[9; 40]).unwrap();
    for cut in 0..sealed.len() {
        let why = r.open(A, B, &sealed[..cut], 1);
        assert!(matches!(why, Opened::Rejected(_)), "cut {cut}: {why:?}");
    }
    for bit in 0..sealed.len() * 8 {
        let mut bad = sealed.clone();
        bad[bit / 8] ^= 1 << (bit % 8);
        assert!(
            matches!(r.open(A, B, &bad, 1), Opened::Rejected(_)),
            "bit {bit}"
        );
    }
    assert_eq!(
        r.open(SessionId(0xA2), B, &sealed, 1),
        Opened::Rejected(Rejection::UnknownSession)
    );
    assert_eq!(r.open(A, B, &sealed, 1), Opened::Message(vec![9; 40]));
}

#[test]
fn a_stranger_with_another_key_gets_no_answer() {
    let (_, b, stranger) = devices();
    let mut r = Channel::new(b, SecureConfig::default());
    let mut m = Channel::new(stranger, SecureConfig::default());
    let init = m.initiate(A).unwrap();
    assert_eq!(
        r.open(A, B, &init, 0),
        Opened::Rejected(Rejection::Handshake)
    );
    // Plaintext dressed as a transport message.
    let mut fake = 0u64.to_le_bytes().to_vec();
    fake.extend_from_slice(&[0; 40]);
    assert_eq!(
        r.open(A, B, &fake, 0),
        Opened::Rejected(Rejection::UnknownSession)
    );
    assert_eq!(r.rejections().total(), 2);
}

#[test]
fn a_replayed_init_never_replaces_the_working_session() {
    let (a, b, _) = devices();
    let (mut i, mut r) = (
        Channel::new(a, SecureConfig::default()),
        Channel::new(b, SecureConfig::default()),
    );
    let init = i.initiate(A).unwrap();
    let Opened::Reply(resp) = r.open(A, B, &init, 0) else {
        panic!()
    };
    i.open(B, A, &resp, 0);
    let m1 = i.seal(b"one").unwrap();
    assert_eq!(r.open(A, B, &m1, 1), Opened::Message(b"one".to_vec()));
    // The same INIT again, from its own session or from another one.
    assert_eq!(
        r.open(A, B, &init, 2),
        Opened::Rejected(Rejection::Handshake)
    );
    assert_eq!(
        r.open(SessionId(7), B, &init, 2),
        Opened::Rejected(Rejection::Handshake)
    );
    assert_eq!(
        r.open(A, B, &i.seal(b"two").unwrap(), 3),
        Opened::Message(b"two".to_vec())
    );
}

#[test]
fn after_a_rekey_the_old_session_is_refused() {
    let (mut i, mut r) = pair();
    let old = i.seal(b"old").unwrap();
    let cfg = SecureConfig::default();
    assert!(!i.needs_handshake(cfg.rekey_after - 1));
    assert!(i.needs_handshake(cfg.rekey_after));
    let a2 = SessionId(0xA3);
    connect(&mut i, &mut r, a2, B, cfg.rekey_after);
    let new = i.seal(b"new").unwrap();
    assert_eq!(
        r.open(a2, B, &new, cfg.rekey_after),
        Opened::Message(b"new".to_vec())
    );
    assert_eq!(
        r.open(A, B, &old, cfg.rekey_after),
        Opened::Rejected(Rejection::UnknownSession)
    );
}

#[test]
fn sessions_expire_and_handshake_floods_are_bounded() {
    let (mut i, mut r) = pair();
    let cfg = SecureConfig::default();
    let late = i.seal(b"late").unwrap();
    assert_eq!(
        r.open(A, B, &late, cfg.reject_after),
        Opened::Rejected(Rejection::UnknownSession)
    );
    // Genuine INITs from fresh sessions: a burst is answered, then one per interval.
    let (a, b, _) = devices();
    let mut r = Channel::new(b, cfg);
    let mut i = Channel::new(a, cfg);
    let mut answered = 0;
    for k in 0..20u32 {
        let init = i.initiate(SessionId(100 + k)).unwrap();
        if matches!(r.open(SessionId(100 + k), B, &init, 1000), Opened::Reply(_)) {
            answered += 1;
        }
    }
    assert_eq!(answered, cfg.handshake_burst);
    assert!(r.pending_handshakes() <= cfg.max_pending);
    let init = i.initiate(SessionId(999)).unwrap();
    assert!(matches!(
        r.open(SessionId(999), B, &init, 1000 + cfg.handshake_interval),
        Opened::Reply(_)
    ));
}

#[test]
fn simultaneous_handshakes_settle_on_one() {
    let (a, b, _) = devices();
    let (mut x, mut y) = (
        Channel::new(a, SecureConfig::default()),
        Channel::new(b, SecureConfig::default()),
    );
    let (ix, iy) = (x.initiate(A).unwrap(), y.initiate(B).unwrap());
    let (ox, oy) = (x.open(B, A, &iy, 0), y.open(A, B, &ix, 0));
    // Exactly one side answers; its answer completes the other's handshake.
    let reply = match (ox, oy) {
        (Opened::Reply(r), Opened::Rejected(_)) => y.open(A, B, &r, 0),
        (Opened::Rejected(_), Opened::Reply(r)) => x.open(B, A, &r, 0),
        other => panic!("{other:?}"),
    };
    assert_eq!(reply, Opened::Established);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Random tampering: any change to a sealed message (flips, cuts,
    /// insertions, overwrites) is refused, and the untouched message is
    /// still taken afterwards.
    #[test]
    fn random_tampering_is_always_refused(
        body in proptest::collection::vec(any::<u8>(), 0..300),
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 1..6),
    ) {
        let (mut i, mut r) = pair();
        let sealed = i.seal(&body).unwrap();
        let mut bad = sealed.clone();
        for (at, byte, op) in edits {
            let at = at as usize % (bad.len() + 1);
            match op {
                0 if at < bad.len() => bad[at] ^= byte.max(1),
                1 => bad.insert(at, byte),
                _ => bad.truncate(at),
            }
        }
        prop_assume!(bad != sealed);
        prop_assert!(matches!(r.open(A, B, &bad, 1), Opened::Rejected(_)));
        prop_assert_eq!(r.open(A, B, &sealed, 1), Opened::Message(body));
    }

    /// Arbitrary bytes from any session never open and never panic.
    #[test]
    fn arbitrary_bytes_are_refused(bytes in proptest::collection::vec(any::<u8>(), 0..200), from in any::<u32>()) {
        let (_, mut r) = pair();
        prop_assert!(matches!(r.open(SessionId(from), B, &bytes, 1), Opened::Rejected(_)));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// The fuzz target's harness on random inputs, in the normal test
    /// suite (cargo-fuzz is not installed in CI).
    #[test]
    fn fuzz_harness_on_random_inputs(data in proptest::collection::vec(any::<u8>(), 0..600)) {
        fuzz::drive(&data);
    }
}
