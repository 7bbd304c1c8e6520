//! A bond: several radio pairs used as one link, for more air.
//!
//! One pair carries what its radio carries (35 kb/s on ZigBee); the paper's
//! future work: "the time taken for transmitting an image can be reduced by
//! implementing a mesh or star topologies using a set of ZIGBEE modules".
//! Each member transport runs in a thread of its own with its own pacing,
//! and a packet goes to the member with the fewest bytes queued. A two-byte
//! sequence number lets the far end hand packets up in the order sent, as
//! the ARQ above takes reordering for loss. A member that fails, or falls
//! silent while the others carry traffic, is dropped with a
//! [`Notice::MemberDown`], and the ARQ resends what it held (the bond
//! acknowledges nothing itself); with every member down the bond fails
//! naming them. Both ends bond the same number of pairs.

use std::collections::VecDeque;
use std::io;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::pacing::PacingCounters;
use crate::sim::{self, SimConfig};
use crate::transport::{no_data_yet, LinkStats, Notice, Transport};

/// Bytes the bond adds to each packet: its sequence number.
pub const HEADER: usize = 2;

/// Packets queued for one member beyond the one it is sending: enough that
/// a member never waits for the next packet, few enough that little is lost
/// with a member that dies.
const DEPTH: usize = 1;

/// How long an idle member waits for a packet to send before it looks for
/// one from its peer again.
const POLL: Duration = Duration::from_millis(1);

/// Packets received and not yet taken, across the members; beyond that
/// they are dropped, as a full socket buffer drops them.
const INBOX: usize = 1024;

/// The least time a member may stay silent before it is dropped.
const MIN_SILENCE: Duration = Duration::from_millis(500);

/// Packet times a member may stay silent before it is dropped.
const SILENT_PACKETS: u32 = 40;

/// Packets the others must carry, per member, while one is silent before
/// that one is dropped: silence alone is an idle link, not a dead one, and
/// the far end gives each live member its turn well within that many.
const OTHERS_PER_MEMBER: u64 = 4;

/// What a member's thread and the bond share about it.
#[derive(Default)]
struct Slot {
    queue: VecDeque<Vec<u8>>,
    /// Bytes queued or being sent.
    bytes: usize,
    /// Why the member is down, once it is.
    down: Option<String>,
    notices: Vec<Notice>,
    stats: LinkStats,
}

struct Shared {
    slots: Vec<Slot>,
}

/// The members' slots and the condition a change of them is signalled on.
type Handle = Arc<(Mutex<Shared>, Condvar)>;

/// A packet, the member that received it and when.
type Arrival = (usize, Vec<u8>, Instant);

fn lock(sync: &Handle) -> MutexGuard<'_, Shared> {
    sync.0.lock().unwrap_or_else(|p| p.into_inner())
}

/// What the bond knows of one member on its own side.
struct Member {
    name: String,
    mtu: usize,
    packet_time: Option<Duration>,
    /// When a packet last came from it, and the packets heard from all
    /// members by then.
    heard: (Instant, u64),
    /// When it was last given a packet (ties go to the least recent).
    used: u64,
    /// Its drop was said.
    said_down: bool,
}

/// Several transports used as one (see the module doc).
pub struct Bond {
    members: Vec<Member>,
    sync: Handle,
    inbox: Receiver<Arrival>,
    order: Reorder,
    next_seq: u16,
    sent: u64,
    heard_total: u64,
    silence: Duration,
    notices: Vec<Notice>,
}

