//! A blocking message endpoint: the ARQ machines driven over a
//! [`Transport`] with the real clock. Both directions share one endpoint,
//! so a side can send messages and receive messages at the same time.
//! Each endpoint is one session: its id is drawn from the OS RNG when it is
//! made, so a restarted process is never taken for the one before. With
//! keys ([`Endpoint::with_keys`], in [`sealed`]) every message is sealed by
//! the secure layer and each handshake opens a new session.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rand::rngs::OsRng;
use rand::RngCore;

use crate::arq::{ArqError, Config, Micros, Receiver, Segment, SendState, Sender, SessionId};
use crate::secure::{Channel, SecureError};
use crate::transport::Transport;

mod sealed;

/// Everything that can end a send or receive.
#[derive(Debug)]
pub enum LinkError {
    /// The transport failed.
    Io(std::io::Error),
    /// The protocol gave up (deadline, abort, corruption, reassembly timeout).
    Arq(ArqError),
    /// Nothing arrived in time.
    Timeout,
    /// Nothing at all came back from the peer before the message deadline.
    NoAnswer(Duration),
    /// No secure session could be set up with the peer.
    Secure(SecureError),
    /// The peer answered no handshake before the message deadline.
    NoHandshake(Duration),
}

impl std::fmt::Display for LinkError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LinkError::Io(e) => write!(f, "link I/O error: {e}"),
            LinkError::Arq(e) => write!(f, "{e}"),
            LinkError::Timeout => write!(f, "timed out waiting for a message"),
            LinkError::NoAnswer(d) => write!(
                f,
                "no answer from the peer: nothing came back in {:.0} s, the message deadline",
                d.as_secs_f64()
            ),
            LinkError::Secure(e) => write!(f, "{e}"),
            LinkError::NoHandshake(d) => write!(
                f,
                "no secure session: the peer answered no handshake in {:.0} s \
                 (is it running with the matching --key/--peer-key pair?)",
                d.as_secs_f64()
            ),
        }
    }
}

impl std::error::Error for LinkError {}

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

/// A message endpoint over a transport.
pub struct Endpoint {
    transport: Box<dyn Transport>,
    cfg: Config,
    session: SessionId,
    sender: Sender,
    receiver: Receiver,
    epoch: Instant,
    /// Messages the ARQ delivered, with the peer session they came from.
    inbox: VecDeque<(SessionId, Vec<u8>)>,
    /// With keys: the secure channel, and the messages it opened.
    secure: Option<Channel>,
    opened: VecDeque<Vec<u8>>,
    failures: VecDeque<ArqError>,
    /// When a valid segment last arrived.
    last_heard: Option<Instant>,
    silence: Option<(Duration, SilenceNotice)>,
}

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
    pub fn with_config(transport: Box<dyn Transport>, cfg: Config) -> std::io::Result<Self> {
        let session = fresh_session()?;
        Ok(Endpoint {
            transport,
            cfg,
            session,
            sender: Sender::new(cfg, session),
            receiver: Receiver::new(cfg, session),
            epoch: Instant::now(),
            inbox: VecDeque::new(),
            secure: None,
            opened: VecDeque::new(),
            failures: VecDeque::new(),
            last_heard: None,
            silence: None,
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
            Segment::Ack { .. } => self.sender.on_segment(&seg, now),
            Segment::Data { .. } | Segment::Fail { .. } => {
                self.sender.on_segment(&seg, now);
                let (ack, delivery) = self.receiver.on_segment(&seg, now);
                if let Some(a) = ack {
                    self.transport.send(&a)?;
                }
                match (delivery, &seg) {
                    (Some(Ok(m)), Segment::Data { session, .. }) => {
                        self.inbox.push_back((*session, m))
                    }
                    (Some(Err((_, e))), _) => self.failures.push_back(e),
                    _ => {}
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
        Ok(())
    }

    /// Sends one message (sealed, with keys) and waits until every fragment
    /// is acknowledged.
    pub fn send_message(&mut self, message: &[u8]) -> Result<SendStats, LinkError> {
        match self.secure {
            Some(_) => self.send_sealed(message),
            None => self.send_raw(message),
        }
    }

    /// Sends `message` as it is.
    fn send_raw(&mut self, message: &[u8]) -> Result<SendStats, LinkError> {
        let start = Instant::now();
        self.sender
            .start(message, self.now())
            .map_err(LinkError::Arq)?;
        loop {
            while let Some(seg) = self.sender.poll_transmit(self.now()) {
                self.transport.send(&seg)?;
                // Take in ACKs between segments, so a long send never starves them.
                self.service(Duration::ZERO)?;
            }
            let heard = self.last_heard.filter(|&t| t >= start);
            match self.sender.state() {
                SendState::Failed(ArqError::Deadline) if heard.is_none() => {
                    return Err(LinkError::NoAnswer(start.elapsed()))
                }
                SendState::Done => {
                    let c = self.sender.counters();
                    return Ok(SendStats {
                        bytes: c.message_bytes,
                        segments: c.segments,
                        retransmissions: c.retransmissions,
                        elapsed: start.elapsed(),
                    });
                }
                SendState::Failed(e) => return Err(LinkError::Arq(e)),
                SendState::Idle | SendState::Sending => {}
            }
            let silent = heard.unwrap_or(start).elapsed();
            if self
                .silence
                .as_ref()
                .is_some_and(|(after, _)| silent >= *after)
            {
                if let Some((_, notice)) = self.silence.take() {
                    notice(silent);
                }
            }
            let wait = self
                .sender
                .poll_at()
                .map_or(TICK, |t| {
                    Duration::from_micros(t.saturating_sub(self.now()))
                })
                .min(TICK);
            self.service(wait)?;
        }
    }

    /// Waits up to `timeout` for the next complete message.
    pub fn recv_message(&mut self, timeout: Duration) -> Result<Vec<u8>, LinkError> {
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
        if self.secure.is_none() {
            return Ok(self.inbox.pop_front().map(|(_, m)| m));
        }
        self.open_inbox()?;
        Ok(self.opened.pop_front())
    }

    /// Keeps answering the peer (ACKs for retransmitted fragments) for `time`.
    pub fn linger(&mut self, time: Duration) -> Result<(), LinkError> {
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
}

/// A random session id from the OS RNG.
fn fresh_session() -> std::io::Result<SessionId> {
    let mut id = [0u8; 4];
    OsRng
        .try_fill_bytes(&mut id)
        .map_err(std::io::Error::other)?;
    Ok(SessionId(u32::from_le_bytes(id)))
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
}
