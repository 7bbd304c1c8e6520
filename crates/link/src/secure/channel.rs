//! The secure channel's state machine: the Noise KK handshake (initiator
//! and responder), the established session with its counters and replay
//! window, and the bounds that keep a flood of handshakes harmless.
//!
//! The responder keeps an answered handshake *pending* until the first
//! transport message authenticates under it (as WireGuard does), so a
//! replayed or forged INIT never replaces the working session; at most
//! `max_pending` are kept and new ones are rate-limited by a token bucket.

use alloc::collections::VecDeque;
use alloc::vec::Vec;

use chacha20poly1305::aead::{AeadInPlace, KeyInit};
use chacha20poly1305::{ChaCha20Poly1305, Nonce, Tag};
use snow::HandshakeState;

use super::replay::ReplayWindow;
use super::wire::{self, Message};
use super::{Keys, Rejection, Rejections, SecureConfig, SecureError, NOISE_PARAMS, PROLOGUE};
use crate::arq::{Micros, SessionId};

/// INIT ephemeral keys remembered, so a replayed INIT is refused unanswered.
const ANSWERED: usize = 16;

/// What an incoming message amounted to.
#[derive(Debug, PartialEq, Eq)]
pub enum Opened {
    /// An authenticated message for the layer above.
    Message(Vec<u8>),
    /// A handshake RESPONSE to send back to the initiator.
    Reply(Vec<u8>),
    /// Our handshake completed: messages can be sealed.
    Established,
    /// Refused; counted in [`Channel::rejections`].
    Rejected(Rejection),
}

/// A handshake we started and whose RESPONSE we wait for.
struct Initiating {
    handshake: HandshakeState,
    local: SessionId,
}

/// Transport keys between two ARQ sessions. The AEAD is run here rather than
/// by `snow`'s transport mode, which caps messages at 65 535 bytes (a frame
/// may be larger); key split, nonce and empty associated data are Noise's
/// (§ 5.2, § 12.3), so the messages are those `snow` would produce.
struct Session {
    local: SessionId,
    peer: SessionId,
    send: ChaCha20Poly1305,
    recv: ChaCha20Poly1305,
    /// The next counter we seal with.
    next: u64,
    window: ReplayWindow,
    since: Micros,
}

/// Handshakes started, per refill interval, beyond a burst.
struct TokenBucket {
    tokens: u32,
    refilled: Micros,
}

impl TokenBucket {
    fn take(&mut self, cfg: &SecureConfig, now: Micros) -> bool {
        let earned = now.saturating_sub(self.refilled) / cfg.handshake_interval.max(1);
        if earned > 0 {
            self.tokens = (self.tokens as u64 + earned).min(cfg.handshake_burst as u64) as u32;
            self.refilled = now;
        }
        let ok = self.tokens > 0;
        self.tokens = self.tokens.saturating_sub(1);
        ok
    }
}

/// One device's end of the secure link to its paired peer.
pub struct Channel {
    cfg: SecureConfig,
    keys: Keys,
    initiating: Option<Initiating>,
    /// Answered handshakes awaiting their first message, oldest first.
    pending: VecDeque<Session>,
    current: Option<Session>,
    bucket: TokenBucket,
    answered: VecDeque<[u8; wire::KEY_LEN]>,
    rejections: Rejections,
}

impl Channel {
    /// A channel with no session yet.
    pub fn new(keys: Keys, cfg: SecureConfig) -> Self {
        Channel {
            bucket: TokenBucket {
                tokens: cfg.handshake_burst,
                refilled: 0,
            },
            cfg,
            keys,
            initiating: None,
            pending: VecDeque::new(),
            current: None,
            answered: VecDeque::new(),
            rejections: Rejections::default(),
        }
    }

    /// Messages refused so far, by cause.
    pub fn rejections(&self) -> Rejections {
        self.rejections
    }

    /// Handshakes answered and not yet confirmed (at most `max_pending`).
    pub fn pending_handshakes(&self) -> usize {
        self.pending.len()
    }

    /// The (local, peer) ARQ sessions of the established session.
    pub fn established(&self) -> Option<(SessionId, SessionId)> {
        self.current.as_ref().map(|s| (s.local, s.peer))
    }

    /// Whether a handshake must run before the next message is sealed: no
    /// session, or it reached the rekey time or message limit.
    pub fn needs_handshake(&self, now: Micros) -> bool {
        self.current.as_ref().is_none_or(|s| {
            now.saturating_sub(s.since) >= self.cfg.rekey_after
                || s.next >= self.cfg.rekey_after_messages
        })
    }

