//! The secure layer's message format (docs/link-protocol.md, "Secure
//! layer"): every message starts with a 64-bit little-endian word. Below
//! [`HANDSHAKE_RESPONSE`] it is the sender's transport counter, followed by
//! the ChaCha20-Poly1305 ciphertext and its 16-byte tag, so a message costs
//! 24 bytes; the two highest values mark the Noise KK handshake messages.
//!
//! ```text
//! DATA      counter (8) | ciphertext … | tag (16)
//! INIT      ff ff ff ff ff ff ff ff | e (32) | session (4) sealed | tag (16)
//! RESPONSE  fe ff ff ff ff ff ff ff | e (32) | session (4), initiator (4) sealed | tag (16)
//! ```

/// Marks the initiator's handshake message (`-> e, es, ss`).
pub const HANDSHAKE_INIT: u64 = u64::MAX;
/// Marks the responder's handshake message (`<- e, ee, se`).
pub const HANDSHAKE_RESPONSE: u64 = u64::MAX - 1;
/// Bytes of the counter word.
pub const COUNTER_LEN: usize = 8;
/// Bytes of a Poly1305 tag.
pub const TAG_LEN: usize = 16;
/// What sealing adds to a message: the counter and the tag.
pub const OVERHEAD: usize = COUNTER_LEN + TAG_LEN;
/// Bytes of an X25519 public key.
pub const KEY_LEN: usize = 32;
/// The Noise payload of INIT: the initiator's ARQ session.
pub const INIT_PAYLOAD: usize = 4;
/// The Noise payload of RESPONSE: the responder's and the initiator's sessions.
pub const RESPONSE_PAYLOAD: usize = 8;
/// A whole INIT message: 60 bytes.
pub const INIT_LEN: usize = COUNTER_LEN + KEY_LEN + INIT_PAYLOAD + TAG_LEN;
/// A whole RESPONSE message: 64 bytes.
pub const RESPONSE_LEN: usize = COUNTER_LEN + KEY_LEN + RESPONSE_PAYLOAD + TAG_LEN;

/// A parsed secure-layer message; the bodies are still sealed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message<'a> {
    /// The Noise message of an INIT.
    Init(&'a [u8]),
    /// The Noise message of a RESPONSE.
    Response(&'a [u8]),
    /// A transport message: its counter and ciphertext with tag.
    Data {
        /// The sender's counter, the AEAD nonce.
        counter: u64,
        /// Ciphertext followed by the tag.
        sealed: &'a [u8],
    },
}

impl<'a> Message<'a> {
    /// Splits `bytes`; `None` when they are too short for what the counter
    /// word announces (a truncated or foreign message).
    pub fn parse(bytes: &'a [u8]) -> Option<Self> {
        let (word, rest) = bytes.split_first_chunk::<COUNTER_LEN>()?;
        match u64::from_le_bytes(*word) {
            HANDSHAKE_INIT if bytes.len() == INIT_LEN => Some(Message::Init(rest)),
            HANDSHAKE_RESPONSE if bytes.len() == RESPONSE_LEN => Some(Message::Response(rest)),
            HANDSHAKE_INIT | HANDSHAKE_RESPONSE => None,
            counter if rest.len() >= TAG_LEN => Some(Message::Data {
                counter,
                sealed: rest,
            }),
            _ => None,
        }
    }
}

/// A message buffer that starts with `word`, with room for `body` more bytes.
pub fn with_word(word: u64, body: usize) -> alloc::vec::Vec<u8> {
    let mut out = alloc::vec![0u8; COUNTER_LEN + body];
    out[..COUNTER_LEN].copy_from_slice(&word.to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_word_tells_the_kinds_apart_and_lengths_are_exact() {
        let mut init = with_word(HANDSHAKE_INIT, INIT_LEN - COUNTER_LEN);
        assert!(matches!(Message::parse(&init), Some(Message::Init(b)) if b.len() == 52));
        init.pop();
        assert_eq!(Message::parse(&init), None);
        let resp = with_word(HANDSHAKE_RESPONSE, RESPONSE_LEN - COUNTER_LEN);
        assert!(matches!(Message::parse(&resp), Some(Message::Response(_))));
        let data = with_word(7, TAG_LEN);
        assert_eq!(
            Message::parse(&data),
            Some(Message::Data {
                counter: 7,
                sealed: &[0; TAG_LEN]
            })
        );
        assert_eq!(Message::parse(&data[..COUNTER_LEN + TAG_LEN - 1]), None);
        assert_eq!(Message::parse(&[1, 2, 3]), None);
    }
}
