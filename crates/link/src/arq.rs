//! Fragmentation and selective-repeat ARQ, as state machines that do no I/O
//! and read no clock: the caller passes `now` (µs) and the segments, and
//! takes the segments to transmit. See `docs/link-protocol.md`.
//!
//! A message is sent as `payload ‖ CRC-32`, cut into fragments that fit the
//! link's payload limit. Every segment ends with a CRC-16, so damaged
//! segments are dropped where they arrive.
//!
//! ```text
//! DATA  01 | msg id u16 | index u16 | count u16 | fragment …      | crc16
//! ACK   02 | msg id u16 | next u16  | bitmap u32                  | crc16
//! FAIL  03 | msg id u16                                           | crc16
//! ```
//!
//! (little-endian). An ACK says "every fragment below `next` arrived, and
//! fragment `next + 1 + i` arrived where bit `i` is set". The sender keeps a
//! window of fragments in flight, retransmits a fragment when its timeout
//! (Jacobson/Karels from measured round trips) expires or when a later
//! fragment is acknowledged before it (a gap), and gives up at the message
//! deadline with a FAIL so both sides end with an explicit error. The
//! receiver drops duplicates, bounds reassembly in memory and time, checks
//! the CRC-32, and never hands up a partial or corrupt message.

use alloc::collections::{BTreeMap, VecDeque};
use alloc::vec;
use alloc::vec::Vec;

use crate::crc::{crc16, crc32};

/// Microseconds on the caller's clock.
pub type Micros = u64;

const DATA: u8 = 1;
const ACK: u8 = 2;
const FAIL: u8 = 3;
/// Bytes of a DATA segment besides the fragment.
pub const DATA_OVERHEAD: usize = 9;

/// A parsed segment.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Segment<'a> {
    /// A fragment of a message.
    Data {
        msg_id: u16,
        index: u16,
        count: u16,
        fragment: &'a [u8],
    },
    /// Acknowledgement state of a message.
    Ack { msg_id: u16, next: u16, bitmap: u32 },
    /// The sender gave up on a message.
    Fail { msg_id: u16 },
}

impl<'a> Segment<'a> {
    /// Parses and checks a segment; `None` for damaged or unknown bytes.
    pub fn parse(bytes: &'a [u8]) -> Option<Self> {
        if bytes.len() < 5 {
            return None;
        }
        let (body, crc) = bytes.split_at(bytes.len() - 2);
        if crc16(body).to_le_bytes() != crc {
            return None;
        }
        let u16_at = |i: usize| u16::from_le_bytes([body[i], body[i + 1]]);
        match (body[0], body.len()) {
            (DATA, n) if n >= 7 => Some(Segment::Data {
                msg_id: u16_at(1),
                index: u16_at(3),
                count: u16_at(5),
                fragment: &body[7..],
            }),
            (ACK, 9) => Some(Segment::Ack {
                msg_id: u16_at(1),
                next: u16_at(3),
                bitmap: u32::from_le_bytes(body[5..9].try_into().expect("4 bytes")),
            }),
            (FAIL, 3) => Some(Segment::Fail { msg_id: u16_at(1) }),
            _ => None,
        }
    }

    /// Serialises the segment with its CRC-16.
    pub fn emit(&self) -> Vec<u8> {
        let mut v = Vec::new();
        match self {
            Segment::Data {
                msg_id,
                index,
                count,
                fragment,
            } => {
                v.push(DATA);
                for x in [msg_id, index, count] {
                    v.extend_from_slice(&x.to_le_bytes());
                }
                v.extend_from_slice(fragment);
            }
            Segment::Ack {
                msg_id,
                next,
                bitmap,
            } => {
                v.push(ACK);
                v.extend_from_slice(&msg_id.to_le_bytes());
                v.extend_from_slice(&next.to_le_bytes());
                v.extend_from_slice(&bitmap.to_le_bytes());
            }
            Segment::Fail { msg_id } => {
                v.push(FAIL);
                v.extend_from_slice(&msg_id.to_le_bytes());
            }
        }
        let crc = crc16(&v);
        v.extend_from_slice(&crc.to_le_bytes());
        v
    }
}

