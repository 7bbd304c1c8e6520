//! Fragmentation and selective-repeat ARQ, as state machines that do no I/O
//! and read no clock: the caller passes `now` (µs) and the segments, and
//! takes the segments to transmit. See `docs/link-protocol.md`.
//!
//! A message is sent as `payload ‖ CRC-32`, cut into fragments that fit the
//! link's payload limit.
//!
//! ```text
//! DATA  31 | session u24 | msg id u8 | index u16 | fragment …              (the last fragment: 34)
//! ACK   32 | session u24 | receiver u24 | msg id u8 | count u16 | next u16 | bitmap u32 | crc16
//! FAIL  33 | session u24 | msg id u8                                      | crc16
//! ```
//!
//! (little-endian; the type byte's high nibble is the wire version,
//! [`WIRE_VERSION`]). DATA is 7 bytes of header and nothing else, so that a
//! ZigBee radio's 84-byte payload carries 77 message bytes: it has no CRC of
//! its own, because every transport under it checks each frame (the XBee's
//! MAC FCS on the air and its API checksum on the UART, SLIP's CRC-16, UDP's
//! checksum) and the message's CRC-32 covers its bytes end to end. The
//! control segments, which are acted on as they arrive, keep a CRC-16. What
//! a damaged DATA header that slipped past the transport can do is bounded:
//! the sender counts a message delivered only on an ACK that names the
//! message's fragment count, which the receiver learns only from the last
//! fragment, so no corruption of an index or of the last-fragment mark can
//! make a message count as delivered that the receiver did not hand up.
//!
//! Each endpoint start has its own random [`SessionId`]:
//! DATA carries the sender's, an ACK echoes it and adds the receiver's own,
//! and a FAIL names the session whose message it ends. The receiver keys
//! reassembly and duplicate suppression by (sender session, message id), so
//! a restarted sender's first messages are never taken for the old one's;
//! the sender trusts ACKs of one receiver session at a time and, when a new
//! one answers (the receiver restarted), sends again what the old one had
//! acknowledged.
//!
//! An ACK says "every fragment below `next` arrived, and fragment
//! `next + 1 + i` arrived where bit `i` is set", and `count`, the message's
//! fragment count once the receiver knows it (0 before). The sender keeps a
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

/// The link segment format's version, the high nibble of every type byte.
/// Version 1 (type bytes 0x01–0x03) had no sessions and version 2 (0x21–0x23)
/// 13-byte DATA headers; their segments are dropped as unknown.
pub const WIRE_VERSION: u8 = 3;
const DATA: u8 = WIRE_VERSION << 4 | 1;
const ACK: u8 = WIRE_VERSION << 4 | 2;
const FAIL: u8 = WIRE_VERSION << 4 | 3;
const DATA_LAST: u8 = WIRE_VERSION << 4 | 4;
/// Bytes of a DATA segment besides the fragment.
pub const DATA_OVERHEAD: usize = 7;
const ACK_LEN: usize = 18;
const FAIL_LEN: usize = 7;
/// The smallest payload a link must carry: an ACK.
pub const MIN_MTU: usize = ACK_LEN;
/// Peer sessions a [`Receiver`] keeps state for, and receiver sessions a
/// [`Sender`] remembers having stopped trusting: the current one and three
/// before it.
pub const REMEMBERED_SESSIONS: usize = 4;

/// One life of an endpoint: drawn at random when it starts (from the OS
/// RNG, by [`crate::endpoint`]), so a restarted process never continues an
/// old one's message ids. A handshake may supply it instead; the ARQ only
/// compares sessions for equality. It travels as 24 bits
/// ([`SessionId::BITS`]): with [`REMEMBERED_SESSIONS`] remembered, a
/// restarted peer draws one of them again about once in 4 million restarts
/// (see `docs/link-protocol.md`, "Sessions").
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SessionId(pub u32);

impl SessionId {
    /// Bits of a session on the wire.
    pub const BITS: u32 = 24;

    /// The session named by the low [`SessionId::BITS`] bits of `random`.
    pub fn from_random(random: u32) -> Self {
        SessionId(random & ((1 << Self::BITS) - 1))
    }
}

