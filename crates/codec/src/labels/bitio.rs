//! The range coder's encoder and decoder behind one trait, so that the same
//! model code runs at both ends, and the counter tree that codes multi-bit
//! values with it.

use crate::rangecoder::{Counter, Decoder, Encoder};

/// The two ends of the range coder behind one interface, so that the
/// encoder and the decoder run the same model code: the encoder codes the
/// bit it is given, the decoder ignores it and returns the decoded one.
pub(super) trait BitIo {
    /// Codes a bit whose probability of being 0 is `p0` / 2^16.
    fn code(&mut self, p0: u32, bit: bool) -> bool;
    fn overrun(&self) -> bool;

    /// Codes a bit with an adaptive counter.
    #[inline(always)]
    fn bit(&mut self, c: &mut Counter, bit: bool) -> bool {
        let bit = self.code(c.p0(), bit);
        c.update(bit);
        bit
    }
}

impl BitIo for Encoder {
    #[inline(always)]
    fn code(&mut self, p0: u32, bit: bool) -> bool {
        Encoder::code(self, p0, bit);
        bit
    }
    fn overrun(&self) -> bool {
        false
    }
}

impl BitIo for Decoder<'_> {
    #[inline(always)]
    fn code(&mut self, p0: u32, _: bool) -> bool {
        Decoder::code(self, p0)
    }
    fn overrun(&self) -> bool {
        Decoder::overrun(self)
    }
}

/// Codes `value` (`bits` bits, most significant first) with a tree of counters.
pub(super) fn tree<I: BitIo>(io: &mut I, probs: &mut [Counter], bits: u32, value: u32) -> u32 {
    let mut node = 1usize;
    for i in (0..bits).rev() {
        let bit = io.bit(&mut probs[node], (value >> i) & 1 == 1);
        node = (node << 1) | bit as usize;
    }
    (node - (1 << bits)) as u32
}