/// Why a message did not get through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ArqError {
    /// The message is larger than the protocol (65535 fragments) or the receiver allows.
    TooLarge,
    /// The sender's deadline passed before every fragment was acknowledged.
    Deadline,
    /// The receiver's reassembly timed out.
    ReassemblyTimeout,
    /// The sender aborted the message.
    Aborted,
    /// The reassembled message failed its CRC-32.
    Corrupt,
    /// A message is already being sent.
    Busy,
}

impl core::fmt::Display for ArqError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ArqError::TooLarge => "message too large",
            ArqError::Deadline => "message not acknowledged before its deadline",
            ArqError::ReassemblyTimeout => "reassembly timed out: fragments stopped arriving",
            ArqError::Aborted => "the sender gave up on the message",
            ArqError::Corrupt => "reassembled message failed its CRC-32",
            ArqError::Busy => "a message is already in flight",
        })
    }
}

/// Sender parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// Largest segment the link carries (100 for XBee 802.15.4, 84 for ZigBee).
    pub mtu: usize,
    /// Fragments in flight.
    pub window: usize,
    /// Initial retransmission timeout.
    pub initial_rto: Micros,
    /// Smallest retransmission timeout.
    pub min_rto: Micros,
    /// Largest retransmission timeout.
    pub max_rto: Micros,
    /// Time allowed for one message.
    pub deadline: Micros,
    /// The receiver acknowledges after this many new fragments (and at gaps and the end).
    pub ack_every: usize,
    /// Largest message the receiver reassembles.
    pub max_message: usize,
    /// Messages reassembled at once.
    pub max_pending: usize,
    /// Drop a partial message when no fragment arrived for this long.
    pub reassembly_timeout: Micros,
}

impl Config {
    /// Defaults for a link whose segments carry at most `mtu` bytes.
    pub fn for_mtu(mtu: usize) -> Self {
        Config {
            mtu,
            window: 32,
            initial_rto: 300_000,
            min_rto: 20_000,
            max_rto: 3_000_000,
            deadline: 120_000_000,
            ack_every: 8,
            max_message: 4 << 20,
            max_pending: 4,
            reassembly_timeout: 30_000_000,
        }
    }

    /// Fragment bytes per DATA segment.
    pub fn fragment_size(&self) -> usize {
        self.mtu.saturating_sub(DATA_OVERHEAD).max(1)
    }
}

/// Progress of the current outgoing message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SendState {
    /// Nothing to send.
    Idle,
    /// Fragments in flight.
    Sending,
    /// Every fragment acknowledged.
    Done,
    /// Gave up.
    Failed(ArqError),
}

/// Counters of the sender.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SendCounters {
    /// DATA segments sent, first transmissions and retransmissions.
    pub segments: u64,
    /// Retransmitted DATA segments.
    pub retransmissions: u64,
    /// Payload bytes of the message.
    pub message_bytes: u64,
}

/// The sending half: one message at a time.
#[derive(Debug)]
pub struct Sender {
    cfg: Config,
    msg_id: u16,
    data: Vec<u8>,
    count: usize,
    acked: Vec<bool>,
    sent_at: Vec<Option<Micros>>,
    tries: Vec<u32>,
    queue: VecDeque<usize>,
    next_new: usize,
    srtt: Option<(f64, f64)>,
    rto: Micros,
    deadline: Micros,
    state: SendState,
    counters: SendCounters,
}

impl Sender {
    /// An idle sender.
    pub fn new(cfg: Config) -> Self {
        Sender {
            cfg,
            msg_id: 0,
            data: Vec::new(),
            count: 0,
            acked: Vec::new(),
            sent_at: Vec::new(),
            tries: Vec::new(),
            queue: VecDeque::new(),
            next_new: 0,
            srtt: None,
            rto: cfg.initial_rto,
            deadline: 0,
            state: SendState::Idle,
            counters: SendCounters::default(),
        }
    }

    /// Starts sending `message` at `now`.
    pub fn start(&mut self, message: &[u8], now: Micros) -> Result<u16, ArqError> {
        if self.state == SendState::Sending {
            return Err(ArqError::Busy);
        }
        let frag = self.cfg.fragment_size();
        let total = message.len() + 4;
        let count = total.div_ceil(frag).max(1);
        if count > u16::MAX as usize || message.len() > self.cfg.max_message {
            return Err(ArqError::TooLarge);
        }
        self.msg_id = self.msg_id.wrapping_add(1);
        self.data.clear();
        self.data.extend_from_slice(message);
        self.data.extend_from_slice(&crc32(message).to_le_bytes());
        self.count = count;
        self.acked = vec![false; count];
        self.sent_at = vec![None; count];
        self.tries = vec![0; count];
        self.queue.clear();
        self.next_new = 0;
        self.deadline = now.saturating_add(self.cfg.deadline);
        self.state = SendState::Sending;
        self.counters = SendCounters {
            message_bytes: message.len() as u64,
            ..Default::default()
        };
        Ok(self.msg_id)
    }

