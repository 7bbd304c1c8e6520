//! Unit and property tests of the ARQ: the segment format, and a sender
//! and receiver driven against each other through loss, restarts, damaged
//! marks and interleaved sessions. Its own file because the tests are as
//! long as the machines.

use super::wire::DATA;
use super::*;
use crate::crc::crc16;

const TX: SessionId = SessionId(0x55_0001);
const RX: SessionId = SessionId(0x55_0002);

fn cfg() -> Config {
    Config {
        initial_rto: 1_000,
        min_rto: 1_000,
        ..Config::for_mtu(40)
    }
}

/// Runs a started sender against `r` from `now` until it finishes,
/// losing the `n`th segment where `drop(n)` and calling `after_ack`
/// after each ACK; returns what `r` delivered.
fn drive(
    s: &mut Sender,
    r: &mut Receiver,
    now: &mut Micros,
    drop: impl Fn(usize) -> bool,
    mut after_ack: impl FnMut(&mut Sender),
) -> Vec<Vec<u8>> {
    let mut n = 0;
    let mut got = Vec::new();
    while s.state() == SendState::Sending {
        while let Some(seg) = s.poll_transmit(*now) {
            n += 1;
            if drop(n) {
                continue;
            }
            let (ack, d) = r.on_segment(&Segment::parse(&seg).unwrap(), *now);
            if let Some(Ok(m)) = d {
                got.push(m);
            }
            if let Some(a) = ack {
                s.on_segment(&Segment::parse(&a).unwrap(), *now + 10);
                after_ack(s);
            }
        }
        *now = s.poll_at().unwrap_or(*now + 1).max(*now + 1);
    }
    got
}

fn transfer(msg: &[u8], drop: impl Fn(usize) -> bool) -> (Vec<u8>, SendCounters) {
    let (mut s, mut r) = (Sender::new(cfg(), TX), Receiver::new(cfg(), RX));
    s.start(msg, 0).unwrap();
    let got = drive(&mut s, &mut r, &mut 0, drop, |_| {});
    assert_eq!(s.state(), SendState::Done);
    assert_eq!(got.len(), 1);
    (got.into_iter().next().unwrap(), s.counters())
}

fn message(seed: u32, len: usize) -> Vec<u8> {
    (0..len as u32).map(|i| (i * 7 + seed * 13) as u8).collect()
}

#[test]
fn the_duplicate_rate_is_copies_over_the_data_segments_received() {
    let mut r = Receiver::new(cfg(), RX);
    assert_eq!(r.duplicate_rate(), None);
    let data = |index| Segment::Data {
        session: TX,
        msg_id: 1,
        index,
        last: false,
        fragment: &[1, 2, 3],
    };
    for (index, now) in [(0, 0), (0, 1), (1, 2), (0, 3)] {
        r.on_segment(&data(index), now);
    }
    assert_eq!((r.segments(), r.duplicates()), (4, 2));
    assert_eq!(r.duplicate_rate(), Some(0.5));
}

#[test]
fn restarted_senders_reusing_message_ids_are_all_delivered() {
    let mut r = Receiver::new(cfg(), RX);
    let mut now = 0;
    for life in 1..=3u32 {
        // Each sender process starts again from message id 1.
        let mut s = Sender::new(cfg(), SessionId(life));
        for k in 0..2 {
            let msg = message(life * 2 + k, 300);
            assert_eq!(s.start(&msg, now).unwrap(), k as u8 + 1);
            let got = drive(&mut s, &mut r, &mut now, |_| false, |_| {});
            assert_eq!(s.state(), SendState::Done);
            assert_eq!(got, [msg], "life {life}, message {k}");
        }
    }
    assert_eq!(r.duplicates(), 0);
}

#[test]
fn an_old_sessions_ack_never_acknowledges_a_new_message() {
    let mut s = Sender::new(cfg(), SessionId(2));
    s.start(&[9; 20], 0).unwrap();
    let first = s.poll_transmit(0).unwrap();
    assert!(matches!(
        Segment::parse(&first),
        Some(Segment::Data { last: true, .. })
    ));
    let ack = |session| Segment::Ack {
        session,
        receiver: RX,
        msg_id: 1,
        count: 1,
        next: 1,
        bitmap: 0,
    };
    // The previous process's final ACK of its own message 1.
    s.on_segment(&ack(SessionId(1)), 10);
    assert_eq!(s.state(), SendState::Sending);
    s.on_segment(&ack(SessionId(2)), 20);
    assert_eq!(s.state(), SendState::Done);
}

