//! A blocking message endpoint: the ARQ machines driven over a
//! [`Transport`] with the real clock. Both directions share one endpoint,
//! so a side can send messages and receive messages at the same time.
//! Each endpoint is one session: its id is drawn from the OS RNG when it is
//! made, so a restarted process is never taken for the one before. With
//! keys ([`Endpoint::with_keys`], in [`sealed`]) every message is sealed by
//! the secure layer and each handshake opens a new session.
//!
//! Outgoing messages take one of two [`Lane`]s, each its own ARQ sender in
//! the one session: a depth report on the urgent lane goes ahead of the
//! fragments of a frame still queued on the bulk lane, so it never waits
//! for a 30 kB frame.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rand::rngs::OsRng;
use rand::RngCore;

use crate::arq::{ArqError, Config, Micros, Receiver, Segment, SendState, Sender, SessionId};
use crate::secure::{Channel, SecureError};
use crate::transport::{LinkStats, Notice, Transport};

mod sealed;

/// Everything that can end a send or receive.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The transport failed.
    #[error("link I/O error: {0}")]
    Io(std::io::Error),
    /// The protocol gave up (deadline, abort, corruption, reassembly timeout).
    #[error("{0}")]
    Arq(ArqError),
    /// Nothing arrived in time.
    #[error("timed out waiting for a message")]
    Timeout,
    /// Nothing at all came back from the peer before the message deadline.
    #[error(
        "no answer from the peer: nothing came back in {:.0} s, the message deadline",
        .0.as_secs_f64()
    )]
    NoAnswer(Duration),
    /// No secure session could be set up with the peer.
    #[error("{0}")]
    Secure(SecureError),
    /// The peer answered no handshake before the message deadline.
    #[error(
        "no secure session: the peer answered no handshake in {:.0} s \
         (is it running with the matching --key/--peer-key pair?)",
        .0.as_secs_f64()
    )]
    NoHandshake(Duration),
}

impl From<std::io::Error> for LinkError {
    fn from(e: std::io::Error) -> Self {
        LinkError::Io(e)
    }
}

/// What sending one message took.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SendStats {
    /// Message bytes.
    pub bytes: u64,
    /// DATA segments sent.
    pub segments: u64,
    /// Retransmitted segments.
    pub retransmissions: u64,
    /// Time until every fragment was acknowledged.
    pub elapsed: Duration,
}

impl SendStats {
    /// Message bits per second.
    pub fn goodput_bps(&self) -> f64 {
        self.bytes as f64 * 8.0 / self.elapsed.as_secs_f64().max(1e-9)
    }
}

/// Called once, with how long the peer has been silent, when a message has
/// waited that long with nothing heard back (see [`Endpoint::on_silence`]).
pub type SilenceNotice = Box<dyn FnOnce(Duration)>;

/// Where a message being sent stands (see [`Endpoint::on_progress`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Progress {
    /// Fragments acknowledged so far.
    pub acked: usize,
    /// Fragments of the message.
    pub fragments: usize,
    /// Message bytes.
    pub bytes: u64,
    /// Retransmitted segments so far.
    pub retransmissions: u64,
    /// Time since the send began.
    pub elapsed: Duration,
}

impl Progress {
    /// Acknowledged message bits per second so far.
    pub fn goodput_bps(&self) -> f64 {
        let done = self.bytes as f64 * self.acked as f64 / self.fragments.max(1) as f64;
        done * 8.0 / self.elapsed.as_secs_f64().max(1e-9)
    }
}

/// Called with the progress of a message being sent ([`Endpoint::on_progress`]).
pub type ProgressReport = Box<dyn FnMut(&Progress)>;

/// Called with each notice of the transport ([`Endpoint::on_notice`]).
pub type NoticeReport = Box<dyn FnMut(Notice)>;

/// How often [`Endpoint::on_progress`]'s callback is called during a send.
pub const PROGRESS_EVERY: Duration = Duration::from_millis(200);

/// Which of an endpoint's senders carries a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lane {
    /// Large messages (frames), one at a time.
    Bulk,
    /// Small, urgent messages (depth reports): their segments go first.
    Urgent,
}

impl Lane {
    const ALL: [Lane; 2] = [Lane::Bulk, Lane::Urgent];

    fn index(self) -> usize {
        self as usize
    }
}

