//! Adaptive binary range coder (the LZMA scheme: 11-bit probabilities, a
//! 32-bit range with carry propagation, adaptation by 1/2⁵ per bit).
//!
//! The decoder never reads outside its input: past the end it sees zero
//! bytes, so a truncated stream decodes to garbage that the caller's checks
//! (label ranges, CRC) reject, never to a panic or an endless loop.

const PROB_BITS: u32 = 11;
const PROB_ONE: u16 = 1 << PROB_BITS;
const MOVE_BITS: u32 = 5;
const TOP: u32 = 1 << 24;

/// An adaptive probability that the next bit is 0.
#[derive(Clone, Copy, Debug)]
pub struct Prob(u16);

impl Default for Prob {
    fn default() -> Self {
        Prob(PROB_ONE / 2)
    }
}

/// Precision of the probabilities given to [`Encoder::code`] and [`Decoder::code`].
pub const P16_BITS: u32 = 16;
/// Smallest probability [`Counter`] yields (and 2^16 minus it, the largest).
const P16_MIN: u32 = 32;
/// Largest state count of a [`Counter`]: its slowest adaptation rate is
/// 1/(`COUNT_LIMIT` + 1.5).
const COUNT_LIMIT: u8 = 120;

/// An adaptive probability (16 bits) that the next bit is 0 which adapts
/// fast while young: after `n` bits it moves by 1/(n + 1.5) per bit, down to
/// 1/(`COUNT_LIMIT` + 1.5), so rare contexts learn quickly and frequent ones
/// settle close to their frequency.
#[derive(Clone, Copy, Debug)]
pub struct Counter {
    p: u16,
    n: u8,
}

impl Default for Counter {
    fn default() -> Self {
        Counter { p: 1 << 15, n: 0 }
    }
}

/// `65536 / (n + 1.5)` for each state count `n` (up to `COUNT_LIMIT`;
/// one entry per `u8`, so that a count indexes it without a bounds check).
const RATES: [u32; 256] = {
    let mut t = [0; 256];
    let mut n = 0;
    while n < 256 {
        t[n] = 2 * 65536 / (2 * n as u32 + 3);
        n += 1;
    }
    t
};

impl Counter {
    /// The probability of a 0, in 1/2^16, clamped to [32, 65504].
    #[inline(always)]
    pub fn p0(self) -> u32 {
        (self.p as u32).clamp(P16_MIN, (1 << P16_BITS) - P16_MIN)
    }

    /// Learns `bit`.
    #[inline(always)]
    pub fn update(&mut self, bit: bool) {
        self.update_to(bit, COUNT_LIMIT);
    }

    /// Learns `bit`, the state count stopping at `limit` (at most
    /// `COUNT_LIMIT`): the slowest rate is then 1/(`limit` + 1.5), for
    /// statistics that drift.
    #[inline(always)]
    pub fn update_to(&mut self, bit: bool, limit: u8) {
        let rate = RATES[self.n as usize];
        let p = self.p as u32;
        self.p = if bit {
            p - ((p * rate) >> 16)
        } else {
            p + ((((1 << 16) - 1 - p) * rate) >> 16)
        } as u16;
        self.n += (self.n < limit) as u8;
    }
}

/// Encodes bits into a byte vector.
pub struct Encoder {
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
    out: Vec<u8>,
}

impl Default for Encoder {
    fn default() -> Self {
        Encoder {
            low: 0,
            range: u32::MAX,
            cache: 0,
            cache_size: 1,
            out: Vec::new(),
        }
    }
}

impl Encoder {
    /// A new encoder.
    pub fn new() -> Self {
        Self::default()
    }

    fn shift_low(&mut self) {
        if (self.low as u32) < 0xFF00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut temp = self.cache;
            loop {
                self.out.push(temp.wrapping_add(carry));
                temp = 0xFF;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = ((self.low >> 24) & 0xFF) as u8;
        }
        self.cache_size += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// Encodes `bit` with the adaptive probability `p`.
    #[inline]
    pub fn bit(&mut self, p: &mut Prob, bit: bool) {
        let bound = (self.range >> PROB_BITS) * p.0 as u32;
        if !bit {
            self.range = bound;
            p.0 += (PROB_ONE - p.0) >> MOVE_BITS;
        } else {
            self.low += bound as u64;
            self.range -= bound;
            p.0 -= p.0 >> MOVE_BITS;
        }
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Encodes `bit` whose probability of being 0 is `p0` / 2^16 (0 < `p0` < 2^16).
    #[inline]
    pub fn code(&mut self, p0: u32, bit: bool) {
        let bound = (self.range >> P16_BITS) * p0;
        if !bit {
            self.range = bound;
        } else {
            self.low += bound as u64;
            self.range -= bound;
        }
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Encodes the low `n` bits of `value` with fixed probability ½, high bit first.
    pub fn direct(&mut self, value: u32, n: u32) {
        for i in (0..n).rev() {
            self.range >>= 1;
            if (value >> i) & 1 == 1 {
                self.low += self.range as u64;
            }
            while self.range < TOP {
                self.range <<= 8;
                self.shift_low();
            }
        }
    }

    /// Flushes and returns the bytes.
    pub fn finish(mut self) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        // The first byte is always the initial zero cache.
        self.out.remove(0);
        self.out
    }
}

/// Decodes bits from a byte slice.
pub struct Decoder<'a> {
    input: &'a [u8],
    pos: usize,
    range: u32,
    code: u32,
}

impl<'a> Decoder<'a> {
    /// Starts decoding `input`.
    pub fn new(input: &'a [u8]) -> Self {
        let mut d = Decoder {
            input,
            pos: 0,
            range: u32::MAX,
            code: 0,
        };
        for _ in 0..4 {
            d.code = (d.code << 8) | d.next_byte() as u32;
        }
        d
    }