impl Bond {
    /// Bonds `members`, each run by a thread of its own from now on.
    ///
    /// # Panics
    /// If `members` is empty.
    pub fn new(members: Vec<Box<dyn Transport>>) -> Self {
        assert!(!members.is_empty(), "a bond needs at least one member");
        let now = Instant::now();
        let info: Vec<Member> = members
            .iter()
            .map(|t| Member {
                name: t.describe(),
                mtu: t.mtu(),
                packet_time: t.packet_time(),
                heard: (now, 0),
                used: 0,
                said_down: false,
            })
            .collect();
        let slowest = info.iter().filter_map(|m| m.packet_time).max();
        let sync: Handle = Arc::new((
            Mutex::new(Shared {
                slots: members.iter().map(|_| Slot::default()).collect(),
            }),
            Condvar::new(),
        ));
        let (tx, inbox) = mpsc::sync_channel(INBOX);
        for (i, t) in members.into_iter().enumerate() {
            let (sync, tx) = (sync.clone(), tx.clone());
            std::thread::spawn(move || run_member(i, t, &sync, &tx));
        }
        let slowest = slowest.unwrap_or_default();
        Bond {
            order: Reorder::new(info.len(), slowest * 3 + Duration::from_millis(10)),
            silence: MIN_SILENCE.max(slowest * SILENT_PACKETS),
            members: info,
            sync,
            inbox,
            next_seq: 0,
            sent: 0,
            heard_total: 0,
            notices: Vec::new(),
        }
    }

    /// Two bonds joined by one simulated radio pair per configuration (see
    /// [`sim::pair`]), running `speedup` times faster than the radios.
    pub fn sim_pair(configs: &[SimConfig], speedup: f64) -> (Bond, Bond) {
        type Ends = Vec<Box<dyn Transport>>;
        let (a, b): (Ends, Ends) = configs
            .iter()
            .map(|&c| {
                let (a, b) = sim::pair(c, speedup);
                (Box::new(a) as Box<dyn Transport>, Box::new(b) as _)
            })
            .unzip();
        (Bond::new(a), Bond::new(b))
    }

    /// Takes in a packet that member `i` received at `at`.
    fn take_in(&mut self, (i, packet, at): Arrival) {
        self.heard_total += 1;
        self.members[i].heard = (at, self.heard_total);
        if let Some((seq, body)) = packet.split_first_chunk() {
            self.order
                .push(i, u16::from_le_bytes(*seq), body.to_vec(), at);
        }
    }

    /// Drops member `i` for `reason` (its thread ends at its next turn).
    fn drop_member(shared: &mut Shared, i: usize, reason: String) {
        let slot = &mut shared.slots[i];
        if slot.down.is_none() {
            slot.down = Some(reason);
            slot.queue.clear();
        }
    }

    /// Drops the members silent for longer than the bond allows while the
    /// others carried traffic, says each drop once, and fails when none is
    /// left.
    fn check_members(&mut self) -> io::Result<()> {
        let now = Instant::now();
        let others = OTHERS_PER_MEMBER * self.members.len() as u64;
        let mut shared = lock(&self.sync);
        for (i, m) in self.members.iter_mut().enumerate() {
            let (at, total) = m.heard;
            let silent = now.duration_since(at);
            if silent > self.silence && self.heard_total - total >= others {
                let reason = format!(
                    "nothing heard from it for {:.1} s while the others carried {} packets",
                    silent.as_secs_f64(),
                    self.heard_total - total
                );
                Self::drop_member(&mut shared, i, reason);
            }
            let slot = &mut shared.slots[i];
            self.notices.append(&mut slot.notices);
            if let (Some(reason), false) = (&slot.down, m.said_down) {
                m.said_down = true;
                self.notices.push(Notice::MemberDown {
                    member: m.name.clone(),
                    reason: reason.clone(),
                });
            }
        }
        if shared.slots.iter().all(|s| s.down.is_some()) {
            let why: Vec<String> = (self.members.iter().zip(&shared.slots))
                .map(|(m, s)| format!("{} ({})", m.name, s.down.as_deref().unwrap_or("")))
                .collect();
            return Err(io::Error::new(
                io::ErrorKind::NotConnected,
                format!("every link of the bond is down: {}", why.join("; ")),
            ));
        }
        Ok(())
    }
}

impl Drop for Bond {
    fn drop(&mut self) {
        let mut shared = lock(&self.sync);
        for i in 0..shared.slots.len() {
            Self::drop_member(&mut shared, i, "the bond was closed".into());
        }
    }
}

