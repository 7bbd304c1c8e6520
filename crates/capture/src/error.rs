//! The capture crate's one error type: each variant names the camera (its
//! side and its device or source description) and what went wrong.

use std::path::PathBuf;
use std::time::Duration;

use crate::Side;

/// Why a camera stopped delivering frames.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// Its stream ended (a file source at its end, `num-buffers` reached,
    /// a device unplugged).
    EndOfStream,
    /// No frame came for this long.
    NoFrame(Duration),
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopReason::EndOfStream => f.write_str("end of stream"),
            StopReason::NoFrame(d) => write!(f, "no frame for {:.1} s", d.as_secs_f64()),
        }
    }
}

/// What can go wrong between two cameras and a stereo pair.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Error {
    /// The crate was built without the `gstreamer` feature.
    #[error("this build has no GStreamer support (the `gstreamer` feature of stereolink-capture)")]
    Unsupported,
    /// GStreamer itself could not be started.
    #[error("GStreamer could not start: {0}")]
    Init(String),
    /// The camera device does not exist.
    #[error("{side} camera {}: no such device (is it plugged in? `ls /dev/video*` lists the cameras)", device.display())]
    NoDevice {
        /// Which camera.
        side: Side,
        /// The device path.
        device: PathBuf,
    },
    /// The camera device is in use by another program.
    #[error("{side} camera {camera} is busy: another program is using it ({detail})")]
    Busy {
        /// Which camera.
        side: Side,
        /// The device or source description.
        camera: String,
        /// What GStreamer said.
        detail: String,
    },
    /// The camera cannot deliver the requested format, size or rate.
    #[error("{side} camera {camera} cannot deliver {requested} ({detail}); `v4l2-ctl --list-formats-ext -d DEVICE` lists what it can")]
    Caps {
        /// Which camera.
        side: Side,
        /// The device or source description.
        camera: String,
        /// The caps asked for.
        requested: String,
        /// What GStreamer said.
        detail: String,
    },
    /// A source description that GStreamer cannot parse.
    #[error("{side} source {camera} is not a valid GStreamer description: {detail}")]
    Description {
        /// Which camera.
        side: Side,
        /// The description.
        camera: String,
        /// What the parser said.
        detail: String,
    },
    /// Another GStreamer error, in one camera's branch or in the pipeline.
    #[error("{origin}: {detail}")]
    Pipeline {
        /// `left camera /dev/video0`, or `the capture pipeline`.
        origin: String,
        /// What GStreamer said.
        detail: String,
    },
    /// A camera stopped mid-stream.
    #[error("{side} camera {camera} stopped: {reason}")]
    Stopped {
        /// Which camera.
        side: Side,
        /// The device or source description.
        camera: String,
        /// End of stream or no frame within the timeout.
        reason: StopReason,
    },
    /// Both cameras deliver, but no two frames lie within the maximum skew.
    #[error(
        "both cameras deliver frames but none pair within {:.1} ms in {:.1} s \
         ({dropped_left} left and {dropped_right} right frames dropped): are both \
         sources in one pipeline and at the same frame rate? or allow a larger maximum skew",
        max_skew.as_secs_f64() * 1e3,
        waited.as_secs_f64()
    )]
    Unpaired {
        /// The maximum skew.
        max_skew: Duration,
        /// How long was waited.
        waited: Duration,
        /// Left frames dropped so far.
        dropped_left: u64,
        /// Right frames dropped so far.
        dropped_right: u64,
    },
    /// The two cameras deliver frames of different sizes.
    #[error("the cameras deliver different sizes: left {}x{}, right {}x{}", left.0, left.1, right.0, right.1)]
    SizeMismatch {
        /// Width and height of the left frames.
        left: (usize, usize),
        /// Width and height of the right frames.
        right: (usize, usize),
    },
}

/// The capture crate's result.
pub type Result<T> = std::result::Result<T, Error>;