/// How a send on a lane ended.
pub type SendOutcome = (Lane, Result<SendStats, LinkError>);

/// A message endpoint over a transport.
pub struct Endpoint {
    transport: Box<dyn Transport>,
    cfg: Config,
    session: SessionId,
    /// One sender per [`Lane`], in `Lane::ALL` order.
    senders: [Sender; 2],
    /// When the message on each lane began, while one is being sent.
    started: [Option<Instant>; 2],
    /// Sends that ended and were not yet taken.
    ended: VecDeque<SendOutcome>,
    /// With keys: each lane's message in the clear and the peer session it
    /// was sealed for, so that it can be sent again under a new handshake.
    sealed_for: [Option<(Vec<u8>, Option<SessionId>)>; 2],
    /// Sealed messages a restarted peer could not open, to send again (with
    /// when they were first submitted).
    resend: VecDeque<(Lane, Vec<u8>, Instant)>,
    last_progress: Instant,
    receiver: Receiver,
    epoch: Instant,
    /// Messages the ARQ delivered, with the peer session they came from.
    inbox: VecDeque<(SessionId, Vec<u8>, Held)>,
    /// With keys: the secure channel, and the messages it opened.
    secure: Option<Channel>,
    opened: VecDeque<(Vec<u8>, Held)>,
    /// The held ACKs of messages handed up: sent when the layer above asks
    /// again ([`Endpoint::recv_message`], [`Endpoint::linger`]), that is,
    /// once it has dealt with them.
    handed: Vec<Held>,
    failures: VecDeque<ArqError>,
    /// When a valid segment last arrived.
    last_heard: Option<Instant>,
    silence: Option<(Duration, SilenceNotice)>,
    progress: Option<ProgressReport>,
    notices: Option<NoticeReport>,
}

/// A message's key, the ACK that completed it (empty once sent) and when it
/// arrived: held until the layer above has dealt with the message, or for
/// at most [`HOLD_MAX`].
type Held = (MsgKey, Vec<u8>, Instant);

/// The longest an ACK is held for a layer above that is slow to ask again
/// (the board takes a few hundred ms a frame): the sender must not time out.
const HOLD_MAX: Duration = Duration::from_secs(1);

/// A message of a peer session.
type MsgKey = (SessionId, u8);

/// Longest single wait inside the loops, so timers and peers are served.
const TICK: Duration = Duration::from_millis(20);

impl Endpoint {
    /// An endpoint with the default protocol parameters for the transport's
    /// MTU; fails only when the OS has no randomness for the session id.
    pub fn new(transport: Box<dyn Transport>) -> std::io::Result<Self> {
        let cfg = Config::for_mtu(transport.mtu());
        Self::with_config(transport, cfg)
    }

    /// An endpoint with explicit protocol parameters and a fresh session.
    /// Where the transport knows its radio's pace, the first retransmission
    /// timeout is seeded from it ([`Config::with_packet_time`]).
    pub fn with_config(transport: Box<dyn Transport>, cfg: Config) -> std::io::Result<Self> {
        let cfg = match transport.packet_time() {
            Some(t) => cfg.with_packet_time(t.as_micros() as Micros),
            None => cfg,
        };
        let session = fresh_session()?;
        Ok(Endpoint {
            transport,
            cfg,
            session,
            senders: [0, 1].map(|lane| Sender::lane(cfg, session, lane, 2)),
            started: [None; 2],
            ended: VecDeque::new(),
            sealed_for: [None, None],
            resend: VecDeque::new(),
            last_progress: Instant::now(),
            receiver: Receiver::new(cfg, session),
            epoch: Instant::now(),
            inbox: VecDeque::new(),
            secure: None,
            opened: VecDeque::new(),
            handed: Vec::new(),
            failures: VecDeque::new(),
            last_heard: None,
            silence: None,
            progress: None,
            notices: None,
        })
    }

    /// This endpoint's current session (with keys, the one of its last handshake).
    pub fn session(&self) -> SessionId {
        self.session
    }

    /// Calls `notice` once, the first time a message being sent has heard
    /// nothing from the peer for `after` (the peer is absent or the link is
    /// misconfigured); the send goes on retrying until its deadline.
    pub fn on_silence(&mut self, after: Duration, notice: SilenceNotice) {
        self.silence = Some((after, notice));
    }

