//! The frame container: a fixed header and a typed body, all little-endian.
//! `docs/wire-format.md` gives the exact byte layout.
//!
//! ```text
//!  0      4   5   6      8          12                 20         24         28
//!  +------+---+---+------+----------+------------------+----------+----------+------ ...
//!  | SLNK |ver|typ|flags | frame id | timestamp (µs)   | body len | body CRC | body
//!  +------+---+---+------+----------+------------------+----------+----------+------ ...
//! ```
//!
//! `bytes` holds the little-endian reader and writer (shared with the
//! plane table), `encode` writes messages, `parse` checks a message and
//! parses its body without decoding the views, and `decoder` decodes a
//! parsed frame's views, into buffers it may keep from frame to frame.

mod bytes;
mod decoder;
mod encode;
mod parse;
#[cfg(test)]
mod tests;

pub(crate) use bytes::{Reader, Writer};
pub use decoder::FrameDecoder;
pub(crate) use encode::predicted_payload;
pub use encode::{
    conditioned_payload, encode, encode_with, report_len, right_prediction, REPORT_LEVEL_LEN,
};
pub use parse::{decode_header, parse, Body, FrameRef, ViewRef};

use crate::{CodecError, Limits, Message};

/// The magic bytes.
pub const MAGIC: [u8; 4] = *b"SLNK";
/// The format version this build writes and reads.
pub const VERSION: u8 = 2;
/// Header length in bytes.
pub const HEADER_LEN: usize = 28;

/// Message type codes.
pub mod kind {
    /// [`crate::Message::StereoFrame`].
    pub const STEREO_FRAME: u8 = 1;
    /// [`crate::Message::DepthReport`].
    pub const DEPTH_REPORT: u8 = 2;
    /// [`crate::Message::Control`].
    pub const CONTROL: u8 = 3;
}

/// View coding codes.
mod coding {
    pub const LABELS: u8 = 0;
    pub const LABELS_CONDITIONED: u8 = 1;
    pub const RGB: u8 = 2;
    /// A lossy view: the codec's byte ([`crate::lossy::LossyCodec`]),
    /// then its bitstream.
    pub const LOSSY: u8 = 3;
    /// A view predicted from an earlier frame ([`crate::temporal`]).
    pub const PREDICTED: u8 = 4;
    /// A label map predicted from an earlier frame's.
    pub const LABELS_PREDICTED: u8 = 5;
    /// A right view predicted from the frame's left view
    /// ([`crate::stereo`]).
    pub const STEREO: u8 = 6;
    /// A view predicted by motion from an earlier frame
    /// ([`crate::motion`]).
    pub const MOTION: u8 = 7;

    /// Whether a view so coded is a label map.
    pub fn indexed(code: u8) -> bool {
        matches!(code, LABELS | LABELS_CONDITIONED | LABELS_PREDICTED)
    }
}

/// Stereo shift search range of the encoder (px); any value decodes.
pub const SHIFT_SEARCH: usize = 96;

/// The decoded header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Format version.
    pub version: u8,
    /// Message type code.
    pub kind: u8,
    /// Frame id.
    pub frame_id: u32,
    /// Sender timestamp in microseconds.
    pub timestamp_us: u64,
    /// Body length in bytes.
    pub body_len: u32,
}

/// Decodes one message; the bytes must hold exactly one header and its body.
pub fn decode(bytes: &[u8], limits: &Limits) -> Result<(Header, Message), CodecError> {
    let (header, body) = parse(bytes, limits)?;
    let msg = match body {
        Body::StereoFrame(f) => Message::StereoFrame(Box::new(f.decode()?)),
        Body::DepthReport(r) => Message::DepthReport(r),
        Body::Control(c) => Message::Control(c.to_vec()),
    };
    Ok((header, msg))
}