    /// The current state.
    pub fn state(&self) -> SendState {
        self.state
    }

    /// Counters of the current (or last) message.
    pub fn counters(&self) -> SendCounters {
        self.counters
    }

    /// The current retransmission timeout.
    pub fn rto(&self) -> Micros {
        self.rto
    }

    fn segment(&self, i: usize) -> Vec<u8> {
        let frag = self.cfg.fragment_size();
        let end = ((i + 1) * frag).min(self.data.len());
        Segment::Data {
            msg_id: self.msg_id,
            index: i as u16,
            count: self.count as u16,
            fragment: &self.data[i * frag..end],
        }
        .emit()
    }

    fn in_flight(&self) -> usize {
        (0..self.next_new).filter(|&i| !self.acked[i]).count()
    }

    /// The next segment to transmit at `now`, if any.
    pub fn poll_transmit(&mut self, now: Micros) -> Option<Vec<u8>> {
        if self.state != SendState::Sending {
            return None;
        }
        if now >= self.deadline {
            self.state = SendState::Failed(ArqError::Deadline);
            return Some(
                Segment::Fail {
                    msg_id: self.msg_id,
                }
                .emit(),
            );
        }
        for i in 0..self.next_new {
            if !self.acked[i]
                && self.sent_at[i].is_some_and(|t| now >= t + self.rto)
                && !self.queue.contains(&i)
            {
                self.queue.push_back(i);
                self.sent_at[i] = None; // counted as lost until resent
            }
        }
        while let Some(i) = self.queue.pop_front() {
            if !self.acked[i] {
                self.counters.retransmissions += 1;
                return Some(self.transmit(i, now));
            }
        }
        if self.next_new < self.count && self.in_flight() < self.cfg.window {
            self.next_new += 1;
            return Some(self.transmit(self.next_new - 1, now));
        }
        None
    }

    fn transmit(&mut self, i: usize, now: Micros) -> Vec<u8> {
        self.sent_at[i] = Some(now);
        self.tries[i] += 1;
        self.counters.segments += 1;
        self.segment(i)
    }

    /// When [`Sender::poll_transmit`] may next have something to do.
    pub fn poll_at(&self) -> Option<Micros> {
        if self.state != SendState::Sending {
            return None;
        }
        let timer = self
            .sent_at
            .iter()
            .zip(&self.acked)
            .filter(|(_, a)| !**a)
            .filter_map(|(t, _)| t.map(|t| t + self.rto))
            .min();
        Some(timer.map_or(self.deadline, |t| t.min(self.deadline)))
    }

    /// Takes an incoming ACK or FAIL segment into account.
    pub fn on_segment(&mut self, seg: &Segment, now: Micros) {
        if self.state != SendState::Sending {
            return;
        }
        let (msg_id, next, bitmap) = match *seg {
            Segment::Ack {
                msg_id,
                next,
                bitmap,
            } => (msg_id, next as usize, bitmap),
            Segment::Fail { msg_id } if msg_id == self.msg_id => {
                self.state = SendState::Failed(ArqError::Aborted);
                return;
            }
            _ => return,
        };
        if msg_id != self.msg_id {
            return;
        }
        let mut highest = None;
        let newly: Vec<usize> = (0..self.count)
            .filter(|&i| {
                i < next || (i > next && i - next - 1 < 32 && bitmap >> (i - next - 1) & 1 == 1)
            })
            .filter(|&i| !self.acked[i])
            .collect();
        for &i in &newly {
            self.acked[i] = true;
            highest = highest.max(Some(i));
            // Karn: only fragments sent once give round-trip samples.
            if let (1, Some(t)) = (self.tries[i], self.sent_at[i]) {
                self.sample_rtt(now.saturating_sub(t));
            }
        }
        if self.acked.iter().all(|&a| a) {
            self.state = SendState::Done;
            return;
        }
        // A gap below an acknowledged fragment that was sent later: resend it now.
        if let Some(h) = highest {
            let h_sent = self.sent_at[h];
            for i in 0..h {
                if !self.acked[i]
                    && !self.queue.contains(&i)
                    && self.sent_at[i].is_some_and(|t| Some(t) < h_sent)
                {
                    self.sent_at[i] = None;
                    self.queue.push_back(i);
                }
            }
        }
    }

