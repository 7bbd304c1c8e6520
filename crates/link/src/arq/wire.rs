//! The link segment's wire format, version 3: DATA, ACK and FAIL segments,
//! parsed and emitted byte for byte (the layout is in the [`super`] module
//! doc), and the session ids they carry. Its own module because it is the
//! one thing both machines, the transports' callers and the fuzz targets
//! share, and it changes only with [`WIRE_VERSION`].

use alloc::vec::Vec;

use crate::crc::crc16;

/// The link segment format's version, the high nibble of every type byte.
/// Version 1 (type bytes 0x01–0x03) had no sessions and version 2 (0x21–0x23)
/// 13-byte DATA headers; their segments are dropped as unknown.
pub const WIRE_VERSION: u8 = 3;
pub(super) const DATA: u8 = WIRE_VERSION << 4 | 1;
const ACK: u8 = WIRE_VERSION << 4 | 2;
const FAIL: u8 = WIRE_VERSION << 4 | 3;
const DATA_LAST: u8 = WIRE_VERSION << 4 | 4;
/// Bytes of a DATA segment besides the fragment.
pub const DATA_OVERHEAD: usize = 7;
const ACK_LEN: usize = 18;
const FAIL_LEN: usize = 7;
/// The smallest payload a link must carry: an ACK.
pub const MIN_MTU: usize = ACK_LEN;

/// One life of an endpoint: drawn at random when it starts (from the OS
/// RNG, by [`crate::endpoint`]), so a restarted process never continues an
/// old one's message ids. A handshake may supply it instead; the ARQ only
/// compares sessions for equality. It travels as 24 bits
/// ([`SessionId::BITS`]): with [`REMEMBERED_SESSIONS`](super::REMEMBERED_SESSIONS) remembered, a
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
        /// The sender's session.
        session: SessionId,
        /// The message's id within the session (wraps).
        msg_id: u8,
        /// The fragment's index in the message.
        index: u16,
        /// Whether this is the message's final fragment.
        last: bool,
        /// The fragment's bytes.
        fragment: &'a [u8],
    },
    /// Acknowledgement state of message `msg_id` of `session`, from the
    /// receiver whose own session is `receiver`; `count` is the message's
    /// fragment count where the receiver knows it, else 0.
    Ack {
        /// The sender's session the message belongs to.
        session: SessionId,
        /// The acknowledging receiver's own session.
        receiver: SessionId,
        /// The message acknowledged.
        msg_id: u8,
        /// The message's fragment count, 0 when not yet known.
        count: u16,
        /// The first fragment not yet received.
        next: u16,
        /// Which of the 32 fragments after `next` arrived (bit i: `next + 1 + i`).
        bitmap: u32,
    },
    /// Message `msg_id` of `session` is given up (by its sender, or by the
    /// receiver when it arrived corrupt).
    Fail {
        /// The sender's session.
        session: SessionId,
        /// The message given up.
        msg_id: u8,
    },
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

/// Whether an ACK of `next` and `bitmap` says fragment `i` arrived.
pub(super) fn covers(next: usize, bitmap: u32, i: usize) -> bool {
    i < next || (i > next && i - next - 1 < 32 && bitmap >> (i - next - 1) & 1 == 1)
}
