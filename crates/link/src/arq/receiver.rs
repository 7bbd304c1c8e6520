//! The receiving half of the ARQ: reassembly of several messages keyed by
//! (sender session, message id), duplicate suppression, ACKs and the CRC-32
//! check before a message is handed up. Its own module because the two
//! halves share only the segment format, [`Config`] and [`ArqError`].

use alloc::collections::{BTreeMap, VecDeque};
use alloc::vec::Vec;

use super::wire::{Segment, SessionId};
use super::{ArqError, Config, Micros, REMEMBERED_SESSIONS};
use crate::crc::crc32;

pub(super) struct Pending {
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
pub(super) type MsgKey = (SessionId, u8);

/// The receiving half: reassembles several messages, acknowledges, delivers.
pub struct Receiver {
    cfg: Config,
    session: SessionId,
    /// Peer sessions with state here, the most recently heard first.
    pub(super) peers: VecDeque<SessionId>,
    pub(super) pending: BTreeMap<MsgKey, Pending>,
    /// The last delivered messages and their fragment counts.
    pub(super) recent: VecDeque<(MsgKey, u16)>,
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
