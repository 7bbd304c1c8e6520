//! The sliding anti-replay window of RFC 6479 ("IPsec Anti-Replay Algorithm
//! without Bit Shifting"): a ring of 64-bit blocks, so sliding the window
//! clears whole blocks instead of shifting a long bitmap. WireGuard uses the
//! same construction for its transport counters.

/// Bits in one block of the ring.
const BLOCK_BITS: u64 = 64;
/// Blocks in the ring; one of them is always being refilled.
const BLOCKS: usize = 16;
/// Counters this far below the highest one seen are still judged
/// individually: (16 − 1) · 64 = 960.
pub const WINDOW: u64 = (BLOCKS as u64 - 1) * BLOCK_BITS;

/// Which of the recent counters were seen (RFC 6479 § 2).
#[derive(Clone, Debug, Default)]
pub struct ReplayWindow {
    /// The highest counter accepted so far (0 before any).
    last: u64,
    ring: [u64; BLOCKS],
}

/// Why a counter is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stale {
    /// It was accepted before.
    Seen,
    /// It lies below the window: it cannot be told from a replay.
    TooOld,
}

impl ReplayWindow {
    /// Whether `counter` may be accepted; changes nothing, so a message can
    /// be judged before its tag is checked and marked only after.
    pub fn check(&self, counter: u64) -> Result<(), Stale> {
        if counter > self.last {
            return Ok(());
        }
        if self.last - counter >= WINDOW {
            return Err(Stale::TooOld);
        }
        if self.ring[Self::block(counter)] & Self::bit(counter) != 0 {
            return Err(Stale::Seen);
        }
        Ok(())
    }

    /// Marks `counter` accepted (after [`check`](Self::check) passed and the
    /// message authenticated), sliding the window when it is the new highest.
    pub fn mark(&mut self, counter: u64) {
        if counter > self.last {
            let (from, to) = (self.last / BLOCK_BITS, counter / BLOCK_BITS);
            let cleared = (to - from).min(BLOCKS as u64);
            for i in 1..=cleared {
                self.ring[((from + i) % BLOCKS as u64) as usize] = 0;
            }
            self.last = counter;
        }
        self.ring[Self::block(counter)] |= Self::bit(counter);
    }

    fn block(counter: u64) -> usize {
        ((counter / BLOCK_BITS) % BLOCKS as u64) as usize
    }

    fn bit(counter: u64) -> u64 {
        1 << (counter % BLOCK_BITS)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn accept(w: &mut ReplayWindow, c: u64) -> Result<(), Stale> {
        w.check(c)?;
        w.mark(c);
        Ok(())
    }

    #[test]
    fn each_counter_once_in_any_order_within_the_window() {
        let mut w = ReplayWindow::default();
        for c in [0, 5, 3, 1000, 999, 41] {
            assert_eq!(accept(&mut w, c), Ok(()), "{c}");
        }
        for c in [1000, 999, 41] {
            assert_eq!(accept(&mut w, c), Err(Stale::Seen), "{c}");
        }
        assert_eq!(accept(&mut w, 5), Err(Stale::TooOld));
        assert_eq!(accept(&mut w, 1000 - WINDOW), Err(Stale::TooOld));
        assert_eq!(accept(&mut w, 1002 - WINDOW), Ok(()));
    }

    proptest! {
        /// Against a set of every counter ever accepted: the window never
        /// accepts one twice, and accepts every new one inside the window.
        #[test]
        fn agrees_with_a_complete_record(counters in proptest::collection::vec(0u64..3000, 1..400)) {
            let mut w = ReplayWindow::default();
            let mut seen = std::collections::BTreeSet::new();
            let mut high = 0u64;
            for c in counters {
                let got = accept(&mut w, c);
                let inside = c > high || high - c < WINDOW;
                if seen.contains(&c) {
                    prop_assert!(got.is_err());
                } else {
                    prop_assert_eq!(got.is_ok(), inside);
                }
                if got.is_ok() {
                    seen.insert(c);
                    high = high.max(c);
                }
            }
        }
    }
}