/// A member's thread: sends what the bond queues for it, hands up what it
/// receives, and passes on its notices and statistics, until it fails or
/// the bond drops it.
fn run_member(i: usize, mut t: Box<dyn Transport>, sync: &Handle, inbox: &SyncSender<Arrival>) {
    let (mut stats_at, mut busy) = (Instant::now(), true);
    loop {
        let packet = {
            let mut shared = lock(sync);
            if !busy && shared.slots[i].queue.is_empty() {
                // Idle: woken by a packet to send, or after POLL to listen.
                shared = (sync.1.wait_timeout(shared, POLL))
                    .unwrap_or_else(|p| p.into_inner())
                    .0;
            }
            let slot = &mut shared.slots[i];
            if slot.down.is_some() {
                return;
            }
            slot.queue.pop_front()
        };
        let mut failure = None;
        if let Some(p) = &packet {
            let sent = t.send(p);
            let shared = &mut *lock(sync);
            shared.slots[i].bytes -= p.len();
            sync.1.notify_all();
            if let Err(e) = sent {
                failure = Some(format!("it failed to send: {e}"));
            }
        }
        busy = packet.is_some();
        match t.recv(Duration::ZERO) {
            Ok(Some(p)) => match inbox.try_send((i, p, Instant::now())) {
                Ok(()) | Err(TrySendError::Full(_)) => busy = true,
                Err(TrySendError::Disconnected(_)) => return,
            },
            Ok(None) => {}
            Err(e) if no_data_yet(&e) => {}
            Err(e) => failure = failure.or(Some(format!("it failed to receive: {e}"))),
        }
        let notices = t.take_notices();
        let refresh = stats_at.elapsed() >= Duration::from_millis(100);
        if notices.is_empty() && failure.is_none() && !refresh {
            continue;
        }
        let shared = &mut *lock(sync);
        for n in notices {
            if let Notice::NoStatus { .. } = n {
                failure = failure.or(Some(n.to_string()));
            }
            shared.slots[i].notices.push(n);
        }
        if refresh {
            stats_at = Instant::now();
            shared.slots[i].stats = t.stats();
        }
        if let Some(reason) = failure {
            Bond::drop_member(shared, i, reason);
            sync.1.notify_all();
            return;
        }
    }
}

impl Transport for Bond {
    /// Queues `packet` on the member with the fewest bytes queued that has
    /// room, waiting while none has; fails only when every member is down.
    fn send(&mut self, packet: &[u8]) -> io::Result<()> {
        self.check_members()?;
        let mut framed = Vec::with_capacity(packet.len() + HEADER);
        framed.extend_from_slice(&self.next_seq.to_le_bytes());
        framed.extend_from_slice(packet);
        self.next_seq = self.next_seq.wrapping_add(1);
        self.sent += 1;
        let mut shared = lock(&self.sync);
        loop {
            let pick = (shared.slots.iter().enumerate())
                .filter(|(_, s)| s.down.is_none() && s.queue.len() < DEPTH)
                .min_by_key(|(i, s)| (s.bytes, self.members[*i].used))
                .map(|(i, _)| i);
            if let Some(i) = pick {
                let slot = &mut shared.slots[i];
                slot.bytes += framed.len();
                slot.queue.push_back(framed);
                self.members[i].used = self.sent;
                self.sync.1.notify_all();
                return Ok(());
            }
            if shared.slots.iter().all(|s| s.down.is_some()) {
                drop(shared);
                self.check_members()?;
                shared = lock(&self.sync);
                continue;
            }
            shared = (self.sync.1)
                .wait_timeout(shared, Duration::from_millis(20))
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }

    /// The next packet in the order the far end sent it.
    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
        let deadline = Instant::now() + timeout;
        loop {
            // Everything that arrived is put in order before anything is
            // handed up: a packet is passed over only for what truly came.
            while let Ok(arrival) = self.inbox.try_recv() {
                self.take_in(arrival);
            }
            let now = Instant::now();
            if let Some(p) = self.order.pop(now) {
                return Ok(Some(p));
            }
            self.check_members()?;
            if now >= deadline {
                return Ok(None);
            }
            let wait = (self.order.release_at())
                .map_or(deadline, |t| t.min(deadline))
                .saturating_duration_since(now);
            match self.inbox.recv_timeout(wait) {
                Ok(arrival) => self.take_in(arrival),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => self.check_members()?,
            }
        }
    }

