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
//!
//! The segment format is in `wire`, the two machines in `sender` and
//! `receiver`, and the sender's retransmission timeout in `timer`.

mod receiver;
mod sender;
#[cfg(test)]
mod tests;
mod timer;
mod wire;

pub use receiver::{Delivery, Receiver};
pub use sender::{SendCounters, SendState, Sender};
pub use wire::{Segment, SessionId, DATA_OVERHEAD, MIN_MTU, WIRE_VERSION};

/// Microseconds on the caller's clock.
pub type Micros = u64;

/// Peer sessions a [`Receiver`] keeps state for, and receiver sessions a
/// [`Sender`] remembers having stopped trusting: the current one and three
/// before it.
pub const REMEMBERED_SESSIONS: usize = 4;

/// Why a message did not get through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ArqError {
    /// The message is larger than the protocol (65535 fragments) or the receiver allows.
    #[error("message too large")]
    TooLarge,
    /// The sender's deadline passed before every fragment was acknowledged.
    #[error("message not acknowledged before its deadline")]
    Deadline,
    /// The receiver's reassembly timed out.
    #[error("reassembly timed out: fragments stopped arriving")]
    ReassemblyTimeout,
    /// The sender aborted the message.
    #[error("the sender gave up on the message")]
    Aborted,
    /// The reassembled message failed its CRC-32.
    #[error("reassembled message failed its CRC-32")]
    Corrupt,
    /// A message is already being sent.
    #[error("a message is already in flight")]
    Busy,
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

    /// The same parameters with the first retransmission timeout seeded
    /// from the air time of one full `packet` on the link (RFC 6298 §2.1
    /// starts at 1 s before any round trip is measured; a radio's pace is
    /// known better than that). A fragment's first round trip is at most
    /// about `ack_every + 3` packet times: the radio's buffer ahead of it
    /// (two packets), itself, the fragments the receiver waits for before
    /// it acknowledges, and the ACK. The first timeout is twice that, and
    /// never below the configured one; the largest timeout grows with it.
    pub fn with_packet_time(mut self, packet: Micros) -> Self {
        let round_trip = packet.saturating_mul(self.ack_every as Micros + 3);
        self.initial_rto = self.initial_rto.max(round_trip.saturating_mul(2));
        self.max_rto = self.max_rto.max(self.initial_rto.saturating_mul(2));
        self
    }

    /// Fragment bytes per DATA segment.
    pub fn fragment_size(&self) -> usize {
        self.mtu.saturating_sub(DATA_OVERHEAD).max(1)
    }
}