    /// Drops the established session (the peer is known to have restarted).
    pub fn forget(&mut self) {
        self.current = None;
    }

    fn builder(&self) -> Result<snow::Builder<'_>, SecureError> {
        let params = NOISE_PARAMS.parse().map_err(|_| SecureError::Noise)?;
        snow::Builder::new(params)
            .prologue(PROLOGUE)
            .and_then(|b| b.local_private_key(&self.keys.private))
            .and_then(|b| b.remote_public_key(&self.keys.peer))
            .map_err(|_| SecureError::Noise)
    }

    /// Starts a handshake from the fresh ARQ session `local`; returns the
    /// INIT message to send. A handshake already under way is abandoned.
    pub fn initiate(&mut self, local: SessionId) -> Result<Vec<u8>, SecureError> {
        let mut handshake = self
            .builder()?
            .build_initiator()
            .map_err(|_| SecureError::Noise)?;
        let mut out = wire::with_word(wire::HANDSHAKE_INIT, wire::INIT_LEN - wire::COUNTER_LEN);
        handshake
            .write_message(&local.0.to_le_bytes(), &mut out[wire::COUNTER_LEN..])
            .map_err(|_| SecureError::Noise)?;
        self.initiating = Some(Initiating { handshake, local });
        Ok(out)
    }

    /// Seals `plaintext` with the next counter of the established session.
    pub fn seal(&mut self, plaintext: &[u8]) -> Result<Vec<u8>, SecureError> {
        let s = self.current.as_mut().ok_or(SecureError::NoSession)?;
        let mut out = wire::with_word(s.next, plaintext.len());
        out[wire::COUNTER_LEN..].copy_from_slice(plaintext);
        let tag = s
            .send
            .encrypt_in_place_detached(&nonce(s.next), &[], &mut out[wire::COUNTER_LEN..])
            .map_err(|_| SecureError::Noise)?;
        out.extend_from_slice(&tag);
        s.next += 1;
        Ok(out)
    }

    /// Judges a message delivered by the ARQ from the peer session `from`;
    /// `local` is our current ARQ session (named in a RESPONSE).
    pub fn open(&mut self, from: SessionId, local: SessionId, bytes: &[u8], now: Micros) -> Opened {
        let result = match Message::parse(bytes) {
            None => Err(Rejection::BadTag),
            Some(Message::Init(noise)) => self.answer(from, local, noise, now).map(Opened::Reply),
            Some(Message::Response(noise)) => self.complete(from, noise, now),
            Some(Message::Data { counter, sealed }) => self
                .decrypt(from, counter, sealed, now)
                .map(Opened::Message),
        };
        result.unwrap_or_else(|why| {
            self.rejections.count(why);
            Opened::Rejected(why)
        })
    }

    /// Responder: answers an INIT from `from`, keeping its keys pending.
    fn answer(
        &mut self,
        from: SessionId,
        local: SessionId,
        noise: &[u8],
        now: Micros,
    ) -> Result<Vec<u8>, Rejection> {
        let ephemeral = *noise
            .first_chunk::<{ wire::KEY_LEN }>()
            .ok_or(Rejection::Handshake)?;
        let known = |s: &Session| s.peer == from;
        if self.answered.contains(&ephemeral)
            || self.current.as_ref().is_some_and(known)
            || self.pending.iter().any(known)
        {
            return Err(Rejection::Handshake);
        }
        // Simultaneous starts: the side with the lower public key answers.
        if self.initiating.is_some() && self.keys.public > self.keys.peer {
            return Err(Rejection::Handshake);
        }
        if !self.bucket.take(&self.cfg, now) {
            return Err(Rejection::Handshake);
        }
        let mut handshake = self
            .builder()
            .and_then(|b| b.build_responder().map_err(|_| SecureError::Noise))
            .map_err(|_| Rejection::Handshake)?;
        let mut payload = [0u8; wire::INIT_PAYLOAD];
        let n = handshake
            .read_message(noise, &mut payload)
            .map_err(|_| Rejection::Handshake)?;
        if n != wire::INIT_PAYLOAD || u32::from_le_bytes(payload) != from.0 {
            return Err(Rejection::Handshake);
        }
        let mut sessions = [0u8; wire::RESPONSE_PAYLOAD];
        sessions[..4].copy_from_slice(&local.0.to_le_bytes());
        sessions[4..].copy_from_slice(&from.0.to_le_bytes());
        let mut out = wire::with_word(
            wire::HANDSHAKE_RESPONSE,
            wire::RESPONSE_LEN - wire::COUNTER_LEN,
        );
        handshake
            .write_message(&sessions, &mut out[wire::COUNTER_LEN..])
            .map_err(|_| Rejection::Handshake)?;
        let keys = split(&mut handshake, false);
        self.initiating = None;
        if self.answered.len() == ANSWERED {
            self.answered.pop_front();
        }
        self.answered.push_back(ephemeral);
        if self.pending.len() >= self.cfg.max_pending.max(1) {
            self.pending.pop_front();
        }
        self.pending.push_back(Session::new(local, from, keys, now));
        Ok(out)
    }

    /// Initiator: takes the RESPONSE to our INIT.
    fn complete(
        &mut self,
        from: SessionId,
        noise: &[u8],
        now: Micros,
    ) -> Result<Opened, Rejection> {
        let init = self.initiating.as_mut().ok_or(Rejection::Handshake)?;
        let mut sessions = [0u8; wire::RESPONSE_PAYLOAD];
        let n = init
            .handshake
            .read_message(noise, &mut sessions)
            .map_err(|_| Rejection::Handshake)?;
        let named = |i: usize| {
            SessionId(u32::from_le_bytes([
                sessions[i],
                sessions[i + 1],
                sessions[i + 2],
                sessions[i + 3],
            ]))
        };
        if n != wire::RESPONSE_PAYLOAD || named(0) != from || named(4) != init.local {
            return Err(Rejection::Handshake);
        }
        let mut init = self.initiating.take().ok_or(Rejection::Handshake)?;
        let keys = split(&mut init.handshake, true);
        self.current = Some(Session::new(init.local, from, keys, now));
        self.pending.clear();
        Ok(Opened::Established)
    }

    /// A transport message: the current session, or a pending one that it
    /// confirms.
    fn decrypt(
        &mut self,
        from: SessionId,
        counter: u64,
        sealed: &[u8],
        now: Micros,
    ) -> Result<Vec<u8>, Rejection> {
        let reject_after = self.cfg.reject_after;
        let live = |s: &Session| s.peer == from && now.saturating_sub(s.since) < reject_after;
        if let Some(s) = self.current.as_mut().filter(|s| live(s)) {
            return s.open(counter, sealed);
        }
        let i = self
            .pending
            .iter()
            .position(live)
            .ok_or(Rejection::UnknownSession)?;
        let plain = self.pending[i].open(counter, sealed)?;
        // Confirmed: it replaces the current session and every older pending one.
        self.current = self.pending.drain(..=i).next_back();
        Ok(plain)
    }
}