    fn mtu(&self) -> usize {
        self.members
            .iter()
            .map(|m| m.mtu)
            .min()
            .unwrap_or(0)
            .saturating_sub(HEADER)
    }

    /// The slowest member's: a fragment's round trip is that of its member.
    fn packet_time(&self) -> Option<Duration> {
        self.members.iter().filter_map(|m| m.packet_time).max()
    }

    fn describe(&self) -> String {
        let names: Vec<&str> = self.members.iter().map(|m| m.name.as_str()).collect();
        format!("bond:{}", names.join(","))
    }

    /// The members' statistics added up (the signal strength is the first
    /// member's that has one).
    fn stats(&self) -> LinkStats {
        let shared = lock(&self.sync);
        let mut all = LinkStats::default();
        for s in shared.slots.iter().map(|s| &s.stats) {
            all.damaged += s.damaged;
            all.foreign_requests += s.foreign_requests;
            all.rssi_dbm = all.rssi_dbm.or(s.rssi_dbm);
            if let Some(r) = &s.radio {
                all.radio.get_or_insert_with(PacingCounters::default).add(r);
            }
        }
        all
    }

    fn take_notices(&mut self) -> Vec<Notice> {
        // A failure to report here is reported by the next send or receive.
        let _ = self.check_members();
        std::mem::take(&mut self.notices)
    }
}

/// Puts the packets of the far end back in the order it sent them.
struct Reorder {
    /// The sequence number handed up next (the far end starts at 0; after
    /// a restart of either end the order is found again within a hold).
    expected: u16,
    /// Packets from `expected` on, by their distance from it.
    held: VecDeque<Option<Vec<u8>>>,
    /// Packets to hand up at once (late ones: their turn passed).
    ready: VecDeque<Vec<u8>>,
    /// Since when the packet at `expected` is awaited while later ones are held.
    waiting_since: Option<Instant>,
    /// The longest a missing packet is awaited.
    hold: Duration,
    /// Per member, the last sequence number it carried and when it arrived
    /// (at first: none, and when the first packet came).
    last: Vec<(Option<u16>, Instant)>,
    /// The latest arrival taken in.
    frontier: Instant,
}

impl Reorder {
    fn new(members: usize, hold: Duration) -> Self {
        Reorder {
            expected: 0,
            held: VecDeque::new(),
            ready: VecDeque::new(),
            waiting_since: None,
            hold,
            last: vec![(None, Instant::now()); members],
            frontier: Instant::now(),
        }
    }

    /// How far `seq` is ahead of the expected one (negative: behind).
    fn ahead(&self, seq: u16) -> i16 {
        seq.wrapping_sub(self.expected) as i16
    }

    fn push(&mut self, member: usize, seq: u16, packet: Vec<u8>, now: Instant) {
        if self.last.iter().all(|(seq, _)| seq.is_none()) {
            // The first packet: the others may be carrying the ones before.
            self.last.iter_mut().for_each(|l| l.1 = now);
        }
        self.last[member] = (Some(seq), now);
        self.frontier = self.frontier.max(now);
        let ahead = self.ahead(seq);
        if ahead < 0 {
            self.ready.push_back(packet);
            return;
        }
        if ahead as usize >= INBOX {
            // Far beyond anything in flight: the far end started again.
            self.ready.extend(self.held.drain(..).flatten());
            self.expected = seq;
        }
        let at = self.ahead(seq) as usize;
        if self.held.len() <= at {
            self.held.resize(at + 1, None);
        }
        self.held[at].get_or_insert(packet);
        if at > 0 {
            self.waiting_since.get_or_insert(now);
        }
    }

    /// When the awaited packet stops being awaited.
    fn release_at(&self) -> Option<Instant> {
        self.waiting_since.map(|t| t + self.hold)
    }

