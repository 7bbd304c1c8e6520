//! The secure layer: Noise KK (`Noise_KK_25519_ChaChaPoly_BLAKE2s`, through
//! the `snow` crate) between the ARQ and the payload, after WireGuard:
//! static keys per device, a fresh handshake per session, an explicit 64-bit
//! counter per direction and the RFC 6479 replay window. Whole messages are
//! sealed, so a forged fragment or ACK can cost a retransmission but never
//! deliver or alter a message. See docs/security.md for why Noise KK and
//! docs/link-protocol.md ("Secure layer") for the wire and the rules.
//!
//! One mechanism for sessions: the ARQ session ids *are* the secure
//! session's identifiers. The initiator draws a fresh ARQ session for every
//! handshake and names it in INIT; the responder names its own in RESPONSE;
//! both are sealed in the handshake, so the transport keys belong to that
//! pair of ARQ sessions and a message of any other session is refused.
//!
//! [`Channel`] is a state machine without I/O or clock (the caller passes
//! `now`); `snow` draws the ephemeral keys from the OS through `getrandom`.

mod channel;
pub mod fuzz;
pub mod replay;
pub mod wire;

#[cfg(feature = "std")]
pub mod keyfile;
#[cfg(feature = "std")]
pub mod sim;

pub use channel::{Channel, Opened};

use crate::arq::Micros;

/// The Noise protocol name, also the handshake's first hash input.
pub const NOISE_PARAMS: &str = "Noise_KK_25519_ChaChaPoly_BLAKE2s";

/// Mixed into the handshake as the Noise prologue: a peer speaking another
/// version of this layer fails the handshake instead of misreading it.
pub const PROLOGUE: &[u8] = b"stereolink secure v1";

/// A device's static X25519 key pair and the peer's public key.
#[derive(Clone)]
pub struct Keys {
    private: [u8; 32],
    public: [u8; 32],
    peer: [u8; 32],
}

impl Keys {
    /// Keys from this device's private key and the paired peer's public key.
    pub fn new(private: [u8; 32], peer: [u8; 32]) -> Self {
        Keys {
            public: public_key(&private),
            private,
            peer,
        }
    }

    /// This device's public key.
    pub fn public(&self) -> [u8; 32] {
        self.public
    }
}

impl core::fmt::Debug for Keys {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Keys").finish_non_exhaustive()
    }
}

/// The X25519 public key of a private key (RFC 7748, clamped).
pub fn public_key(private: &[u8; 32]) -> [u8; 32] {
    curve25519_dalek::MontgomeryPoint::mul_base_clamped(*private).to_bytes()
}

/// Timers and bounds of the secure layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SecureConfig {
    /// A sender starts a new handshake before sending once its session is
    /// this old (WireGuard's REKEY_AFTER_TIME, 120 s).
    pub rekey_after: Micros,
    /// A session this old is refused; it must outlast `rekey_after` by the
    /// ARQ message deadline, so a message sealed just before the rekey
    /// time is still accepted when it arrives (120 + 120 + 60 s).
    pub reject_after: Micros,
    /// A sender rekeys after this many messages (WireGuard: 2^60).
    pub rekey_after_messages: u64,
    /// Handshakes answered but not yet confirmed by a first message.
    pub max_pending: usize,
    /// Handshakes answered at once before the rate limit applies.
    pub handshake_burst: u32,
    /// Then one handshake per this interval.
    pub handshake_interval: Micros,
}

impl Default for SecureConfig {
    fn default() -> Self {
        SecureConfig {
            rekey_after: 120_000_000,
            reject_after: 300_000_000,
            rekey_after_messages: 1 << 60,
            max_pending: 4,
            handshake_burst: 4,
            handshake_interval: 500_000,
        }
    }
}

/// Why a message was refused, one counter each in [`Rejections`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// It did not authenticate: forged, altered, truncated or sealed with
    /// other keys.
    BadTag,
    /// Its counter was seen before in its session, or is below the window.
    Replay,
    /// It came from an ARQ session with no (or an expired) secure session.
    UnknownSession,
    /// A handshake message that failed, repeated or exceeded the rate limit.
    Handshake,
}

impl core::fmt::Display for Rejection {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Rejection::BadTag => "bad tag",
            Rejection::Replay => "replay",
            Rejection::UnknownSession => "unknown session",
            Rejection::Handshake => "handshake failure",
        })
    }
}

/// Messages refused, by cause.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Rejections {
    /// [`Rejection::BadTag`].
    pub bad_tag: u64,
    /// [`Rejection::Replay`].
    pub replay: u64,
    /// [`Rejection::UnknownSession`].
    pub unknown_session: u64,
    /// [`Rejection::Handshake`].
    pub handshake: u64,
}

impl Rejections {
    /// Counts one refusal.
    pub fn count(&mut self, why: Rejection) {
        *match why {
            Rejection::BadTag => &mut self.bad_tag,
            Rejection::Replay => &mut self.replay,
            Rejection::UnknownSession => &mut self.unknown_session,
            Rejection::Handshake => &mut self.handshake,
        } += 1;
    }

    /// All refusals.
    pub fn total(&self) -> u64 {
        self.bad_tag + self.replay + self.unknown_session + self.handshake
    }
}

impl core::fmt::Display for Rejections {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "rejected: {} bad tag, {} replay, {} unknown session, {} handshake",
            self.bad_tag, self.replay, self.unknown_session, self.handshake
        )
    }
}

/// Why sealing or starting a handshake failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SecureError {
    /// No established session: run a handshake first.
    #[error("no secure session with the peer yet")]
    NoSession,
    /// The Noise library refused (bad key, no randomness).
    #[error("the Noise handshake could not be built (bad key or no randomness)")]
    Noise,
}

#[cfg(test)]
mod tests;