    /// Calls `report` every [`PROGRESS_EVERY`] while a message is sent, and
    /// once when it is done.
    pub fn on_progress(&mut self, report: ProgressReport) {
        self.progress = Some(report);
    }

    /// Passes on what the transport has to say about the link ([`Notice`]);
    /// without a callback the notices are dropped.
    pub fn on_notice(&mut self, notice: NoticeReport) {
        self.notices = Some(notice);
    }

    /// What the transport measured (damaged frames, the radio's statuses).
    pub fn link_stats(&self) -> LinkStats {
        self.transport.stats()
    }

    /// The air time one full packet takes, where the transport knows its
    /// radio's pace.
    pub fn packet_time(&self) -> Option<Duration> {
        self.transport.packet_time()
    }

    /// The transport's description.
    pub fn describe(&self) -> String {
        self.transport.describe()
    }

    fn now(&self) -> Micros {
        self.epoch.elapsed().as_micros() as Micros
    }

    /// Handles one incoming packet; damaged or foreign packets are dropped.
    fn handle(&mut self, packet: &[u8]) -> Result<(), LinkError> {
        let Some(seg) = Segment::parse(packet) else {
            return Ok(());
        };
        self.last_heard = Some(Instant::now());
        let now = self.now();
        match seg {
            Segment::Ack { .. } => self
                .senders
                .iter_mut()
                .for_each(|s| s.on_segment(&seg, now)),
            Segment::Data { .. } | Segment::Fail { .. } => {
                self.senders
                    .iter_mut()
                    .for_each(|s| s.on_segment(&seg, now));
                let key = match seg {
                    Segment::Data {
                        session, msg_id, ..
                    } => Some((session, msg_id)),
                    _ => None,
                };
                let (ack, delivery) = self.receiver.on_segment(&seg, now);
                match (delivery, key) {
                    // The ACK that completes a message waits until the layer
                    // above has taken it and dealt with it.
                    (Some(Ok(m)), Some(key)) => {
                        let held = (key, ack.unwrap_or_default(), Instant::now());
                        self.inbox.push_back((key.0, m, held));
                        return Ok(());
                    }
                    (Some(Err((_, e))), _) => self.failures.push_back(e),
                    _ => {}
                }
                if let Some(a) = ack.filter(|_| !key.is_some_and(|k| self.holds(k))) {
                    self.transport.send(&a)?;
                }
            }
        }
        Ok(())
    }

    fn service(&mut self, wait: Duration) -> Result<(), LinkError> {
        let mut wait = wait;
        while let Some(p) = self.transport.recv(wait)? {
            self.handle(&p)?;
            wait = Duration::ZERO; // then drain whatever else is already there
        }
        if let Some(Err((_, e))) = self.receiver.poll(self.now()) {
            self.failures.push_back(e);
        }
        self.release_overdue()?;
        let notices = self.transport.take_notices();
        if let Some(say) = self.notices.as_mut() {
            notices.into_iter().for_each(say);
        }
        Ok(())
    }

    fn report_progress(&mut self, start: Instant) {
        if let Some(report) = self.progress.as_mut() {
            let bulk = &self.senders[Lane::Bulk.index()];
            let (acked, fragments) = bulk.progress();
            let c = bulk.counters();
            report(&Progress {
                acked,
                fragments,
                bytes: c.message_bytes,
                retransmissions: c.retransmissions,
                elapsed: start.elapsed(),
            });
        }
    }

    /// The largest message that crosses the link in one packet: one DATA
    /// segment, less the message's CRC-32 and, with keys, the secure layer's
    /// counter and tag. A depth report of at most this many bytes costs the
    /// radio one packet (and one ACK).
    pub fn one_packet_message(&self) -> usize {
        let sealing = if self.secure.is_some() {
            crate::secure::wire::OVERHEAD
        } else {
            0
        };
        self.cfg.fragment_size().saturating_sub(4 + sealing)
    }

    /// Starts sending `message` on `lane` (sealed, with keys: after a
    /// handshake when one is due and both lanes are idle);
    /// [`Endpoint::poll_sends`] drives it. A lane carries one message at a
    /// time ([`ArqError::Busy`]).
    pub fn submit(&mut self, lane: Lane, message: &[u8]) -> Result<(), LinkError> {
        match self.secure {
            Some(_) => self.submit_sealed(lane, message, Instant::now()),
            None => self.submit_raw(lane, message),
        }
    }