    /// The next packet to hand up, if its turn has come.
    fn pop(&mut self, now: Instant) -> Option<Vec<u8>> {
        if let Some(p) = self.ready.pop_front() {
            return Some(p);
        }
        if self.held.front()?.is_none() {
            // Every member heard lately carried a later packet (each member
            // keeps its packets' order), or the wait is over: it was lost.
            let passed = self.last.iter().all(|&(seq, at)| {
                self.frontier.duration_since(at) > self.hold
                    || seq.is_some_and(|s| self.ahead(s) > 0)
            });
            if !passed && self.release_at().is_some_and(|t| now < t) {
                return None;
            }
            while self.held.front().is_some_and(Option::is_none) {
                self.held.pop_front();
                self.expected = self.expected.wrapping_add(1);
            }
        }
        let p = self.held.pop_front().flatten();
        self.expected = self.expected.wrapping_add(1);
        let gap = self.held.front().is_some_and(Option::is_none);
        self.waiting_since = gap.then_some(self.frontier);
        p
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::thread;

    use super::*;
    use crate::endpoint::{Endpoint, LinkError};
    use crate::radio::Firmware;

    /// A member that carries packets until the pair's budget of sent
    /// packets is spent; then its sends fail (`fail`) or vanish, and
    /// nothing arrives on it any more: the radio pair died.
    struct Cut {
        inner: Box<dyn Transport>,
        left: Arc<AtomicUsize>,
        fail: bool,
        sent: Arc<AtomicUsize>,
    }

    impl Cut {
        fn alive(&self) -> bool {
            self.left.load(Ordering::SeqCst) > 0
        }
    }

    impl Transport for Cut {
        fn send(&mut self, packet: &[u8]) -> io::Result<()> {
            let spend = |n: usize| n.checked_sub(1);
            if self
                .left
                .fetch_update(Ordering::SeqCst, Ordering::SeqCst, spend)
                .is_ok()
            {
                self.sent.fetch_add(1, Ordering::SeqCst);
                return self.inner.send(packet);
            }
            match self.fail {
                true => Err(io::Error::new(io::ErrorKind::BrokenPipe, "radio unplugged")),
                false => Ok(()),
            }
        }

        fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
            let p = self.inner.recv(timeout)?;
            Ok(p.filter(|_| self.alive()))
        }

        fn mtu(&self) -> usize {
            self.inner.mtu()
        }

        fn packet_time(&self) -> Option<Duration> {
            self.inner.packet_time()
        }

        fn describe(&self) -> String {
            format!("cut:{}", self.inner.describe())
        }
    }

    /// Two bonds over simulated 802.15.4 pairs sped up 10 times; pair `i`
    /// carries `budgets[i]` packets (both ways together), then dies
    /// (failing its sends with `fail`). Also returns each pair's count of
    /// packets carried.
    fn bonds(budgets: &[usize], fail: bool) -> (Bond, Bond, Vec<Arc<AtomicUsize>>) {
        let (mut a, mut b, mut counts) = (Vec::new(), Vec::new(), Vec::new());
        for (i, &budget) in budgets.iter().enumerate() {
            let cfg = SimConfig {
                seed: i as u64 + 1,
                ..SimConfig::default()
            };
            let (x, y) = sim::pair(cfg, 10.0);
            let left = Arc::new(AtomicUsize::new(budget));
            let sent = Arc::new(AtomicUsize::new(0));
            for (end, side) in [
                (Box::new(x) as Box<dyn Transport>, &mut a),
                (Box::new(y), &mut b),
            ] {
                side.push(Box::new(Cut {
                    inner: end,
                    left: left.clone(),
                    fail,
                    sent: sent.clone(),
                }) as Box<dyn Transport>);
            }
            counts.push(sent);
        }
        (Bond::new(a), Bond::new(b), counts)
    }

    fn message(n: usize, seed: u8) -> Vec<u8> {
        (0..n).map(|i| (i as u8).wrapping_mul(31) ^ seed).collect()
    }