#[test]
fn a_receiver_restart_mid_message_gets_the_whole_message_once() {
    let msg = message(5, 1000);
    let mut s = Sender::new(cfg(), TX);
    let mut old = Receiver::new(cfg(), RX);
    s.start(&msg, 0).unwrap();
    let mut stale = None;
    for _ in 0..16 {
        let seg = s.poll_transmit(0).unwrap();
        if let (Some(a), None) = old.on_segment(&Segment::parse(&seg).unwrap(), 0) {
            s.on_segment(&Segment::parse(&a).unwrap(), 10);
            stale = Some(a);
        }
    }
    let stale = stale.expect("the old receiver acknowledged");
    assert!(matches!(
        Segment::parse(&stale),
        Some(Segment::Ack { next: 16, .. })
    ));
    // The old receiver is gone; a new one hears the rest. Its first ACK
    // is followed by a late one of the old receiver, which must not count.
    let mut new = Receiver::new(cfg(), SessionId(0xBEEF));
    let mut late = Some(stale);
    let mut now = 20;
    let got = drive(
        &mut s,
        &mut new,
        &mut now,
        |_| false,
        |s| {
            if let Some(a) = late.take() {
                s.on_segment(&Segment::parse(&a).unwrap(), 30);
            }
        },
    );
    assert!(late.is_none());
    assert_eq!(s.state(), SendState::Done);
    assert_eq!(got, [msg]);
}

#[test]
fn only_a_few_peer_sessions_are_remembered() {
    let cfg = cfg();
    let mut r = Receiver::new(cfg, RX);
    let mut now = 0;
    for life in 1..=10u32 {
        let mut s = Sender::new(cfg, SessionId(life));
        s.start(&message(life, 100), now).unwrap();
        assert_eq!(drive(&mut s, &mut r, &mut now, |_| false, |_| {}).len(), 1);
        // And a partial message left behind.
        s.start(&message(life, 100), now).unwrap();
        let seg = s.poll_transmit(now).unwrap();
        r.on_segment(&Segment::parse(&seg).unwrap(), now);
        assert!(r.peers.len() <= REMEMBERED_SESSIONS);
        assert!(r.pending.len() <= cfg.max_pending);
        let known = |s: &SessionId| r.peers.contains(s);
        assert!(r.pending.keys().all(|(s, _)| known(s)));
        assert!(r.recent.iter().all(|((s, _), _)| known(s)));
    }
    assert_eq!(r.peers.front(), Some(&SessionId(10)));
}

#[test]
fn earlier_versions_segments_are_dropped() {
    // A version 1 DATA segment (type 0x01, no session) and a version 2
    // one (type 0x21, 32-bit session, count), each with a valid CRC.
    let v1 = [0x01, 1, 0, 0, 0, 1, 0, 0xAA, 0xBB, 0xCC, 0xDD];
    let v2 = [0x21, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0xAA, 0xBB];
    for old in [&v1[..], &v2[..]] {
        let mut seg = old.to_vec();
        seg.extend_from_slice(&crc16(old).to_le_bytes());
        assert_eq!(Segment::parse(&seg), None);
    }
}

#[test]
fn a_data_header_is_seven_bytes_and_laid_out_as_documented() {
    let seg = Segment::Data {
        session: SessionId(0x12_3456),
        msg_id: 0x9A,
        index: 0x0102,
        last: true,
        fragment: b"xy",
    };
    assert_eq!(
        seg.emit(),
        [0x34, 0x56, 0x34, 0x12, 0x9A, 0x02, 0x01, b'x', b'y']
    );
    assert_eq!(DATA_OVERHEAD, 7);
    assert_eq!(SessionId::from_random(0xFFAB_CDEF), SessionId(0xAB_CDEF));
}

/// The last fragment's mark damaged past the transport's check: the
/// receiver holds every fragment but no count, so the sender does not
/// count the message delivered; it resends the last fragment, whose
/// count completes the message.
#[test]
fn a_message_counts_delivered_only_once_the_receiver_knows_its_count() {
    let msg = message(3, 200);
    let (mut s, mut r) = (Sender::new(cfg(), TX), Receiver::new(cfg(), RX));
    s.start(&msg, 0).unwrap();
    let segs: Vec<Vec<u8>> = core::iter::from_fn(|| s.poll_transmit(0)).collect();
    let (last, rest) = segs.split_last().unwrap();
    for seg in rest {
        r.on_segment(&Segment::parse(seg).unwrap(), 0);
    }
    let mut unmarked = last.clone();
    unmarked[0] = DATA;
    let mut now = 0;
    for seg in rest.iter().chain([&unmarked]) {
        let (ack, delivered) = r.on_segment(&Segment::parse(seg).unwrap(), now);
        assert_eq!(delivered, None);
        if let Some(a) = ack {
            s.on_segment(&Segment::parse(&a).unwrap(), now + 10);
        }
    }
    assert_eq!(s.state(), SendState::Sending);
    let got = drive(&mut s, &mut r, &mut now, |_| false, |_| {});
    assert_eq!(s.state(), SendState::Done);
    assert_eq!(got, [msg]);
}