/// A parsed segment.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Segment<'a> {
    /// Fragment `index` of a message of the sender's `session`; `last`
    /// marks the message's final fragment (so its count is `index + 1`).
    Data {
        session: SessionId,
        msg_id: u8,
        index: u16,
        last: bool,
        fragment: &'a [u8],
    },
    /// Acknowledgement state of message `msg_id` of `session`, from the
    /// receiver whose own session is `receiver`; `count` is the message's
    /// fragment count where the receiver knows it, else 0.
    Ack {
        session: SessionId,
        receiver: SessionId,
        msg_id: u8,
        count: u16,
        next: u16,
        bitmap: u32,
    },
    /// Message `msg_id` of `session` is given up (by its sender, or by the
    /// receiver when it arrived corrupt).
    Fail { session: SessionId, msg_id: u8 },
}

fn u24_at(b: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([b[i], b[i + 1], b[i + 2], 0])
}

fn u16_at(b: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([b[i], b[i + 1]])
}

fn push_session(v: &mut Vec<u8>, s: SessionId) {
    v.extend_from_slice(&s.0.to_le_bytes()[..3]);
}

/// Splits off and checks a control segment's CRC-16.
fn checked(bytes: &[u8]) -> Option<&[u8]> {
    let (body, crc) = bytes.split_at(bytes.len().checked_sub(2)?);
    (crc16(body).to_le_bytes() == crc).then_some(body)
}

impl<'a> Segment<'a> {
    /// Parses a segment (and checks a control segment's CRC-16); `None` for
    /// damaged, unknown or other versions' bytes.
    pub fn parse(bytes: &'a [u8]) -> Option<Self> {
        let kind = *bytes.first()?;
        match kind {
            DATA | DATA_LAST if bytes.len() >= DATA_OVERHEAD => Some(Segment::Data {
                session: SessionId(u24_at(bytes, 1)),
                msg_id: bytes[4],
                index: u16_at(bytes, 5),
                last: kind == DATA_LAST,
                fragment: &bytes[DATA_OVERHEAD..],
            }),
            ACK if bytes.len() == ACK_LEN => {
                let b = checked(bytes)?;
                Some(Segment::Ack {
                    session: SessionId(u24_at(b, 1)),
                    receiver: SessionId(u24_at(b, 4)),
                    msg_id: b[7],
                    count: u16_at(b, 8),
                    next: u16_at(b, 10),
                    bitmap: u32::from_le_bytes([b[12], b[13], b[14], b[15]]),
                })
            }
            FAIL if bytes.len() == FAIL_LEN => {
                let b = checked(bytes)?;
                Some(Segment::Fail {
                    session: SessionId(u24_at(b, 1)),
                    msg_id: b[4],
                })
            }
            _ => None,
        }
    }

