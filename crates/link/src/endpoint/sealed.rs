//! The endpoint with keys: every message goes through the secure
//! [`Channel`]. Before sealing, a handshake runs when there is no session or
//! it is due for a rekey (and both lanes are idle); each handshake first
//! opens a fresh ARQ session of this endpoint for both lanes, so the ARQ
//! session and the Noise session begin and end together. A message whose ACKs came from a receiver session other than
//! the handshake's peer reached a restarted peer that could not open it: it
//! is sent again under a new handshake, never reported delivered.

use std::time::{Duration, Instant};

use super::{fresh_session, Endpoint, Lane, LinkError, TICK};
use crate::arq::{ArqError, Sender};
use crate::secure::{Channel, Keys, Opened, Rejections, SecureConfig};

/// How long a handshake waits for its RESPONSE before starting over.
const HANDSHAKE_WAIT: Duration = Duration::from_secs(3);

/// How long a RESPONSE is retransmitted: a replayed INIT, whose sender is
/// gone, costs the responder at most this, not a whole message deadline.
const RESPONSE_DEADLINE: Duration = Duration::from_secs(3);

impl Endpoint {
    /// Seals every message with the paired `keys` (see [`crate::secure`]).
    pub fn with_keys(mut self, keys: Keys, cfg: SecureConfig) -> Self {
        self.secure = Some(Channel::new(keys, cfg));
        self
    }

    /// Messages the secure layer refused, by cause (`None` without keys).
    pub fn rejections(&self) -> Option<Rejections> {
        self.secure.as_ref().map(Channel::rejections)
    }

    /// Seals `message` and starts it on `lane`, after a handshake if one is
    /// due and both lanes are idle (a handshake opens a new ARQ session, so
    /// it waits for the lanes; until then a due rekey seals under the
    /// current session). `start` is when the message was first submitted.
    pub(super) fn submit_sealed(
        &mut self,
        lane: Lane,
        message: &[u8],
        start: Instant,
    ) -> Result<(), LinkError> {
        if !self.is_idle(lane) {
            return Err(LinkError::Arq(ArqError::Busy));
        }
        if Lane::ALL.iter().all(|&l| self.is_idle(l)) {
            self.ensure_session(start)?;
        }
        let channel = self.secure.as_mut().expect("called with keys");
        let sealed = channel.seal(message).map_err(LinkError::Secure)?;
        let peer = channel.established().map(|(_, peer)| peer);
        self.submit_raw(lane, &sealed)?;
        self.started[lane.index()] = Some(start);
        self.sealed_for[lane.index()] = Some((message.to_vec(), peer));
        Ok(())
    }

    /// Sends again, under a new handshake, the messages a restarted peer
    /// could not open, once both lanes are idle.
    pub(super) fn send_again(&mut self) -> Result<(), LinkError> {
        if self.resend.is_empty() || !Lane::ALL.iter().all(|&l| self.is_idle(l)) {
            return Ok(());
        }
        while let Some((lane, clear, start)) = self.resend.pop_front() {
            self.submit_sealed(lane, &clear, start)?;
        }
        Ok(())
    }

    fn deadline(&self) -> Duration {
        Duration::from_micros(self.cfg.deadline)
    }

    /// Runs handshakes until a session is established from our current
    /// ARQ session, or the message deadline passes.
    fn ensure_session(&mut self, start: Instant) -> Result<(), LinkError> {
        let due = |e: &Self| {
            e.secure
                .as_ref()
                .is_some_and(|c| c.needs_handshake(e.now()))
        };
        while due(self) {
            if start.elapsed() >= self.deadline() {
                return Err(LinkError::NoHandshake(start.elapsed()));
            }
            self.session = fresh_session()?;
            let (cfg, session) = (self.cfg, self.session);
            self.senders = [0, 1].map(|lane| Sender::lane(cfg, session, lane, 2));
            self.receiver.renew(self.session);
            let channel = self.secure.as_mut().expect("called with keys");
            let init = channel.initiate(self.session).map_err(LinkError::Secure)?;
            self.send_raw(Lane::Bulk, &init)?;
            let until = Instant::now() + HANDSHAKE_WAIT;
            while due(self) && Instant::now() < until {
                self.service(TICK)?;
                self.open_inbox()?;
            }
        }
        Ok(())
    }