#[test]
fn lossless_and_lossy_transfers_deliver_exactly() {
    let msg: Vec<u8> = (0..1000u32).map(|i| (i * 7) as u8).collect();
    let (got, c) = transfer(&msg, |_| false);
    assert_eq!(got, msg);
    assert_eq!(c.retransmissions, 0);
    let (got, c) = transfer(&msg, |n| n % 5 == 0);
    assert_eq!(got, msg);
    assert!(c.retransmissions > 0);
    let (got, _) = transfer(&[], |_| false);
    assert!(got.is_empty());
}

#[test]
fn segments_round_trip_and_damaged_control_segments_are_dropped() {
    let data = Segment::Data {
        session: TX,
        msg_id: 3,
        index: 1,
        last: false,
        fragment: b"abc",
    };
    assert_eq!(Segment::parse(&data.emit()), Some(data));
    let ack = Segment::Ack {
        session: TX,
        receiver: RX,
        msg_id: 3,
        count: 9,
        next: 4,
        bitmap: 0x8000_0001,
    };
    let fail = Segment::Fail {
        session: TX,
        msg_id: 3,
    };
    for s in [ack, fail] {
        let b = s.emit();
        assert_eq!(Segment::parse(&b), Some(s));
        for i in 0..b.len() {
            let mut c = b.clone();
            c[i] ^= 0x04;
            assert_eq!(Segment::parse(&c), None);
        }
    }
}

#[test]
fn deadline_fails_explicitly_on_both_sides() {
    let cfg = Config {
        deadline: 5_000,
        ..Config::for_mtu(40)
    };
    let (mut s, mut r) = (Sender::new(cfg, TX), Receiver::new(cfg, RX));
    s.start(&[1; 100], 0).unwrap();
    let first = s.poll_transmit(0).unwrap();
    r.on_segment(&Segment::parse(&first).unwrap(), 0);
    let fail = s.poll_transmit(6_000).unwrap();
    assert_eq!(s.state(), SendState::Failed(ArqError::Deadline));
    let (_, d) = r.on_segment(&Segment::parse(&fail).unwrap(), 6_000);
    assert_eq!(d, Some(Err((1, ArqError::Aborted))));
}

proptest::proptest! {
    /// Any bytes, and any bytes with a forged valid CRC: parsing never
    /// panics, and what parses emits back to the same bytes.
    #[test]
    fn parse_is_total_and_canonical(body in proptest::collection::vec(proptest::num::u8::ANY, 0..120)) {
        let mut forged = body.clone();
        forged.extend_from_slice(&crc16(&body).to_le_bytes());
        for bytes in [&body, &forged] {
            if let Some(seg) = Segment::parse(bytes) {
                proptest::prop_assert_eq!(&seg.emit(), bytes);
            }
        }
    }

    /// The DATA fragments of several sessions' messages, with the same
    /// message ids, fed in any order with repeats and then once in order:
    /// every message is delivered exactly once and intact.
    #[test]
    fn interleaved_sessions_deliver_each_message_once(
        sessions in 1..=REMEMBERED_SESSIONS as u32,
        per_session in 1..=3usize,
        lens in proptest::collection::vec(0..300usize, 12),
        order in proptest::collection::vec(proptest::num::usize::ANY, 0..400),
    ) {
        let cfg = Config { window: usize::MAX, ..cfg() };
        let mut messages = Vec::new();
        let mut segments = Vec::new();
        for life in 0..sessions {
            let session = SessionId(0xA000 + life);
            let mut s = Sender::new(cfg, session);
            for k in 0..per_session {
                let mut msg = message(life * 3 + k as u32, lens[life as usize * 3 + k]);
                msg.extend_from_slice(&[life as u8, k as u8]); // each message unique
                let msg_id = s.start(&msg, 0).unwrap();
                let segs: Vec<Vec<u8>> = core::iter::from_fn(|| s.poll_transmit(0)).collect();
                let next = segs.len() as u16;
                s.on_segment(&Segment::Ack { session, receiver: RX, msg_id, count: next, next, bitmap: 0 }, 0);
                segments.extend(segs);
                messages.push(msg);
            }
        }
        let mut r = Receiver::new(cfg, RX);
        let mut delivered = vec![0usize; messages.len()];
        let feed = order.iter().map(|&i| i % segments.len()).chain(0..segments.len());
        for (t, i) in feed.enumerate() {
            if let (_, Some(Ok(m))) = r.on_segment(&Segment::parse(&segments[i]).unwrap(), t as u64) {
                let which = messages.iter().position(|x| *x == m);
                proptest::prop_assert!(which.is_some(), "a message nobody sent");
                delivered[which.unwrap()] += 1;
            }
        }
        proptest::prop_assert!(delivered.iter().all(|&n| n == 1), "{:?}", delivered);
    }
}