    /// Starts sending `message` on `lane` as it is.
    fn submit_raw(&mut self, lane: Lane, message: &[u8]) -> Result<(), LinkError> {
        let now = self.now();
        self.senders[lane.index()]
            .start(message, now)
            .map_err(LinkError::Arq)?;
        self.started[lane.index()] = Some(Instant::now());
        self.sealed_for[lane.index()] = None;
        self.last_progress = Instant::now();
        Ok(())
    }

    /// Sends `message` on `lane` as it is and waits for its end.
    fn send_raw(&mut self, lane: Lane, message: &[u8]) -> Result<SendStats, LinkError> {
        self.submit_raw(lane, message)?;
        self.wait_for(lane)
    }

    /// Drives the link until the send on `lane` ended.
    fn wait_for(&mut self, lane: Lane) -> Result<SendStats, LinkError> {
        loop {
            self.drive(TICK)?;
            if let Some(i) = self.ended.iter().position(|(l, _)| *l == lane) {
                if let Some((_, result)) = self.ended.remove(i) {
                    return result;
                }
            }
        }
    }

    /// Gives up the message in flight on `lane` without waiting for its
    /// acknowledgement: it is not reported, delivered or failed, and the
    /// lane takes a new message at once (the newest depth report replacing
    /// an older one the peer may or may not have).
    pub fn abandon(&mut self, lane: Lane) {
        self.senders[lane.index()].abandon();
        self.started[lane.index()] = None;
        self.sealed_for[lane.index()] = None;
    }

    /// Whether `lane` has no message in flight.
    pub fn is_idle(&self, lane: Lane) -> bool {
        self.started[lane.index()].is_none()
    }

    /// Drives both lanes (the urgent one first) and the receiver for about
    /// `wait`; returns the sends that ended since the last call.
    pub fn poll_sends(&mut self, wait: Duration) -> Result<Vec<SendOutcome>, LinkError> {
        self.drive(wait)?;
        Ok(self.ended.drain(..).collect())
    }

    /// Sends one message on the bulk lane and waits until every fragment is
    /// acknowledged (urgent sends that end meanwhile stay for
    /// [`Endpoint::poll_sends`]).
    pub fn send_message(&mut self, message: &[u8]) -> Result<SendStats, LinkError> {
        self.submit(Lane::Bulk, message)?;
        self.wait_for(Lane::Bulk)
    }

    /// One round: transmit what the lanes have (urgent first), settle the
    /// sends that ended, say what needs saying, then wait for the next timer.
    fn drive(&mut self, wait: Duration) -> Result<(), LinkError> {
        // A paced radio takes a segment every few ms: hand back control
        // after a tick, so an urgent message can be submitted.
        let round = Instant::now();
        while round.elapsed() < TICK {
            let now = self.now();
            let [bulk, urgent] = &mut self.senders;
            let Some(seg) = urgent
                .poll_transmit(now)
                .or_else(|| bulk.poll_transmit(now))
            else {
                break;
            };
            self.transport.send(&seg)?;
            // Take in ACKs between segments, so a long send never starves them.
            self.service(Duration::ZERO)?;
        }
        for lane in Lane::ALL {
            self.settle(lane);
        }
        self.send_again()?;
        let Some(start) = self.started.iter().flatten().min().copied() else {
            return self.service(wait);
        };
        if let Some(bulk_start) = self.started[Lane::Bulk.index()] {
            if self.last_progress.elapsed() >= PROGRESS_EVERY {
                self.last_progress = Instant::now();
                self.report_progress(bulk_start);
            }
        }
        let silent = self
            .last_heard
            .filter(|&t| t >= start)
            .unwrap_or(start)
            .elapsed();
        if self
            .silence
            .as_ref()
            .is_some_and(|(after, _)| silent >= *after)
        {
            if let Some((_, notice)) = self.silence.take() {
                notice(silent);
            }
        }
        let now = self.now();
        let next = self
            .senders
            .iter()
            .filter_map(Sender::poll_at)
            .min()
            .map_or(TICK, |t| Duration::from_micros(t.saturating_sub(now)));
        self.service(next.min(TICK).min(wait))
    }

