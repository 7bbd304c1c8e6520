//! The stereo pairer: left and right frames, each with its buffer timestamp,
//! are paired when their timestamps lie within a maximum skew.
//!
//! Each camera delivers its frames in timestamp order, but the two run
//! unsynchronised: a frame may be late, missing or doubled on one side.
//! A frame that can no longer meet a partner within the skew (the other
//! side has moved past it) is dropped and counted. When the consumer is
//! slower than the cameras, the newest pair wins: an untaken pair that a
//! newer one replaces is counted as skipped, so a robot always acts on the
//! latest view and never on a backlog.

use std::collections::VecDeque;
use std::time::Duration;

use crate::Side;

/// A frame with its buffer timestamp (the pipeline's running time).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stamped<T> {
    /// When the frame was taken.
    pub pts: Duration,
    /// The frame.
    pub frame: T,
}

/// A left and a right frame whose timestamps lie within the maximum skew.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Matched<T> {
    /// The left frame.
    pub left: Stamped<T>,
    /// The right frame.
    pub right: Stamped<T>,
}

impl<T> Matched<T> {
    /// The absolute difference of the two timestamps.
    pub fn skew(&self) -> Duration {
        self.left.pts.abs_diff(self.right.pts)
    }
}

/// What the pairer did with the frames it was given.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairStats {
    /// Pairs formed (delivered, skipped or waiting to be taken).
    pub paired: u64,
    /// Left frames dropped: stale, out of order or without a partner.
    pub dropped_left: u64,
    /// Right frames dropped: stale, out of order or without a partner.
    pub dropped_right: u64,
    /// Pairs replaced by a newer one before the consumer took them.
    pub skipped: u64,
    /// The largest skew of a pair formed.
    pub max_skew: Duration,
    total_skew: Duration,
}

impl PairStats {
    /// The mean skew of the pairs formed (zero before the first).
    pub fn mean_skew(&self) -> Duration {
        match u32::try_from(self.paired) {
            Ok(0) => Duration::ZERO,
            Ok(n) => self.total_skew / n,
            Err(_) => Duration::from_secs_f64(self.total_skew.as_secs_f64() / self.paired as f64),
        }
    }

    /// Frames dropped on `side`.
    pub fn dropped(&self, side: Side) -> u64 {
        match side {
            Side::Left => self.dropped_left,
            Side::Right => self.dropped_right,
        }
    }

    fn drop_one(&mut self, side: Side) {
        match side {
            Side::Left => self.dropped_left += 1,
            Side::Right => self.dropped_right += 1,
        }
    }
}

/// Pairs two timestamped streams (see the [module docs](self)).
#[derive(Debug)]
pub struct Pairer<T> {
    max_skew: Duration,
    capacity: usize,
    queues: [VecDeque<Stamped<T>>; 2],
    newest: Option<Matched<T>>,
    stats: PairStats,
}

impl<T> Pairer<T> {
    /// Frames waiting on one side for a partner, at most; older ones are
    /// dropped (a camera whose partner has stopped must not fill memory).
    pub const DEFAULT_CAPACITY: usize = 8;

    /// A pairer that pairs frames at most `max_skew` apart.
    pub fn new(max_skew: Duration) -> Self {
        Self::with_capacity(max_skew, Self::DEFAULT_CAPACITY)
    }

    /// A pairer that keeps at most `capacity` (at least 1) unpaired frames
    /// per side.
    pub fn with_capacity(max_skew: Duration, capacity: usize) -> Self {
        Self {
            max_skew,
            capacity: capacity.max(1),
            queues: [VecDeque::new(), VecDeque::new()],
            newest: None,
            stats: PairStats::default(),
        }
    }

    /// The maximum skew of a pair.
    pub fn max_skew(&self) -> Duration {
        self.max_skew
    }

    /// What happened so far.
    pub fn stats(&self) -> PairStats {
        self.stats
    }

    /// Whether a pair is waiting to be [taken](Self::take).
    pub fn has_pair(&self) -> bool {
        self.newest.is_some()
    }