    /// Passes the delivered messages through the channel: opened ones wait
    /// in `opened` (their ACKs held), a handshake INIT is answered (its ACK
    /// sent first: the initiator waits for it).
    pub(super) fn open_inbox(&mut self) -> Result<(), LinkError> {
        while let Some((from, bytes, held)) = self.inbox.pop_front() {
            let now = self.now();
            let Some(channel) = self.secure.as_mut() else {
                return Ok(());
            };
            let opened = channel.open(from, self.session, &bytes, now);
            if let Opened::Message(m) = opened {
                self.opened.push_back((m, held));
                continue;
            }
            // The layer itself dealt with it (a handshake, a refusal).
            self.send_ack(&held.1)?;
            match opened {
                Opened::Message(_) => {}
                Opened::Reply(r) => {
                    // On a lane that is free (both busy: the peer's handshake
                    // times out and it tries again).
                    let Some(lane) = [Lane::Urgent, Lane::Bulk]
                        .into_iter()
                        .find(|&l| self.is_idle(l))
                    else {
                        continue;
                    };
                    let sender = &mut self.senders[lane.index()];
                    sender.set_deadline(RESPONSE_DEADLINE.as_micros() as u64);
                    let sent = self.send_raw(lane, &r);
                    self.senders[lane.index()].set_deadline(self.cfg.deadline);
                    // A RESPONSE nobody takes (a replayed INIT) is not fatal.
                    if let Err(LinkError::Io(e)) = sent {
                        return Err(LinkError::Io(e));
                    }
                }
                Opened::Established | Opened::Rejected(_) => {}
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::secure::public_key;
    use crate::sim::{pair, SimConfig};

    fn keys() -> (Keys, Keys) {
        let (a, b) = ([5u8; 32], [6u8; 32]);
        (Keys::new(a, public_key(&b)), Keys::new(b, public_key(&a)))
    }

    /// A message of `one_packet_message()` bytes, sealed, crosses a ZigBee
    /// model in one DATA segment; one byte more takes two.
    #[test]
    fn a_one_packet_message_takes_one_segment_sealed() {
        let (ka, kb) = keys();
        let zigbee = SimConfig {
            radio: crate::radio::Firmware::Zigbee,
            mtu: 84,
            ..SimConfig::default()
        };
        let (a, b) = pair(zigbee, 20.0);
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b))
                .unwrap()
                .with_keys(kb, SecureConfig::default());
            for _ in 0..2 {
                e.recv_message(Duration::from_secs(20)).unwrap();
            }
            e.linger(Duration::from_millis(300)).unwrap();
        });
        let mut e = Endpoint::new(Box::new(a))
            .unwrap()
            .with_keys(ka, SecureConfig::default());
        let n = e.one_packet_message();
        assert_eq!(
            n,
            84 - crate::arq::DATA_OVERHEAD - 4 - crate::secure::wire::OVERHEAD
        );
        assert_eq!(e.send_message(&vec![1; n]).unwrap().segments, 1);
        assert_eq!(e.send_message(&vec![2; n + 1]).unwrap().segments, 2);
        rx.join().unwrap();
    }

    #[test]
    fn sealed_messages_cross_a_lossy_link_and_a_sender_restart() {
        let (ka, kb) = keys();
        let (a, b) = pair(
            SimConfig {
                loss: 0.1,
                seed: 9,
                ..SimConfig::default()
            },
            20.0,
        );
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b))
                .unwrap()
                .with_keys(kb, SecureConfig::default());
            let got: Vec<Vec<u8>> = (0..4)
                .map(|_| e.recv_message(Duration::from_secs(20)).unwrap())
                .collect();
            e.linger(Duration::from_millis(300)).unwrap();
            (got, e.rejections().unwrap())
        });
        let msgs: Vec<Vec<u8>> = (0..4u8).map(|i| vec![i; 1500]).collect();
        // Two sender lives over the same radio: the second handshakes anew.
        let mut e = Endpoint::new(Box::new(a))
            .unwrap()
            .with_keys(ka.clone(), SecureConfig::default());
        let first = e.session();
        for m in &msgs[..2] {
            assert_eq!(e.send_message(m).unwrap().bytes, 1500);
        }
        assert_ne!(e.session(), first, "the handshake opened a new session");
        let Endpoint { transport, .. } = e;
        let mut e = Endpoint::new(transport)
            .unwrap()
            .with_keys(ka, SecureConfig::default());
        for m in &msgs[2..] {
            e.send_message(m).unwrap();
        }
        let (got, rejected) = rx.join().unwrap();
        assert_eq!(got, msgs);
        assert_eq!(rejected.total(), 0, "{rejected}");
    }

    #[test]
    fn a_message_the_restarted_receiver_could_not_open_is_sent_again() {
        let (ka, kb) = keys();
        let (a, b) = pair(SimConfig::default(), 20.0);
        let msgs: Vec<Vec<u8>> = (0..4u8).map(|i| vec![i; 700]).collect();
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(b))
                .unwrap()
                .with_keys(kb.clone(), SecureConfig::default());
            let mut got: Vec<Vec<u8>> = (0..2)
                .map(|_| e.recv_message(Duration::from_secs(20)).unwrap())
                .collect();
            // It has dealt with both (linger sends their held ACKs), then
            // restarts at once: same radio, no state, no keys.
            e.linger(Duration::ZERO).unwrap();
            let Endpoint { transport, .. } = e;
            let mut e = Endpoint::new(transport)
                .unwrap()
                .with_keys(kb, SecureConfig::default());
            got.extend((0..2).map(|_| e.recv_message(Duration::from_secs(20)).unwrap()));
            e.linger(Duration::from_millis(300)).unwrap();
            (got, e.rejections().unwrap())
        });
        let mut e = Endpoint::new(Box::new(a))
            .unwrap()
            .with_keys(ka, SecureConfig::default());
        for m in &msgs {
            e.send_message(m).unwrap();
        }
        let (got, rejected) = rx.join().unwrap();
        assert_eq!(got, msgs, "every message once, none lost to the restart");
        // The first copy of message 3 reached a receiver with no session.
        assert_eq!(rejected.unknown_session, 1, "{rejected}");
    }
}