    /// Records the end of the send on `lane`, if it ended.
    fn settle(&mut self, lane: Lane) {
        let Some(start) = self.started[lane.index()] else {
            return;
        };
        let heard = self.last_heard.is_some_and(|t| t >= start);
        let sender = &self.senders[lane.index()];
        let result = match sender.state() {
            SendState::Failed(ArqError::Deadline) if !heard => {
                Err(LinkError::NoAnswer(start.elapsed()))
            }
            SendState::Failed(e) => Err(LinkError::Arq(e)),
            SendState::Done => {
                let c = sender.counters();
                let mut bytes = c.message_bytes;
                if let Some((clear, peer)) = self.sealed_for[lane.index()].take() {
                    if sender.receiver() != peer {
                        // A restarted peer acknowledged it but holds no
                        // session to open it: never report it delivered.
                        self.started[lane.index()] = None;
                        self.resend.push_back((lane, clear, start));
                        if let Some(c) = self.secure.as_mut() {
                            c.forget();
                        }
                        return;
                    }
                    bytes = clear.len() as u64;
                }
                Ok(SendStats {
                    bytes,
                    segments: c.segments,
                    retransmissions: c.retransmissions,
                    elapsed: start.elapsed(),
                })
            }
            SendState::Idle | SendState::Sending => return,
        };
        self.sealed_for[lane.index()] = None;
        if lane == Lane::Bulk && result.is_ok() {
            self.report_progress(start);
        }
        self.started[lane.index()] = None;
        self.ended.push_back((lane, result));
    }

    /// Waits up to `timeout` for the next complete message.
    /// The message handed up before was dealt with: its ACK goes now.
    pub fn recv_message(&mut self, timeout: Duration) -> Result<Vec<u8>, LinkError> {
        self.release()?;
        let until = Instant::now() + timeout;
        loop {
            if let Some(m) = self.next_message()? {
                return Ok(m);
            }
            if let Some(e) = self.failures.pop_front() {
                return Err(LinkError::Arq(e));
            }
            let now = Instant::now();
            if now >= until {
                return Err(LinkError::Timeout);
            }
            self.service((until - now).min(TICK))?;
        }
    }

    /// The next message for the layer above: as delivered, or with keys
    /// once the secure layer opened it.
    fn next_message(&mut self) -> Result<Option<Vec<u8>>, LinkError> {
        let next = match self.secure {
            None => self.inbox.pop_front().map(|(_, m, held)| (m, held)),
            Some(_) => {
                self.open_inbox()?;
                self.opened.pop_front()
            }
        };
        Ok(next.map(|(m, held)| {
            self.handed.push(held);
            m
        }))
    }

    /// Whether the ACK of message `key` is held (the message not yet dealt
    /// with above): its duplicates are not acknowledged either, so a sender
    /// never takes a message the receiving process died holding for
    /// delivered.
    fn holds(&self, key: MsgKey) -> bool {
        let held = |h: &Held| h.0 == key && !h.1.is_empty();
        self.inbox.iter().any(|(_, _, h)| held(h))
            || self.opened.iter().any(|(_, h)| held(h))
            || self.handed.iter().any(held)
    }

    /// Says that the messages handed up so far have been dealt with (shown,
    /// acted on): their held ACKs go now, rather than at the next
    /// [`Endpoint::recv_message`]. Call it before anything that should only
    /// happen once the sender can count the message delivered.
    ///
    /// # Errors
    /// If the transport fails.
    pub fn dealt_with(&mut self) -> Result<(), LinkError> {
        self.release()
    }

    /// Sends the held ACKs of the messages the layer above has dealt with.
    fn release(&mut self) -> Result<(), LinkError> {
        for (_, ack, _) in std::mem::take(&mut self.handed) {
            self.send_ack(&ack)?;
        }
        Ok(())
    }

    /// Sends the ACKs held longer than [`HOLD_MAX`].
    fn release_overdue(&mut self) -> Result<(), LinkError> {
        let Endpoint {
            inbox,
            opened,
            handed,
            transport,
            ..
        } = self;
        let held = (inbox.iter_mut().map(|(_, _, h)| h))
            .chain(opened.iter_mut().map(|(_, h)| h))
            .chain(handed.iter_mut());
        for h in held.filter(|h| !h.1.is_empty() && h.2.elapsed() >= HOLD_MAX) {
            transport.send(&std::mem::take(&mut h.1))?;
        }
        Ok(())
    }