    /// Adds a frame of `side`. A frame older than the last one of its side
    /// is dropped.
    pub fn push(&mut self, side: Side, frame: Stamped<T>) {
        let queue = &mut self.queues[side.index()];
        if queue.back().is_some_and(|last| frame.pts < last.pts) {
            self.stats.drop_one(side);
            return;
        }
        queue.push_back(frame);
        if queue.len() > self.capacity {
            queue.pop_front();
            self.stats.drop_one(side);
        }
        self.pair_fronts();
    }

    /// The newest pair, if one was formed since the last call.
    pub fn take(&mut self) -> Option<Matched<T>> {
        self.newest.take()
    }

    /// Pairs the queues' fronts while they can be decided.
    fn pair_fronts(&mut self) {
        loop {
            let [left, right] = &self.queues;
            let (Some(l), Some(r)) = (left.front(), right.front()) else {
                return;
            };
            let (older, newer_pts) = if l.pts <= r.pts {
                (Side::Left, r.pts)
            } else {
                (Side::Right, l.pts)
            };
            let queue = &self.queues[older.index()];
            let gap = queue[0].pts.abs_diff(newer_pts);
            // Too old for any frame of the other side (its frames only get
            // newer), or a later frame of the same side is closer.
            let closer_next = queue
                .get(1)
                .is_some_and(|next| next.pts.abs_diff(newer_pts) < gap);
            if gap > self.max_skew || closer_next {
                self.queues[older.index()].pop_front();
                self.stats.drop_one(older);
                continue;
            }
            let (Some(left), Some(right)) =
                (self.queues[0].pop_front(), self.queues[1].pop_front())
            else {
                return;
            };
            self.stats.paired += 1;
            self.stats.max_skew = self.stats.max_skew.max(gap);
            self.stats.total_skew += gap;
            if self.newest.replace(Matched { left, right }).is_some() {
                self.stats.skipped += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    fn frame(pts_ms: u64, id: u32) -> Stamped<u32> {
        Stamped {
            pts: ms(pts_ms),
            frame: id,
        }
    }

    fn ids(m: &Matched<u32>) -> (u32, u32) {
        (m.left.frame, m.right.frame)
    }

    #[test]
    fn frames_with_close_timestamps_pair_in_order() {
        let mut p = Pairer::new(ms(5));
        for i in 0..10u32 {
            let t = u64::from(i) * 33;
            p.push(Side::Left, frame(t, i));
            assert!(p.take().is_none(), "paired before the right frame came");
            p.push(Side::Right, frame(t + u64::from(i % 3), 100 + i));
            let m = p.take().expect("a pair");
            assert_eq!(ids(&m), (i, 100 + i));
            assert_eq!(m.skew(), ms(u64::from(i % 3)));
        }
        let s = p.stats();
        assert_eq!(s.paired, 10);
        assert_eq!((s.dropped_left, s.dropped_right, s.skipped), (0, 0, 0));
        assert_eq!(s.max_skew, ms(2));
        // Skews 0,1,2,0,1,2,0,1,2,0: 9 ms over 10 pairs.
        assert_eq!(s.mean_skew(), Duration::from_micros(900));
    }

    #[test]
    fn a_frame_without_a_partner_is_dropped() {
        let mut p = Pairer::new(ms(5));
        p.push(Side::Left, frame(0, 0));
        p.push(Side::Left, frame(33, 1));
        // The right camera missed t = 0.
        p.push(Side::Right, frame(34, 11));
        assert_eq!(ids(&p.take().unwrap()), (1, 11));
        // The left camera missed t = 66.
        p.push(Side::Right, frame(67, 12));
        p.push(Side::Left, frame(99, 3));
        assert!(p.take().is_none());
        p.push(Side::Right, frame(100, 13));
        assert_eq!(ids(&p.take().unwrap()), (3, 13));
        let s = p.stats();
        assert_eq!((s.paired, s.dropped_left, s.dropped_right), (2, 1, 1));
    }

    #[test]
    fn frames_further_apart_than_the_skew_never_pair() {
        let mut p = Pairer::new(ms(5));
        for i in 0..20u32 {
            let t = u64::from(i) * 33;
            p.push(Side::Left, frame(t, i));
            p.push(Side::Right, frame(t + 6, i));
        }
        assert!(p.take().is_none());
        let s = p.stats();
        assert_eq!(s.paired, 0);
        assert_eq!(s.dropped_left, 20);
    }

    #[test]
    fn the_newest_pair_wins_and_skipped_pairs_are_counted() {
        let mut p = Pairer::new(ms(5));
        for i in 0..5u32 {
            p.push(Side::Right, frame(u64::from(i) * 33, 10 + i));
            p.push(Side::Left, frame(u64::from(i) * 33 + 1, i));
        }
        assert_eq!(ids(&p.take().unwrap()), (4, 14));
        assert!(p.take().is_none());
        let s = p.stats();
        assert_eq!((s.paired, s.skipped), (5, 4));
    }

    #[test]
    fn a_closer_later_frame_is_preferred() {
        // Left frames at 0 and 4, right at 4: both within 5 ms of it, the
        // second exactly.
        let mut p = Pairer::new(ms(5));
        p.push(Side::Left, frame(0, 0));
        p.push(Side::Left, frame(4, 1));
        p.push(Side::Right, frame(4, 10));
        assert_eq!(ids(&p.take().unwrap()), (1, 10));
        assert_eq!(p.stats().dropped_left, 1);
        assert_eq!(p.stats().max_skew, Duration::ZERO);
    }

    #[test]
    fn a_stopped_partner_does_not_fill_memory() {
        let mut p = Pairer::with_capacity(ms(5), 3);
        for i in 0..100u32 {
            p.push(Side::Left, frame(u64::from(i) * 33, i));
        }
        assert_eq!(p.stats().dropped_left, 97);
        // The three newest are still there to pair.
        p.push(Side::Right, frame(99 * 33, 7));
        assert_eq!(ids(&p.take().unwrap()), (99, 7));
    }

    #[test]
    fn an_out_of_order_frame_is_dropped() {
        let mut p = Pairer::new(ms(5));
        p.push(Side::Left, frame(33, 1));
        p.push(Side::Left, frame(0, 0));
        p.push(Side::Right, frame(33, 11));
        assert_eq!(ids(&p.take().unwrap()), (1, 11));
        assert_eq!(p.stats().dropped_left, 1);
    }

    /// Two 30 fps streams with a fixed phase offset, jitter, lost frames and
    /// random arrival order: every pair is within the skew, its frames are
    /// the same tick, and every frame is paired, dropped or still queued.
    #[test]
    fn jittered_streams_pair_correctly() {
        let mut seed = 0x2545_f491_4f6c_dd1d_u64;
        let mut rand = move |n: u64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % n
        };
        let interval = 33_333u64; // µs
        let max_skew = Duration::from_micros(interval / 2);
        let mut p = Pairer::new(max_skew);
        let (mut pushed, mut next) = ([0u64; 2], [0u32; 2]);
        let mut taken = 0u64;
        while next[0] < 3000 || next[1] < 3000 {
            // Arrival order is random, but neither camera runs more than
            // three frames ahead of the other.
            let side = if next[0] >= 3000 || next[0] > next[1] + 3 {
                Side::Right
            } else if next[1] >= 3000 || next[1] > next[0] + 3 || rand(2) == 0 {
                Side::Left
            } else {
                Side::Right
            };
            let tick = next[side.index()];
            next[side.index()] += 1;
            if rand(20) == 0 {
                continue; // a lost frame
            }
            let offset = if side == Side::Right { 9_000 } else { 0 };
            let jitter = rand(2_000);
            let pts = Duration::from_micros(u64::from(tick) * interval + offset + jitter);
            p.push(side, Stamped { pts, frame: tick });
            pushed[side.index()] += 1;
            if rand(3) == 0 {
                if let Some(m) = p.take() {
                    assert!(m.skew() <= max_skew, "{:?}", m.skew());
                    assert_eq!(m.left.frame, m.right.frame);
                    taken += 1;
                }
            }
        }
        taken += u64::from(p.take().is_some());
        let s = p.stats();
        assert!(s.paired > 2500, "{s:?}");
        assert_eq!(s.paired, taken + s.skipped);
        assert!(s.max_skew <= max_skew);
        for side in [Side::Left, Side::Right] {
            let queued = p.queues[side.index()].len() as u64;
            assert_eq!(pushed[side.index()], s.paired + s.dropped(side) + queued);
        }
    }
}