    /// Receives `n` messages on `bond` in a thread; returns them and the
    /// notices the endpoint passed on.
    fn receive(bond: Bond, n: usize) -> thread::JoinHandle<(Vec<Vec<u8>>, Vec<Notice>)> {
        thread::spawn(move || {
            let mut ep = Endpoint::new(Box::new(bond)).unwrap();
            let said = Arc::new(Mutex::new(Vec::new()));
            let s = said.clone();
            ep.on_notice(Box::new(move |n| s.lock().unwrap().push(n)));
            let got = (0..n)
                .map_while(|_| ep.recv_message(Duration::from_secs(20)).ok())
                .collect();
            let _ = ep.linger(Duration::from_millis(300));
            let said = said.lock().unwrap().clone();
            (got, said)
        })
    }

    /// Packets go out over every member, a like share each, and come out at
    /// the far end all there and in the order they were sent.
    #[test]
    fn stripes_packets_across_members_and_keeps_their_order() {
        let (mut a, mut b, counts) = bonds(&[usize::MAX, usize::MAX, usize::MAX], false);
        assert_eq!(a.mtu(), 100 - HEADER);
        let n = 300usize;
        for i in 0..n {
            a.send(&(i as u16).to_le_bytes()).unwrap();
        }
        let mut got = Vec::new();
        while got.len() < n {
            match b.recv(Duration::from_secs(5)).unwrap() {
                Some(p) => got.push(u16::from_le_bytes([p[0], p[1]]) as usize),
                None => break,
            }
        }
        assert_eq!(got, (0..n).collect::<Vec<_>>());
        for c in &counts {
            let c = c.load(Ordering::SeqCst);
            assert!((n / 3 - 20..=n / 3 + 20).contains(&c), "{c} of {n}");
        }
    }

    /// The far end's packets are put back in order; one lost is passed over
    /// as soon as every member carried a later one, not after the hold.
    #[test]
    fn reorder_passes_over_a_lost_packet_once_every_member_is_past_it() {
        let t0 = Instant::now();
        let mut r = Reorder::new(2, Duration::from_secs(10));
        r.expected = 65530;
        r.push(0, 65530, vec![0], t0);
        r.push(1, 65532, vec![2], t0);
        assert_eq!(r.pop(t0), Some(vec![0]));
        assert_eq!(r.pop(t0), None, "65531 may still come on member 0");
        r.push(0, 65533, vec![3], t0);
        assert_eq!(r.pop(t0), Some(vec![2]), "both members are past 65531");
        assert_eq!(r.pop(t0), Some(vec![3]));
        r.push(1, 65531, vec![1], t0);
        assert_eq!(r.pop(t0), Some(vec![1]), "late: handed up at once");
        r.push(1, 65535, vec![5], t0);
        assert_eq!(r.pop(t0), None);
        let later = t0 + Duration::from_secs(11);
        assert_eq!(r.pop(later), Some(vec![5]), "the hold is over");
        r.push(0, 0, vec![6], later);
        assert_eq!(r.pop(later), Some(vec![6]), "wrapped around");
        r.push(0, 30_000, vec![7], later);
        assert_eq!(r.pop(later), Some(vec![7]), "the far end started again");
        assert_eq!(r.expected, 30_001);
    }

    /// A pair that goes silent mid-transfer is dropped with a notice, and
    /// every message still arrives intact over the other.
    #[test]
    fn a_member_dying_mid_transfer_is_dropped_and_messages_arrive_intact() {
        let (a, b, counts) = bonds(&[usize::MAX, 200], false);
        let msgs: Vec<Vec<u8>> = (0..8).map(|i| message(20_000, i)).collect();
        let rx = receive(b, msgs.len());
        let mut ep = Endpoint::new(Box::new(a)).unwrap();
        let said = Arc::new(Mutex::new(Vec::new()));
        let s = said.clone();
        ep.on_notice(Box::new(move |n| s.lock().unwrap().push(n)));
        for m in &msgs {
            ep.send_message(m).unwrap();
        }
        let (got, rx_said) = rx.join().unwrap();
        assert_eq!(got, msgs);
        assert_eq!(counts[1].load(Ordering::SeqCst), 200);
        for notices in [said.lock().unwrap().clone(), rx_said] {
            assert!(
                notices.iter().any(
                    |n| matches!(n, Notice::MemberDown { member, .. } if member.starts_with("cut:"))
                ),
                "{notices:?}"
            );
        }
    }

