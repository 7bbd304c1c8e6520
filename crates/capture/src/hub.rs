//! Where the cameras' streaming threads meet the consumer: frames, ends of
//! stream and errors come in from GStreamer's threads; [`Hub::wait`] hands
//! out the newest pair, or says which camera stopped, within a timeout.
//!
//! It knows nothing of GStreamer, so the stop and timeout logic is tested
//! with plain threads.

use std::sync::{Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use stereolink_image::RgbImage;

use crate::capture::StereoPair;
use crate::error::{Error, Result, StopReason};
use crate::pair::{PairStats, Pairer, Stamped};
use crate::Side;

struct State {
    pairer: Pairer<RgbImage>,
    last_frame: [Option<Instant>; 2],
    ended: [bool; 2],
    failure: Option<Error>,
}

/// The state shared by the streaming threads and the consumer.
pub(crate) struct Hub {
    state: Mutex<State>,
    changed: Condvar,
    /// Each camera's device or description, for messages.
    names: [String; 2],
}

// The producer side (push, end, fail, failure) is called by the GStreamer
// backend only; without it the tests still drive it.
#[cfg_attr(not(feature = "gstreamer"), allow(dead_code))]
impl Hub {
    /// A hub pairing within `max_skew`, naming the cameras `names`.
    pub fn new(max_skew: Duration, names: [String; 2]) -> Self {
        Self {
            state: Mutex::new(State {
                pairer: Pairer::new(max_skew),
                last_frame: [None; 2],
                ended: [false; 2],
                failure: None,
            }),
            changed: Condvar::new(),
            names,
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere must not become one here: the state stays usable.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The device or description of `side`'s camera.
    pub fn name(&self, side: Side) -> &str {
        &self.names[side.index()]
    }

    /// A frame of `side` taken at `pts`.
    pub fn push(&self, side: Side, pts: Duration, frame: RgbImage) {
        let mut state = self.lock();
        state.last_frame[side.index()] = Some(Instant::now());
        state.pairer.push(side, Stamped { pts, frame });
        if state.pairer.has_pair() {
            self.changed.notify_all();
        }
    }

    /// `side`'s stream ended.
    pub fn end(&self, side: Side) {
        self.lock().ended[side.index()] = true;
        self.changed.notify_all();
    }

    /// The pipeline failed; the first failure is kept.
    pub fn fail(&self, error: Error) {
        self.lock().failure.get_or_insert(error);
        self.changed.notify_all();
    }

    /// The failure recorded, if any.
    pub fn failure(&self) -> Option<Error> {
        self.lock().failure.clone()
    }

    /// What the pairer did so far.
    pub fn stats(&self) -> PairStats {
        self.lock().pairer.stats()
    }

    /// The newest pair, waiting at most `timeout` for one. A pair formed
    /// before a failure or an end of stream is still handed out first.
    pub fn wait(&self, timeout: Duration) -> Result<StereoPair> {
        let start = Instant::now();
        let mut state = self.lock();
        loop {
            if let Some(m) = state.pairer.take() {
                let (l, r) = (m.left.frame.dims(), m.right.frame.dims());
                if l != r {
                    return Err(Error::SizeMismatch { left: l, right: r });
                }
                return Ok(StereoPair {
                    left: m.left.frame,
                    right: m.right.frame,
                    left_pts: m.left.pts,
                    right_pts: m.right.pts,
                    stats: state.pairer.stats(),
                });
            }
            if let Some(error) = &state.failure {
                return Err(error.clone());
            }
            if let Some(side) = Side::BOTH.into_iter().find(|s| state.ended[s.index()]) {
                return Err(self.stopped(side, StopReason::EndOfStream));
            }
            let waited = start.elapsed();
            if waited >= timeout {
                return Err(self.timed_out(&state, start, timeout));
            }
            state = self
                .changed
                .wait_timeout(state, timeout - waited)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }

    fn stopped(&self, side: Side, reason: StopReason) -> Error {
        Error::Stopped {
            side,
            camera: self.name(side).to_string(),
            reason,
        }
    }

    /// No pair came within `timeout`: a camera that sent no frame in that
    /// time stopped (the one silent longer if both did); if both sent
    /// frames, none paired.
    fn timed_out(&self, state: &State, start: Instant, timeout: Duration) -> Error {
        let silent = Side::BOTH
            .into_iter()
            .map(|side| (side, state.last_frame[side.index()]))
            .filter(|(_, last)| last.is_none_or(|t| t < start))
            .min_by_key(|&(_, last)| last);
        if let Some((side, last)) = silent {
            let silent_for = last.map_or(timeout, |t| t.elapsed());
            return self.stopped(side, StopReason::NoFrame(silent_for));
        }
        let stats = state.pairer.stats();
        Error::Unpaired {
            max_skew: state.pairer.max_skew(),
            waited: timeout,
            dropped_left: stats.dropped_left,
            dropped_right: stats.dropped_right,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;

    fn hub() -> Arc<Hub> {
        Arc::new(Hub::new(
            Duration::from_millis(5),
            ["/dev/video0".into(), "/dev/video2".into()],
        ))
    }

    fn image(w: usize) -> RgbImage {
        RgbImage::new(w, 2, [1, 2, 3])
    }

    #[test]
    fn a_pair_from_other_threads_wakes_the_consumer() {
        let hub = hub();
        let producer = {
            let hub = Arc::clone(&hub);
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(50));
                hub.push(Side::Left, Duration::from_millis(10), image(4));
                hub.push(Side::Right, Duration::from_millis(12), image(4));
            })
        };
        let pair = hub.wait(Duration::from_secs(10)).unwrap();
        producer.join().unwrap();
        assert_eq!(pair.skew(), Duration::from_millis(2));
        assert_eq!(pair.stats.paired, 1);
        assert_eq!(pair.left.dims(), (4, 2));
    }

    #[test]
    fn a_silent_camera_is_named_after_the_timeout() {
        let hub = hub();
        hub.push(Side::Left, Duration::ZERO, image(4));
        let start = Instant::now();
        let err = hub.wait(Duration::from_millis(200)).unwrap_err();
        assert!(start.elapsed() >= Duration::from_millis(200));
        assert_eq!(
            err,
            Error::Stopped {
                side: Side::Right,
                camera: "/dev/video2".into(),
                reason: StopReason::NoFrame(Duration::from_millis(200)),
            }
        );
        assert_eq!(
            err.to_string(),
            "right camera /dev/video2 stopped: no frame for 0.2 s"
        );
    }

    #[test]
    fn a_camera_that_delivered_then_fell_silent_is_named() {
        let hub = hub();
        hub.push(Side::Left, Duration::ZERO, image(4));
        hub.push(Side::Right, Duration::ZERO, image(4));
        hub.wait(Duration::from_millis(100)).unwrap();
        let producer = {
            let hub = Arc::clone(&hub);
            std::thread::spawn(move || {
                for i in 1..30u64 {
                    hub.push(Side::Right, Duration::from_millis(33 * i), image(4));
                    std::thread::sleep(Duration::from_millis(10));
                }
            })
        };
        let err = hub.wait(Duration::from_millis(150)).unwrap_err();
        producer.join().unwrap();
        let Error::Stopped { side, reason, .. } = &err else {
            panic!("{err}");
        };
        assert_eq!(*side, Side::Left);
        assert!(matches!(reason, StopReason::NoFrame(d) if *d >= Duration::from_millis(150)));
        assert!(err
            .to_string()
            .starts_with("left camera /dev/video0 stopped: no frame for"));
    }

    #[test]
    fn the_last_pair_comes_before_the_end_of_stream() {
        let hub = hub();
        hub.push(Side::Left, Duration::ZERO, image(4));
        hub.push(Side::Right, Duration::ZERO, image(4));
        hub.end(Side::Right);
        assert!(hub.wait(Duration::from_millis(100)).is_ok());
        let err = hub.wait(Duration::from_secs(10)).unwrap_err();
        assert_eq!(
            err.to_string(),
            "right camera /dev/video2 stopped: end of stream"
        );
    }

    #[test]
    fn frames_that_never_pair_are_reported_as_such() {
        let hub = hub();
        let producer = {
            let hub = Arc::clone(&hub);
            std::thread::spawn(move || {
                for i in 0..20u64 {
                    hub.push(Side::Left, Duration::from_millis(33 * i), image(4));
                    hub.push(Side::Right, Duration::from_millis(33 * i + 10), image(4));
                    std::thread::sleep(Duration::from_millis(10));
                }
            })
        };
        let err = hub.wait(Duration::from_millis(100)).unwrap_err();
        producer.join().unwrap();
        assert!(
            matches!(err, Error::Unpaired { dropped_left, .. } if dropped_left > 0),
            "{err}"
        );
    }

    #[test]
    fn views_of_different_sizes_are_an_error() {
        let hub = hub();
        hub.push(Side::Left, Duration::ZERO, image(4));
        hub.push(Side::Right, Duration::ZERO, image(6));
        assert_eq!(
            hub.wait(Duration::from_millis(100)).unwrap_err(),
            Error::SizeMismatch {
                left: (4, 2),
                right: (6, 2)
            }
        );
    }

    #[test]
    fn a_failure_is_returned_and_kept() {
        let hub = hub();
        let error = Error::Pipeline {
            origin: "the capture pipeline".into(),
            detail: "boom".into(),
        };
        hub.fail(error.clone());
        hub.fail(Error::Unsupported);
        assert_eq!(hub.wait(Duration::from_secs(10)).unwrap_err(), error);
        assert_eq!(hub.failure(), Some(error));
    }
}
