//! From depth to motion, safely.
//!
//! The axis moves toward the target by the reported distance minus a
//! stand-off, clamped to soft limits, at no more than the maximum speed; a
//! new report while moving retargets. Only a [`ValidatedDistance`] moves the
//! axis: it can be built only from a finite, positive distance, and the
//! receiver builds it only from a message that passed its CRC and decoding
//! checks, so a damaged message can never drive the axis. A [`Watchdog`]
//! stops the axis when no valid report arrived for a while.

use std::time::{Duration, Instant};

/// A distance that passed every check and may drive the axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValidatedDistance(f64);

impl ValidatedDistance {
    /// Accepts a finite distance in `(0, 100]` metres.
    pub fn new(metres: f64) -> Option<Self> {
        (metres.is_finite() && metres > 0.0 && metres <= 100.0).then_some(ValidatedDistance(metres))
    }

    /// The distance in metres.
    pub fn metres(self) -> f64 {
        self.0
    }
}

/// Motion limits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionPolicy {
    /// Stop this far short of the target, mm.
    pub standoff_mm: f64,
    /// Soft limits of the axis, mm from home.
    pub min_mm: f64,
    /// Upper soft limit, mm.
    pub max_mm: f64,
    /// Speed limit, mm/s.
    pub max_speed_mm_s: f64,
}

impl Default for MotionPolicy {
    /// A 1 m axis, no stand-off, 50 mm/s.
    fn default() -> Self {
        MotionPolicy {
            standoff_mm: 0.0,
            min_mm: 0.0,
            max_mm: 1000.0,
            max_speed_mm_s: 50.0,
        }
    }
}

/// Where the policy sends the axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Move {
    /// Target position, mm from home.
    pub position_mm: f64,
    /// Speed, mm/s.
    pub speed_mm_s: f64,
    /// True when the soft limits cut the move short.
    pub clamped: bool,
}

impl MotionPolicy {
    /// The move for a validated distance.
    pub fn plan(&self, distance: ValidatedDistance) -> Move {
        let wanted = distance.metres() * 1000.0 - self.standoff_mm;
        let position_mm = wanted.clamp(self.min_mm, self.max_mm);
        Move {
            position_mm,
            speed_mm_s: self.max_speed_mm_s,
            clamped: position_mm != wanted,
        }
    }
}

/// Stops the axis when no valid report arrived for `timeout`.
#[derive(Clone, Copy, Debug)]
pub struct Watchdog {
    timeout: Duration,
    last: Instant,
    tripped: bool,
}

impl Watchdog {
    /// A watchdog fed now.
    pub fn new(timeout: Duration) -> Self {
        Watchdog {
            timeout,
            last: Instant::now(),
            tripped: false,
        }
    }

    /// Records a valid report (and re-arms a tripped watchdog).
    pub fn feed(&mut self, now: Instant) {
        self.last = now;
        self.tripped = false;
    }

    /// True once `timeout` passed since the last valid report.
    pub fn expired(&self, now: Instant) -> bool {
        now.duration_since(self.last) > self.timeout
    }

    /// True the first time it is found expired after a feed: the moment to
    /// stop the axis (and say so once, not at every check).
    pub fn trip(&mut self, now: Instant) -> bool {
        let trips = !self.tripped && self.expired(now);
        self.tripped |= trips;
        trips
    }

    /// Trips again at the next check while still expired (the stop did not
    /// take).
    pub fn rearm(&mut self) {
        self.tripped = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_sane_distances_validate() {
        for bad in [f64::NAN, f64::INFINITY, -1.0, 0.0, 1e6] {
            assert!(ValidatedDistance::new(bad).is_none(), "{bad}");
        }
        assert_eq!(ValidatedDistance::new(0.5).unwrap().metres(), 0.5);
    }

    #[test]
    fn plan_subtracts_the_standoff_and_clamps() {
        let p = MotionPolicy {
            standoff_mm: 100.0,
            min_mm: 0.0,
            max_mm: 500.0,
            max_speed_mm_s: 20.0,
        };
        let m = p.plan(ValidatedDistance::new(0.4).unwrap());
        assert!((m.position_mm - 300.0).abs() < 1e-9 && !m.clamped && m.speed_mm_s == 20.0);
        assert_eq!(
            p.plan(ValidatedDistance::new(2.0).unwrap()).position_mm,
            500.0
        );
        assert!(p.plan(ValidatedDistance::new(0.05).unwrap()).clamped);
    }

    #[test]
    fn watchdog_expires() {
        let t0 = Instant::now();
        let mut w = Watchdog::new(Duration::from_millis(100));
        w.feed(t0);
        assert!(!w.expired(t0 + Duration::from_millis(50)));
        assert!(w.expired(t0 + Duration::from_millis(150)));
        assert!(!w.trip(t0 + Duration::from_millis(50)));
        assert!(w.trip(t0 + Duration::from_millis(150)));
        assert!(!w.trip(t0 + Duration::from_millis(200)), "trips once");
        w.feed(t0 + Duration::from_millis(300));
        assert!(
            w.trip(t0 + Duration::from_millis(450)),
            "re-armed by a feed"
        );
    }
}