    /// A pair whose sends fail is dropped at once, naming the failure.
    #[test]
    fn a_member_whose_sends_fail_is_dropped_with_the_reason() {
        let (a, b, _) = bonds(&[usize::MAX, 50], true);
        let msg = message(30_000, 9);
        let rx = receive(b, 1);
        let mut ep = Endpoint::new(Box::new(a)).unwrap();
        let said = Arc::new(Mutex::new(Vec::new()));
        let s = said.clone();
        ep.on_notice(Box::new(move |n| s.lock().unwrap().push(n)));
        ep.send_message(&msg).unwrap();
        assert_eq!(rx.join().unwrap().0, vec![msg]);
        let said = said.lock().unwrap();
        assert!(
            said.iter()
                .any(|n| n.to_string().contains("radio unplugged")),
            "{said:?}"
        );
    }

    /// With every pair down the bond fails with an error naming each, and
    /// the message is not reported delivered.
    #[test]
    fn all_members_down_is_an_error_naming_them() {
        let (a, _b, _) = bonds(&[3, 3], true);
        let mut ep = Endpoint::new(Box::new(a)).unwrap();
        let err = ep.send_message(&message(5_000, 1)).unwrap_err();
        let text = err.to_string();
        assert!(matches!(err, LinkError::Io(_)), "{text}");
        assert!(text.contains("every link of the bond is down"), "{text}");
        assert_eq!(text.matches("cut:sim:").count(), 2, "{text}");
        assert_eq!(text.matches("radio unplugged").count(), 2, "{text}");
    }

    /// Pairs that carry nothing to a live peer: nothing is reported
    /// delivered, the send fails at its deadline, and no pair is dropped
    /// for a silence that all share (no other pair answers either).
    #[test]
    fn nothing_is_reported_delivered_that_was_not() {
        let (a, _b, _) = bonds(&[0, 0], false);
        let cfg = crate::arq::Config {
            deadline: 1_500_000,
            ..crate::arq::Config::for_mtu(a.mtu())
        };
        let mut ep = Endpoint::with_config(Box::new(a), cfg).unwrap();
        let said = Arc::new(Mutex::new(Vec::new()));
        let s = said.clone();
        ep.on_notice(Box::new(move |n| s.lock().unwrap().push(n)));
        let r = ep.send_message(&message(2_000, 2));
        assert!(matches!(r, Err(LinkError::NoAnswer(_))), "{r:?}");
        assert!(
            said.lock().unwrap().is_empty(),
            "{:?}",
            said.lock().unwrap()
        );
    }

    /// On the calibrated ZigBee model two pairs carry nearly twice what one
    /// does (the figures are in docs/benchmarks.md).
    #[test]
    fn two_zigbee_pairs_carry_more_than_one() {
        let cfg = SimConfig {
            radio: Firmware::Zigbee,
            mtu: 84,
            ..SimConfig::default()
        };
        let (a, b) = Bond::sim_pair(&[cfg, SimConfig { seed: 2, ..cfg }], 10.0);
        let msg = message(20_000, 3);
        let rx = receive(b, 1);
        let mut ep = Endpoint::new(Box::new(a)).unwrap();
        let st = ep.send_message(&msg).unwrap();
        assert_eq!(rx.join().unwrap().0, vec![msg]);
        let one = sim::transfer(cfg, crate::arq::Config::for_mtu(84), &message(20_000, 3));
        let radio_bps = st.goodput_bps() / 10.0;
        assert!(
            radio_bps > 1.5 * one.goodput_bps,
            "{radio_bps:.0} against {:.0}",
            one.goodput_bps
        );
    }
}
