//! Live capture of two cameras for stereolink: from two V4L2 webcams, or
//! any two GStreamer sources, to stereo pairs of [`RgbImage`]s paired by
//! buffer timestamp.
//!
//! # Brief overview
//!
//! * [`pair`]: the [`Pairer`], which pairs left and right frames within a
//!   maximum skew, drops stale or unpaired frames and lets the newest pair
//!   win when the consumer is slower than the cameras. Pure, always built.
//! * [`source`]: what a camera is ([`SourceSpec`]): a V4L2 device (MJPEG
//!   640x480 at 30 fps by default) or a GStreamer source description, and
//!   the pipeline description each becomes.
//! * [`StereoCapture`]: both sources in one GStreamer pipeline, so that they
//!   share a clock and a base time and their timestamps compare; it needs
//!   the `gstreamer` feature, and without it [`StereoCapture::open`] returns
//!   [`Error::Unsupported`].
//!
//! Every wait has a timeout: a camera that stops mid-stream is an error
//! naming it ([`Error::Stopped`]), never a hang.

mod capture;
mod error;
#[cfg(feature = "gstreamer")]
mod gst;
mod hub;
pub mod pair;
pub mod source;

pub use capture::{CaptureOptions, StereoCapture, StereoPair};
pub use error::{Error, Result, StopReason};
pub use pair::{Matched, PairStats, Pairer, Stamped};
pub use source::{PixelFormat, SourceSpec, V4l2Spec};
pub use stereolink_image::RgbImage;

/// Which camera of the pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    /// The left camera (the reference view).
    Left,
    /// The right camera.
    Right,
}

impl Side {
    /// Both sides, left first.
    pub const BOTH: [Side; 2] = [Side::Left, Side::Right];

    /// 0 for the left camera, 1 for the right.
    pub fn index(self) -> usize {
        self as usize
    }

    /// `"left"` or `"right"`.
    pub fn name(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
}

impl std::fmt::Display for Side {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
