//! Framing for XBee transparent (AT) mode, where the radio passes a raw byte
//! stream: SLIP byte stuffing (RFC 1055) around each packet plus a CRC-16, so
//! a receiver resynchronises at the next END byte after loss or noise and
//! drops damaged packets.

use alloc::vec::Vec;

use crate::crc::crc16;

const END: u8 = 0xC0;
const ESC: u8 = 0xDB;
const ESC_END: u8 = 0xDC;
const ESC_ESC: u8 = 0xDD;

/// Frames a packet: END, stuffed (packet ‖ CRC-16 big-endian), END.
pub fn encode(packet: &[u8]) -> Vec<u8> {
    let crc = crc16(packet).to_be_bytes();
    let mut out = Vec::with_capacity(packet.len() + 8);
    out.push(END);
    for &b in packet.iter().chain(&crc) {
        match b {
            END => out.extend_from_slice(&[ESC, ESC_END]),
            ESC => out.extend_from_slice(&[ESC, ESC_ESC]),
            _ => out.push(b),
        }
    }
    out.push(END);
    out
}

/// Why a SLIP frame was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SlipError {
    /// CRC mismatch or bad escape: the bytes were damaged.
    Corrupt,
    /// Longer than the deframer's limit.
    TooLong,
}

/// Streaming deframer with a bound on packet length.
#[derive(Debug)]
pub struct Deframer {
    buf: Vec<u8>,
    escaped: bool,
    overflow: bool,
    max: usize,
}

impl Deframer {
    /// A deframer accepting packets up to `max` bytes.
    pub fn new(max: usize) -> Self {
        Deframer {
            buf: Vec::new(),
            escaped: false,
            overflow: false,
            max,
        }
    }

    /// Feeds one byte; returns a packet or an error when a frame ends.
    pub fn push(&mut self, byte: u8) -> Option<Result<Vec<u8>, SlipError>> {
        if byte == END {
            let (escaped, overflow) = (
                core::mem::take(&mut self.escaped),
                core::mem::take(&mut self.overflow),
            );
            if self.buf.is_empty() && !overflow {
                return None; // back-to-back END bytes
            }
            let buf = core::mem::take(&mut self.buf);
            if overflow {
                return Some(Err(SlipError::TooLong));
            }
            if escaped || buf.len() < 2 {
                return Some(Err(SlipError::Corrupt));
            }
            let (body, crc) = buf.split_at(buf.len() - 2);
            return Some(if crc16(body).to_be_bytes() == crc {
                Ok(body.to_vec())
            } else {
                Err(SlipError::Corrupt)
            });
        }
        let b = if core::mem::take(&mut self.escaped) {
            match byte {
                ESC_END => END,
                ESC_ESC => ESC,
                _ => {
                    self.buf.clear();
                    self.buf.push(0); // poison: the CRC will fail
                    return None;
                }
            }
        } else if byte == ESC {
            self.escaped = true;
            return None;
        } else {
            byte
        };
        if self.buf.len() >= self.max + 2 {
            self.overflow = true;
            self.buf.clear();
        } else if !self.overflow {
            self.buf.push(b);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use alloc::vec;

    #[test]
    fn round_trip_with_special_bytes_and_resync() {
        let p = vec![END, 1, ESC, 2, END];
        let mut stream = vec![7, 7, 7]; // noise before the first END
        stream.extend(encode(&p));
        let mut damaged = encode(b"hello");
        damaged[3] ^= 0x40;
        stream.extend(damaged);
        stream.extend(encode(b"ok"));
        let mut d = Deframer::new(64);
        let out: Vec<_> = stream.iter().filter_map(|&b| d.push(b)).collect();
        assert_eq!(
            out,
            vec![
                Err(SlipError::Corrupt),
                Ok(p),
                Err(SlipError::Corrupt),
                Ok(b"ok".to_vec())
            ]
        );
    }

    #[test]
    fn long_frames_are_bounded() {
        let mut d = Deframer::new(4);
        let out: Vec<_> = encode(&[1; 100])
            .iter()
            .filter_map(|&b| d.push(b))
            .collect();
        assert_eq!(out, vec![Err(SlipError::TooLong)]);
    }
}