/// The Noise nonce of a counter: 32 zero bits, then the counter little-endian.
fn nonce(counter: u64) -> Nonce {
    let mut n = Nonce::default();
    n[4..].copy_from_slice(&counter.to_le_bytes());
    n
}

/// The (send, receive) ciphers of a finished handshake (Noise `Split()`:
/// the first key protects initiator-to-responder messages).
fn split(handshake: &mut HandshakeState, initiator: bool) -> (ChaCha20Poly1305, ChaCha20Poly1305) {
    let (i2r, r2i) = handshake.dangerously_get_raw_split();
    let (i2r, r2i) = (
        ChaCha20Poly1305::new(&i2r.into()),
        ChaCha20Poly1305::new(&r2i.into()),
    );
    if initiator {
        (i2r, r2i)
    } else {
        (r2i, i2r)
    }
}

impl Session {
    fn new(
        local: SessionId,
        peer: SessionId,
        (send, recv): (ChaCha20Poly1305, ChaCha20Poly1305),
        now: Micros,
    ) -> Self {
        Session {
            local,
            peer,
            send,
            recv,
            next: 0,
            window: ReplayWindow::default(),
            since: now,
        }
    }

    /// Checks the counter, authenticates and decrypts, then marks the counter.
    fn open(&mut self, counter: u64, sealed: &[u8]) -> Result<Vec<u8>, Rejection> {
        self.window.check(counter).map_err(|_| Rejection::Replay)?;
        let (body, tag) = sealed
            .split_last_chunk::<{ wire::TAG_LEN }>()
            .ok_or(Rejection::BadTag)?;
        let mut plain = body.to_vec();
        self.recv
            .decrypt_in_place_detached(&nonce(counter), &[], &mut plain, &Tag::from(*tag))
            .map_err(|_| Rejection::BadTag)?;
        self.window.mark(counter);
        Ok(plain)
    }
}