    fn sample_rtt(&mut self, rtt: Micros) {
        let r = rtt as f64;
        let (srtt, var) = match self.srtt {
            None => (r, r / 2.0),
            Some((s, v)) => (0.875 * s + 0.125 * r, 0.75 * v + 0.25 * (s - r).abs()),
        };
        self.srtt = Some((srtt, var));
        self.rto = ((srtt + 4.0 * var) as Micros).clamp(self.cfg.min_rto, self.cfg.max_rto);
    }
}

struct Pending {
    count: usize,
    frags: Vec<Option<Vec<u8>>>,
    received: usize,
    bytes: usize,
    since_ack: usize,
    last_seen: Micros,
}

/// What the receiver hands up.
pub type Delivery = Result<Vec<u8>, (u16, ArqError)>;

/// The receiving half: reassembles several messages, acknowledges, delivers.
pub struct Receiver {
    cfg: Config,
    pending: BTreeMap<u16, Pending>,
    recent: VecDeque<(u16, u16)>,
    duplicates: u64,
}

impl Receiver {
    /// An empty receiver.
    pub fn new(cfg: Config) -> Self {
        Receiver {
            cfg,
            pending: BTreeMap::new(),
            recent: VecDeque::new(),
            duplicates: 0,
        }
    }

    /// Duplicate DATA segments dropped so far.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }

    fn ack(msg_id: u16, p: &Pending) -> Vec<u8> {
        let next = p.frags.iter().position(Option::is_none).unwrap_or(p.count);
        let mut bitmap = 0u32;
        for i in 0..32 {
            if p.frags.get(next + 1 + i).is_some_and(Option::is_some) {
                bitmap |= 1 << i;
            }
        }
        Segment::Ack {
            msg_id,
            next: next as u16,
            bitmap,
        }
        .emit()
    }

    /// Handles a DATA or FAIL segment: returns an ACK to send and, when a
    /// message completes or fails, what to hand up.
    pub fn on_segment(
        &mut self,
        seg: &Segment,
        now: Micros,
    ) -> (Option<Vec<u8>>, Option<Delivery>) {
        match *seg {
            Segment::Fail { msg_id } => {
                let known = self.pending.remove(&msg_id).is_some();
                (None, known.then_some(Err((msg_id, ArqError::Aborted))))
            }
            Segment::Data {
                msg_id,
                index,
                count,
                fragment,
            } => self.on_data(msg_id, index as usize, count as usize, fragment, now),
            Segment::Ack { .. } => (None, None),
        }
    }

