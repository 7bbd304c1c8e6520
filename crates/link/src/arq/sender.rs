//! The sending half of the ARQ: one message at a time cut into fragments,
//! a window of them in flight, retransmission on timeout or at a gap, and
//! the rules for which ACKs count. Its own module because the two
//! halves share only the segment format, [`Config`] and [`ArqError`].

use alloc::collections::VecDeque;
use alloc::vec;
use alloc::vec::Vec;

use super::timer::RetransmitTimer;
use super::wire::{covers, Segment, SessionId};
use super::{ArqError, Config, Micros, REMEMBERED_SESSIONS};
use crate::crc::crc32;

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
    timer: RetransmitTimer,
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
            timer: RetransmitTimer::new(&cfg),
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

    /// Gives up the message in flight, unacknowledged, so that a newer one
    /// can start at once (a depth report overtaken by the next pair's). Its
    /// late ACKs are ignored: they name an id that is no longer current.
    pub fn abandon(&mut self) {
        if self.state == SendState::Sending {
            self.queue.clear();
            self.state = SendState::Idle;
        }
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
        self.timer.rto()
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
            tracing::warn!(
                msg_id = self.msg_id,
                "message given up: its deadline passed"
            );
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
            let Some(sent) = self.sent_at[i] else {
                continue;
            };
            if !self.acked[i] && now >= self.timer.expires_at(sent) && !self.queue.contains(&i) {
                tracing::debug!(
                    msg_id = self.msg_id,
                    fragment = i,
                    rto_us = self.timer.rto(),
                    "no ACK within the RTO: resend, back off"
                );
                self.timer.on_expired(sent, now);
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
            .filter_map(|(t, _)| t.map(|t| self.timer.expires_at(t)))
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
            self.timer.on_acked(self.tries[i], self.sent_at[i], now);
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
                    tracing::debug!(
                        msg_id = self.msg_id,
                        fragment = i,
                        acked_later = h,
                        "a gap below an acknowledged fragment: resend"
                    );
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
            tracing::debug!(
                msg_id = self.msg_id,
                "a new receiver session: what the old one acknowledged goes again"
            );
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
}