    /// Serialises the segment (a control segment with its CRC-16). Sessions
    /// are written as their low 24 bits.
    pub fn emit(&self) -> Vec<u8> {
        let mut v = Vec::new();
        match self {
            Segment::Data {
                session,
                msg_id,
                index,
                last,
                fragment,
            } => {
                v.reserve(DATA_OVERHEAD + fragment.len());
                v.push(if *last { DATA_LAST } else { DATA });
                push_session(&mut v, *session);
                v.push(*msg_id);
                v.extend_from_slice(&index.to_le_bytes());
                v.extend_from_slice(fragment);
                return v;
            }
            Segment::Ack {
                session,
                receiver,
                msg_id,
                count,
                next,
                bitmap,
            } => {
                v.push(ACK);
                push_session(&mut v, *session);
                push_session(&mut v, *receiver);
                v.push(*msg_id);
                v.extend_from_slice(&count.to_le_bytes());
                v.extend_from_slice(&next.to_le_bytes());
                v.extend_from_slice(&bitmap.to_le_bytes());
            }
            Segment::Fail { session, msg_id } => {
                v.push(FAIL);
                push_session(&mut v, *session);
                v.push(*msg_id);
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

/// The sending half: one message at a time, of one session.
#[derive(Debug)]
pub struct Sender {
    cfg: Config,
    session: SessionId,
    /// The receiver session whose ACKs count.
    peer: Option<SessionId>,
    /// Receiver sessions replaced by a newer one: their late ACKs are ignored.
    retired: VecDeque<SessionId>,
    msg_id: u8,
    /// Message ids go up by this much: lanes of one session share the id
    /// space, each with its own residue.
    id_step: u8,
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
    /// An idle sender of `session`; its message ids start at 1.
    pub fn new(cfg: Config, session: SessionId) -> Self {
        Self::lane(cfg, session, 0, 1)
    }

    /// Sender `lane` of `lanes` sharing `session`: its message ids are
    /// `lane + k·lanes` (k ≥ 1) modulo 256, so no two lanes ever use the
    /// same id and the receiver needs nothing new to keep their messages
    /// apart. `lanes` is rounded up to a power of two, so ids keep their
    /// lane when they wrap.
    pub fn lane(cfg: Config, session: SessionId, lane: u8, lanes: u8) -> Self {
        let lanes = lanes.max(1).next_power_of_two();
        Sender {
            cfg,
            session,
            peer: None,
            retired: VecDeque::new(),
            msg_id: lane % lanes,
            id_step: lanes,
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

    /// The receiver session whose ACKs this sender trusts (the last heard).
    pub fn receiver(&self) -> Option<SessionId> {
        self.peer
    }

    /// The time allowed for the messages started from now on.
    pub fn set_deadline(&mut self, deadline: Micros) {
        self.cfg.deadline = deadline;
    }

    /// Starts sending `message` at `now`.
    pub fn start(&mut self, message: &[u8], now: Micros) -> Result<u8, ArqError> {
        if self.state == SendState::Sending {
            return Err(ArqError::Busy);
        }
        let frag = self.cfg.fragment_size();
        let total = message.len() + 4;
        let count = total.div_ceil(frag).max(1);
        if count > u16::MAX as usize || message.len() > self.cfg.max_message {
            return Err(ArqError::TooLarge);
        }
        self.msg_id = self.msg_id.wrapping_add(self.id_step);
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

    /// Fragments of the current message acknowledged, and how many it has.
    pub fn progress(&self) -> (usize, usize) {
        (self.acked.iter().filter(|&&a| a).count(), self.count)
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
            session: self.session,
            msg_id: self.msg_id,
            index: i as u16,
            last: i + 1 == self.count,
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
                    session: self.session,
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

    /// Takes an incoming ACK or FAIL segment into account; those of other
    /// sessions, other messages and retired receivers are ignored.
    pub fn on_segment(&mut self, seg: &Segment, now: Micros) {
        if self.state != SendState::Sending {
            return;
        }
        let (receiver, count, next, bitmap) = match *seg {
            Segment::Ack {
                session,
                receiver,
                msg_id,
                count,
                next,
                bitmap,
            } if session == self.session && msg_id == self.msg_id => {
                (receiver, count as usize, next as usize, bitmap)
            }
            Segment::Fail { session, msg_id }
                if session == self.session && msg_id == self.msg_id =>
            {
                self.state = SendState::Failed(ArqError::Aborted);
                return;
            }
            _ => return,
        };
        if !self.trust(receiver) {
            return;
        }
        let mut highest = None;
        let newly: Vec<usize> = (0..self.count)
            .filter(|&i| covers(next, bitmap, i) && !self.acked[i])
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
            // Delivered only when the receiver itself says it holds every
            // fragment of a message whose count it knows: it then has checked
            // and handed up the message.
            if count == self.count && next == self.count {
                self.state = SendState::Done;
                return;
            }
            // It holds less than its earlier ACKs said (it dropped the
            // partial message), or it does not know the count (the last
            // fragment's mark was damaged): resend what this ACK does not
            // cover, and the last fragment, which tells the count.
            let last = self.count - 1;
            for i in 0..self.count {
                if !covers(next, bitmap, i) || (i == last && count != self.count) {
                    self.acked[i] = false;
                    self.sent_at[i] = None;
                    // An entry left from before it was acknowledged sends it already.
                    if !self.queue.contains(&i) {
                        self.queue.push_back(i);
                    }
                }
            }
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

    /// Whether ACKs of `receiver` count. A receiver session not heard
    /// before replaces the current one: the receiver restarted and holds
    /// nothing of what the old one acknowledged, so that is sent again.
    fn trust(&mut self, receiver: SessionId) -> bool {
        if self.peer == Some(receiver) {
            return true;
        }
        if self.retired.contains(&receiver) {
            return false;
        }
        if let Some(old) = self.peer.replace(receiver) {
            if self.retired.len() == REMEMBERED_SESSIONS {
                self.retired.pop_front();
            }
            self.retired.push_back(old);
            for i in 0..self.next_new {
                if self.acked[i] {
                    self.acked[i] = false;
                    self.sent_at[i] = None;
                    self.queue.push_back(i);
                }
            }
        }
        true
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

/// Whether an ACK of `next` and `bitmap` says fragment `i` arrived.
fn covers(next: usize, bitmap: u32, i: usize) -> bool {
    i < next || (i > next && i - next - 1 < 32 && bitmap >> (i - next - 1) & 1 == 1)
}

struct Pending {
    /// The fragment count, once the last fragment told it.
    count: Option<usize>,
    /// The fragments heard, up to the highest index heard.
    frags: Vec<Option<Vec<u8>>>,
    received: usize,
    since_ack: usize,
    last_seen: Micros,
}

impl Pending {
    fn new(now: Micros) -> Self {
        Pending {
            count: None,
            frags: Vec::new(),
            received: 0,
            since_ack: 0,
            last_seen: now,
        }
    }

    /// Whether fragment `index` (`last` if it is the final one) fits what
    /// this message already told of itself: not beyond its count, and not
    /// a second, different final fragment.
    fn consistent(&self, index: usize, last: bool) -> bool {
        match self.count {
            Some(count) => index < count && (!last || index + 1 == count),
            None => !last || index + 1 >= self.frags.len(),
        }
    }
}

/// What the receiver hands up.
pub type Delivery = Result<Vec<u8>, (u8, ArqError)>;

/// A message of a peer session.
type MsgKey = (SessionId, u8);

/// The receiving half: reassembles several messages, acknowledges, delivers.
pub struct Receiver {
    cfg: Config,
    session: SessionId,
    /// Peer sessions with state here, the most recently heard first.
    peers: VecDeque<SessionId>,
    pending: BTreeMap<MsgKey, Pending>,
    /// The last delivered messages and their fragment counts.
    recent: VecDeque<(MsgKey, u16)>,
    /// DATA segments received, and those among them already held.
    segments: u64,
    duplicates: u64,
}

impl Receiver {
    /// An empty receiver whose ACKs name its own `session`.
    pub fn new(cfg: Config, session: SessionId) -> Self {
        Receiver {
            cfg,
            session,
            peers: VecDeque::new(),
            pending: BTreeMap::new(),
            recent: VecDeque::new(),
            segments: 0,
            duplicates: 0,
        }
    }

    /// Notes that `peer` was heard; a peer session beyond the last
    /// [`REMEMBERED_SESSIONS`] heard is forgotten with all its state.
    fn hear(&mut self, peer: SessionId) {
        if let Some(i) = self.peers.iter().position(|&p| p == peer) {
            self.peers.remove(i);
        }
        self.peers.push_front(peer);
        if self.peers.len() > REMEMBERED_SESSIONS {
            let gone = self.peers.pop_back();
            self.pending.retain(|(s, _), _| Some(*s) != gone);
            self.recent.retain(|((s, _), _)| Some(*s) != gone);
        }
    }

    /// Duplicate DATA segments dropped so far.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }

    /// DATA segments received so far, duplicates included.
    pub fn segments(&self) -> u64 {
        self.segments
    }

    /// The share of the DATA segments received that were retransmissions
    /// of a fragment already held (`None` before the first). The receiver
    /// sees only those: a retransmission of a fragment that was lost looks
    /// like a first copy, so this is a lower bound of the sender's
    /// retransmission rate, and exactly the airtime wasted on copies.
    pub fn duplicate_rate(&self) -> Option<f64> {
        (self.segments > 0).then(|| self.duplicates as f64 / self.segments as f64)
    }

    /// Names `session` in the ACKs from now on (a new handshake opened a new
    /// session of this endpoint); what it holds of its peers is kept.
    pub fn renew(&mut self, session: SessionId) {
        self.session = session;
    }

    fn ack(&self, (session, msg_id): MsgKey, p: &Pending) -> Vec<u8> {
        let next = p
            .frags
            .iter()
            .position(Option::is_none)
            .unwrap_or(p.frags.len());
        let mut bitmap = 0u32;
        for i in 0..32 {
            if p.frags.get(next + 1 + i).is_some_and(Option::is_some) {
                bitmap |= 1 << i;
            }
        }
        Segment::Ack {
            session,
            receiver: self.session,
            msg_id,
            count: p.count.unwrap_or(0) as u16,
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
            Segment::Fail { session, msg_id } => {
                let known = self.pending.remove(&(session, msg_id)).is_some();
                (None, known.then_some(Err((msg_id, ArqError::Aborted))))
            }
            Segment::Data {
                session,
                msg_id,
                index,
                last,
                fragment,
            } => {
                self.hear(session);
                self.on_data((session, msg_id), index as usize, last, fragment, now)
            }
            Segment::Ack { .. } => (None, None),
        }
    }

    fn on_data(
        &mut self,
        key: MsgKey,
        index: usize,
        last: bool,
        fragment: &[u8],
        now: Micros,
    ) -> (Option<Vec<u8>>, Option<Delivery>) {
        let (session, msg_id) = key;
        self.segments += 1;
        if let Some(&(_, c)) = self.recent.iter().find(|(k, _)| *k == key) {
            // Already delivered: the sender missed our final ACK.
            self.duplicates += 1;
            return (
                Some(
                    Segment::Ack {
                        session,
                        receiver: self.session,
                        msg_id,
                        count: c,
                        next: c,
                        bitmap: 0,
                    }
                    .emit(),
                ),
                None,
            );
        }
        let frag = self.cfg.fragment_size();
        if fragment.len() > frag || index * frag > self.cfg.max_message + 4 {
            return (None, None);
        }
        if !self.pending.contains_key(&key) {
            while self.pending.len() >= self.cfg.max_pending {
                let oldest = *self
                    .pending
                    .iter()
                    .min_by_key(|(_, p)| p.last_seen)
                    .expect("non-empty")
                    .0;
                self.pending.remove(&oldest);
            }
            self.pending.insert(key, Pending::new(now));
        }
        let p = self.pending.get_mut(&key).expect("inserted");
        if !p.consistent(index, last) {
            // Two fragments disagree on where the message ends: one of them
            // was damaged past the transport's check, or this id is reused by
            // a new message while an old partial one lingers. Start again
            // from this fragment; the sender resends what is missing.
            *p = Pending::new(now);
        }
        p.last_seen = now;
        if last {
            p.count = Some(index + 1);
        }
        if p.frags.len() <= index {
            p.frags.resize(index + 1, None);
        }
        let duplicate = p.frags[index].is_some();
        let mut gap = false;
        if duplicate {
            self.duplicates += 1;
        } else {
            // A gap: the fragment before this one is missing. (Not "any
            // earlier one": an ACK for every fragment until a hole fills
            // drives the sender's RTO below the every-`ack_every` cadence;
            // see the doc.)
            gap = index > 0 && p.frags[index - 1].is_none();
            p.frags[index] = Some(fragment.to_vec());
            p.received += 1;
            p.since_ack += 1;
        }
        // A duplicate may still complete the message: the first copy of the
        // last fragment may have lost its mark.
        if Some(p.received) != p.count {
            let due = duplicate || gap || last || p.since_ack >= self.cfg.ack_every;
            if due {
                p.since_ack = 0;
            }
            let p = &self.pending[&key];
            return (due.then(|| self.ack(key, p)), None);
        }
        let p = self.pending.remove(&key).expect("present");
        let ack = self.ack(key, &p);
        let count = p.frags.len() as u16;
        let mut data: Vec<u8> = p.frags.into_iter().flatten().flatten().collect();
        if data.len() < 4 {
            return (
                Some(Segment::Fail { session, msg_id }.emit()),
                Some(Err((msg_id, ArqError::Corrupt))),
            );
        }
        let crc = u32::from_le_bytes(data[data.len() - 4..].try_into().expect("4 bytes"));
        data.truncate(data.len() - 4);
        if crc32(&data) != crc {
            return (
                Some(Segment::Fail { session, msg_id }.emit()),
                Some(Err((msg_id, ArqError::Corrupt))),
            );
        }
        self.recent.push_back((key, count));
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
            .map(|(&key, _)| key)?;
        self.pending.remove(&expired);
        Some(Err((expired.1, ArqError::ReassemblyTimeout)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
