//! [`StereoCapture`]: two cameras in one GStreamer pipeline, their frames
//! paired by timestamp.

use std::sync::Arc;
use std::time::Duration;

use stereolink_image::RgbImage;

use crate::error::{Error, Result};
use crate::hub::Hub;
use crate::pair::PairStats;
use crate::source::SourceSpec;
use crate::Side;

/// How the cameras are paired and started.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CaptureOptions {
    /// Frames further apart than this never pair (default 15 ms, under half
    /// the frame interval at 30 fps).
    pub max_skew: Duration,
    /// How long the first pair may take, at least: a webcam takes a second
    /// or so to start streaming (default 5 s).
    pub start_timeout: Duration,
}

impl Default for CaptureOptions {
    fn default() -> Self {
        Self {
            max_skew: Duration::from_millis(15),
            start_timeout: Duration::from_secs(5),
        }
    }
}

/// A stereo pair from the cameras.
#[derive(Clone, Debug)]
pub struct StereoPair {
    /// The left view.
    pub left: RgbImage,
    /// The right view.
    pub right: RgbImage,
    /// The left frame's timestamp (the pipeline's running time).
    pub left_pts: Duration,
    /// The right frame's timestamp.
    pub right_pts: Duration,
    /// The pairer's counts when the pair was handed out.
    pub stats: PairStats,
}

impl StereoPair {
    /// The absolute difference of the two timestamps.
    pub fn skew(&self) -> Duration {
        self.left_pts.abs_diff(self.right_pts)
    }
}

/// Two cameras streaming into one pipeline, paired by timestamp. Dropping
/// it stops the pipeline.
pub struct StereoCapture {
    hub: Arc<Hub>,
    options: CaptureOptions,
    started: bool,
    // Declared last: dropped (stopped) after nothing else needs it.
    _pipeline: backend::Pipeline,
}

impl StereoCapture {
    /// Starts `left` and `right` in one pipeline. Fails, naming the camera,
    /// when a device is absent or busy or a description does not parse;
    /// errors that show only once frames flow (caps a camera cannot
    /// deliver) come from [`next_pair`](Self::next_pair).
    pub fn open(left: &SourceSpec, right: &SourceSpec, options: CaptureOptions) -> Result<Self> {
        backend::init()?;
        for (side, spec) in Side::BOTH.into_iter().zip([left, right]) {
            if let SourceSpec::V4l2(v) = spec {
                if !v.device.exists() {
                    return Err(Error::NoDevice {
                        side,
                        device: v.device.clone(),
                    });
                }
            }
        }
        let hub = Arc::new(Hub::new(
            options.max_skew,
            [left.to_string(), right.to_string()],
        ));
        let pipeline = backend::Pipeline::start([left, right], Arc::clone(&hub))?;
        Ok(Self {
            hub,
            options,
            started: false,
            _pipeline: pipeline,
        })
    }

    /// The newest pair, waiting at most `timeout` for one (at least the
    /// start timeout for the first pair). A camera that sends nothing in
    /// that time, or whose stream ends, is an [`Error::Stopped`] naming it.
    pub fn next_pair(&mut self, timeout: Duration) -> Result<StereoPair> {
        let timeout = if self.started {
            timeout
        } else {
            timeout.max(self.options.start_timeout)
        };
        let pair = self.hub.wait(timeout)?;
        self.started = true;
        Ok(pair)
    }

    /// What the pairer did so far.
    pub fn stats(&self) -> PairStats {
        self.hub.stats()
    }
}

#[cfg(feature = "gstreamer")]
use crate::gst as backend;

/// Without GStreamer, nothing can be opened.
#[cfg(not(feature = "gstreamer"))]
mod backend {
    use std::sync::Arc;

    use crate::error::{Error, Result};
    use crate::hub::Hub;
    use crate::source::SourceSpec;

    pub(crate) fn init() -> Result<()> {
        Err(Error::Unsupported)
    }

    /// No pipeline can exist in this build.
    pub(crate) struct Pipeline {
        _never: std::convert::Infallible,
    }

    impl Pipeline {
        pub(crate) fn start(_: [&SourceSpec; 2], _: Arc<Hub>) -> Result<Self> {
            Err(Error::Unsupported)
        }
    }
}

#[cfg(all(test, not(feature = "gstreamer")))]
mod tests {
    use super::*;

    #[test]
    fn without_gstreamer_nothing_opens() {
        let err = StereoCapture::open(
            &SourceSpec::description("videotestsrc"),
            &SourceSpec::v4l2("/dev/video99"),
            CaptureOptions::default(),
        );
        assert_eq!(err.err(), Some(Error::Unsupported));
    }
}