    fn send_ack(&mut self, ack: &[u8]) -> Result<(), LinkError> {
        if !ack.is_empty() {
            self.transport.send(ack)?;
        }
        Ok(())
    }

    /// Keeps answering the peer (ACKs for retransmitted fragments) for `time`.
    pub fn linger(&mut self, time: Duration) -> Result<(), LinkError> {
        self.release()?;
        let until = Instant::now() + time;
        while Instant::now() < until {
            self.service(TICK.min(until - Instant::now()))?;
        }
        Ok(())
    }

    /// Duplicate segments the receiver dropped.
    pub fn duplicates(&self) -> u64 {
        self.receiver.duplicates()
    }

    /// DATA segments the receiver took in, duplicates included.
    pub fn segments_received(&self) -> u64 {
        self.receiver.segments()
    }

    /// The share of the DATA segments received that were duplicates
    /// ([`Receiver::duplicate_rate`]: what the receiving end can measure of
    /// the retransmissions).
    pub fn duplicate_rate(&self) -> Option<f64> {
        self.receiver.duplicate_rate()
    }
}

/// A random session id from the OS RNG.
fn fresh_session() -> std::io::Result<SessionId> {
    let mut id = [0u8; 4];
    OsRng
        .try_fill_bytes(&mut id)
        .map_err(std::io::Error::other)?;
    Ok(SessionId::from_random(u32::from_le_bytes(id)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{pair, SimConfig};

    #[test]
    fn two_threads_exchange_messages_over_a_lossy_sim_link() {
        let (a, b) = pair(
            SimConfig {
                loss: 0.1,
                seed: 4,
                ..SimConfig::default()
            },
            20.0,
        );
        let msgs: Vec<Vec<u8>> = (0..3)
            .map(|i| (0..2000 + i * 500).map(|j| (j * 31 + i) as u8).collect())
            .collect();
        let expected = msgs.clone();
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b)).unwrap();
            let got: Vec<Vec<u8>> = (0..3)
                .map(|_| e.recv_message(Duration::from_secs(20)).unwrap())
                .collect();
            e.linger(Duration::from_millis(300)).unwrap();
            got
        });
        let mut e = Endpoint::new(Box::new(a)).unwrap();
        for m in &msgs {
            let s = e.send_message(m).unwrap();
            assert_eq!(s.bytes as usize, m.len());
        }
        assert_eq!(rx.join().unwrap(), expected);
    }

    #[test]
    fn silence_is_noticed_once_and_ends_in_no_answer() {
        use crate::transport::Udp;
        let nobody = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let peer = nobody.local_addr().unwrap();
        drop(nobody);
        let udp = Udp::bind("127.0.0.1:0".parse().unwrap(), Some(peer), 100).unwrap();
        let cfg = Config {
            deadline: 1_000_000,
            ..Config::for_mtu(100)
        };
        let mut e = Endpoint::with_config(Box::new(udp), cfg).unwrap();
        let notices = std::rc::Rc::new(std::cell::Cell::new(0));
        let n = notices.clone();
        e.on_silence(
            Duration::from_millis(200),
            Box::new(move |silent| {
                assert!(silent >= Duration::from_millis(200));
                n.set(n.get() + 1);
            }),
        );
        let err = e.send_message(&[7; 500]).unwrap_err();
        assert!(matches!(err, LinkError::NoAnswer(_)), "{err}");
        // A second message heard nothing either, but the notice was once.
        assert!(matches!(
            e.send_message(&[7; 5]),
            Err(LinkError::NoAnswer(_))
        ));
        assert_eq!(notices.get(), 1);
    }

    #[test]
    fn each_endpoint_draws_its_own_session() {
        let (a, b) = pair(SimConfig::default(), 1.0);
        let (a, b) = (
            Endpoint::new(Box::new(a)).unwrap(),
            Endpoint::new(Box::new(b)).unwrap(),
        );
        assert_ne!(a.session(), b.session());
    }

    /// A report submitted on the urgent lane while a frame is in flight on
    /// the bulk lane is delivered before the frame, both intact, and each
    /// lane reports its own outcome.
    #[test]
    fn an_urgent_message_overtakes_a_frame_in_flight() {
        let (a, b) = pair(SimConfig::default(), 10.0);
        let frame: Vec<u8> = (0..20_000).map(|i| (i * 7) as u8).collect();
        let report = vec![0x5A; 300];
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b)).unwrap();
            let got: Vec<Vec<u8>> = (0..2)
                .map(|_| e.recv_message(Duration::from_secs(20)).unwrap())
                .collect();
            e.linger(Duration::from_millis(300)).unwrap();
            got
        });
        let mut e = Endpoint::new(Box::new(a)).unwrap();
        e.submit(Lane::Bulk, &frame).unwrap();
        let mut outcomes = Vec::new();
        // A few rounds into the frame, the report.
        for _ in 0..5 {
            outcomes.extend(e.poll_sends(TICK).unwrap());
        }
        assert!(!e.is_idle(Lane::Bulk), "the frame must still be in flight");
        e.submit(Lane::Urgent, &report).unwrap();
        assert!(matches!(
            e.submit(Lane::Bulk, b"another"),
            Err(LinkError::Arq(ArqError::Busy))
        ));
        while outcomes.len() < 2 {
            outcomes.extend(e.poll_sends(TICK).unwrap());
        }
        let order: Vec<Lane> = outcomes.iter().map(|(l, _)| *l).collect();
        assert_eq!(order, vec![Lane::Urgent, Lane::Bulk]);
        assert!(outcomes.iter().all(|(_, r)| r.is_ok()));
        assert_eq!(rx.join().unwrap(), vec![report, frame]);
    }

    /// A report abandoned in flight ends neither delivered nor failed; the
    /// lane takes the newer one at once, and it is delivered and reported.
    /// The receiver gets the newer one, whatever became of the older.
    #[test]
    fn an_abandoned_report_is_never_reported_and_the_newer_one_goes() {
        let cfg = SimConfig {
            radio: crate::radio::Firmware::Zigbee,
            mtu: 84,
            ..SimConfig::default()
        };
        let (a, b) = pair(cfg, 1.0);
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b)).unwrap();
            let mut got = Vec::new();
            while got.last() != Some(&vec![2u8; 40]) {
                got.push(e.recv_message(Duration::from_secs(20)).unwrap());
            }
            e.linger(Duration::from_millis(300)).unwrap();
            got
        });
        let mut e = Endpoint::new(Box::new(a)).unwrap();
        e.submit(Lane::Urgent, &[1; 40]).unwrap();
        e.abandon(Lane::Urgent);
        assert!(e.is_idle(Lane::Urgent));
        e.submit(Lane::Urgent, &[2; 40]).unwrap();
        let mut outcomes = Vec::new();
        while outcomes.is_empty() {
            outcomes.extend(e.poll_sends(TICK).unwrap());
        }
        e.linger(Duration::from_millis(300)).unwrap();
        outcomes.extend(e.poll_sends(Duration::ZERO).unwrap());
        assert_eq!(outcomes.len(), 1, "{outcomes:?}");
        assert!(matches!(&outcomes[0], (Lane::Urgent, Ok(s)) if s.bytes == 40));
        let got = rx.join().unwrap();
        assert_eq!(got.last(), Some(&vec![2u8; 40]));
        assert!(got.len() <= 2 && got.iter().all(|m| m[0] != 0));
    }

    /// A receiving process that dies holding a message it was handed (its
    /// ACK held until it asks again) never lets the sender think it was
    /// delivered: the next life gets it.
    #[test]
    fn a_message_the_receiver_died_holding_goes_to_its_next_life() {
        let (a, b) = pair(SimConfig::default(), 20.0);
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b)).unwrap();
            let first = e.recv_message(Duration::from_secs(20)).unwrap();
            // Dies while dealing with it: no further call, no ACK.
            let Endpoint { transport, .. } = e;
            let mut e = Endpoint::new(transport).unwrap();
            let again = e.recv_message(Duration::from_secs(20)).unwrap();
            e.linger(Duration::from_millis(300)).unwrap();
            (first, again)
        });
        let mut e = Endpoint::new(Box::new(a)).unwrap();
        let message = vec![0x3C; 900];
        e.send_message(&message).unwrap();
        let (first, again) = rx.join().unwrap();
        assert_eq!((first, again), (message.clone(), message));
    }
}