    fn on_data(
        &mut self,
        msg_id: u16,
        index: usize,
        count: usize,
        fragment: &[u8],
        now: Micros,
    ) -> (Option<Vec<u8>>, Option<Delivery>) {
        if let Some(&(_, c)) = self.recent.iter().find(|(id, _)| *id == msg_id) {
            // Already delivered: the sender missed our final ACK.
            self.duplicates += 1;
            return (
                Some(
                    Segment::Ack {
                        msg_id,
                        next: c,
                        bitmap: 0,
                    }
                    .emit(),
                ),
                None,
            );
        }
        let frag = self.cfg.fragment_size();
        if index >= count
            || count == 0
            || fragment.len() > frag
            || (count - 1) * frag > self.cfg.max_message + 4
        {
            return (None, None);
        }
        if !self.pending.contains_key(&msg_id) {
            while self.pending.len() >= self.cfg.max_pending {
                let oldest = *self
                    .pending
                    .iter()
                    .min_by_key(|(_, p)| p.last_seen)
                    .expect("non-empty")
                    .0;
                self.pending.remove(&oldest);
            }
            self.pending.insert(
                msg_id,
                Pending {
                    count,
                    frags: vec![None; count],
                    received: 0,
                    bytes: 0,
                    since_ack: 0,
                    last_seen: now,
                },
            );
        }
        let p = self.pending.get_mut(&msg_id).expect("inserted");
        if p.count != count {
            return (None, None);
        }
        p.last_seen = now;
        if p.frags[index].is_some() {
            self.duplicates += 1;
            return (Some(Self::ack(msg_id, p)), None);
        }
        let gap = p.frags[..index].iter().any(Option::is_none);
        p.frags[index] = Some(fragment.to_vec());
        p.received += 1;
        p.bytes += fragment.len();
        p.since_ack += 1;
        if p.received < p.count {
            let due = gap || p.since_ack >= self.cfg.ack_every;
            if due {
                p.since_ack = 0;
            }
            return (due.then(|| Self::ack(msg_id, p)), None);
        }
        let p = self.pending.remove(&msg_id).expect("present");
        let ack = Self::ack(msg_id, &p);
        let mut data: Vec<u8> = p.frags.into_iter().flatten().flatten().collect();
        if data.len() < 4 {
            return (
                Some(Segment::Fail { msg_id }.emit()),
                Some(Err((msg_id, ArqError::Corrupt))),
            );
        }
        let crc = u32::from_le_bytes(data[data.len() - 4..].try_into().expect("4 bytes"));
        data.truncate(data.len() - 4);
        if crc32(&data) != crc {
            return (
                Some(Segment::Fail { msg_id }.emit()),
                Some(Err((msg_id, ArqError::Corrupt))),
            );
        }
        self.recent.push_back((msg_id, count as u16));
        if self.recent.len() > 64 {
            self.recent.pop_front();
        }
        (Some(ack), Some(Ok(data)))
    }

    /// Expires partial messages that stopped receiving fragments.
    pub fn poll(&mut self, now: Micros) -> Option<Delivery> {
        let expired = self
            .pending
            .iter()
            .find(|(_, p)| now.saturating_sub(p.last_seen) > self.cfg.reassembly_timeout)
            .map(|(&id, _)| id)?;
        self.pending.remove(&expired);
        Some(Err((expired, ArqError::ReassemblyTimeout)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn transfer(msg: &[u8], drop: impl Fn(usize) -> bool) -> (Vec<u8>, SendCounters) {
        let cfg = Config {
            initial_rto: 1_000,
            min_rto: 1_000,
            ..Config::for_mtu(40)
        };
        let (mut s, mut r) = (Sender::new(cfg), Receiver::new(cfg));
        s.start(msg, 0).unwrap();
        let mut now = 0;
        let mut n = 0;
        let mut got = None;
        while s.state() == SendState::Sending {
            while let Some(seg) = s.poll_transmit(now) {
                n += 1;
                if drop(n) {
                    continue;
                }
                let (ack, d) = r.on_segment(&Segment::parse(&seg).unwrap(), now);
                if let Some(Ok(m)) = d {
                    got = Some(m);
                }
                if let Some(a) = ack {
                    s.on_segment(&Segment::parse(&a).unwrap(), now + 10);
                }
            }
            now = s.poll_at().unwrap_or(now + 1).max(now + 1);
        }
        assert_eq!(s.state(), SendState::Done);
        (got.unwrap(), s.counters())
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
    fn segments_round_trip_and_damage_is_detected() {
        let s = Segment::Data {
            msg_id: 3,
            index: 1,
            count: 2,
            fragment: b"abc",
        };
        let b = s.emit();
        assert_eq!(Segment::parse(&b), Some(s));
        for i in 0..b.len() {
            let mut c = b.clone();
            c[i] ^= 0x04;
            assert_eq!(Segment::parse(&c), None);
        }
    }

    #[test]
    fn deadline_fails_explicitly_on_both_sides() {
        let cfg = Config {
            deadline: 5_000,
            ..Config::for_mtu(40)
        };
        let (mut s, mut r) = (Sender::new(cfg), Receiver::new(cfg));
        s.start(&[1; 100], 0).unwrap();
        let first = s.poll_transmit(0).unwrap();
        r.on_segment(&Segment::parse(&first).unwrap(), 0);
        let fail = s.poll_transmit(6_000).unwrap();
        assert_eq!(s.state(), SendState::Failed(ArqError::Deadline));
        let (_, d) = r.on_segment(&Segment::parse(&fail).unwrap(), 6_000);
        assert_eq!(d, Some(Err((1, ArqError::Aborted))));
    }
}