    #[inline]
    fn next_byte(&mut self) -> u8 {
        let b = self.input.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b
    }

    /// True once the decoder has consumed more bytes than the input holds.
    pub fn overrun(&self) -> bool {
        self.pos > self.input.len() + 4
    }

    /// Decodes one bit with the adaptive probability `p`.
    #[inline]
    pub fn bit(&mut self, p: &mut Prob) -> bool {
        let bound = (self.range >> PROB_BITS) * p.0 as u32;
        let bit = if self.code < bound {
            self.range = bound;
            p.0 += (PROB_ONE - p.0) >> MOVE_BITS;
            false
        } else {
            self.code -= bound;
            self.range -= bound;
            p.0 -= p.0 >> MOVE_BITS;
            true
        };
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next_byte() as u32;
        }
        bit
    }

    /// Decodes a bit written by [`Encoder::code`] with the same `p0`.
    #[inline]
    pub fn code(&mut self, p0: u32) -> bool {
        let bound = (self.range >> P16_BITS) * p0;
        let bit = self.code >= bound;
        if bit {
            self.code -= bound;
            self.range -= bound;
        } else {
            self.range = bound;
        }
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next_byte() as u32;
        }
        bit
    }

    /// Decodes `n` bits written by [`Encoder::direct`].
    pub fn direct(&mut self, n: u32) -> u32 {
        let mut v = 0;
        for _ in 0..n {
            self.range >>= 1;
            let bit = self.code >= self.range;
            if bit {
                self.code -= self.range;
            }
            v = (v << 1) | bit as u32;
            while self.range < TOP {
                self.range <<= 8;
                self.code = (self.code << 8) | self.next_byte() as u32;
            }
        }
        v
    }
}

/// A binary tree of adaptive probabilities coding `bits`-bit values.
#[derive(Clone, Debug)]
pub struct BitTree {
    bits: u32,
    probs: Vec<Prob>,
}

impl BitTree {
    /// A tree for values below `2^bits` (bits ≤ 16).
    pub fn new(bits: u32) -> Self {
        BitTree {
            bits,
            probs: vec![Prob::default(); 1 << bits],
        }
    }

    /// Back to the state of [`BitTree::new`]`(bits)`, reusing the storage.
    pub fn reset(&mut self, bits: u32) {
        self.bits = bits;
        self.probs.clear();
        self.probs.resize(1 << bits, Prob::default());
    }

    /// Encodes `value`.
    pub fn encode(&mut self, enc: &mut Encoder, value: u32) {
        let mut node = 1usize;
        for i in (0..self.bits).rev() {
            let bit = (value >> i) & 1 == 1;
            enc.bit(&mut self.probs[node], bit);
            node = (node << 1) | bit as usize;
        }
    }

    /// Decodes a value.
    pub fn decode(&mut self, dec: &mut Decoder) -> u32 {
        let mut node = 1usize;
        for _ in 0..self.bits {
            node = (node << 1) | dec.bit(&mut self.probs[node]) as usize;
        }
        (node - (1 << self.bits)) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn bits_round_trip(bits in proptest::collection::vec(any::<bool>(), 0..2000), skew in 0usize..4) {
            let mut enc = Encoder::new();
            let mut probs = [Prob::default(); 4];
            for (i, &b) in bits.iter().enumerate() {
                enc.bit(&mut probs[(i + skew) % 4], b);
            }
            enc.direct(0x2A5, 10);
            let bytes = enc.finish();
            let mut dec = Decoder::new(&bytes);
            let mut probs = [Prob::default(); 4];
            for (i, &b) in bits.iter().enumerate() {
                prop_assert_eq!(dec.bit(&mut probs[(i + skew) % 4]), b);
            }
            prop_assert_eq!(dec.direct(10), 0x2A5);
        }
    }

    #[test]
    fn skewed_bits_compress() {
        let mut enc = Encoder::new();
        let mut p = Prob::default();
        for i in 0..10_000 {
            enc.bit(&mut p, i % 100 == 0);
        }
        assert!(enc.finish().len() < 150);
    }
}
