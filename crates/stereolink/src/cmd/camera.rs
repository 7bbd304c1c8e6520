//! Camera options shared by the commands that capture live (`capture`,
//! `send`): two V4L2 devices or two GStreamer source descriptions, the mode
//! asked of the devices, and how frames are paired.

use std::path::PathBuf;
use std::time::Duration;

use clap::ArgGroup;
use stereolink_capture::{CaptureOptions, PixelFormat, SourceSpec, StereoCapture, V4l2Spec};

/// What to say when the binary was built without cameras.
const NOT_BUILT: &str = "this stereolink was built without cameras: install Debian's \
     libgstreamer1.0-dev libgstreamer-plugins-base1.0-dev gstreamer1.0-plugins-base \
     gstreamer1.0-plugins-good, then `cargo build --release --features camera`";

/// Two cameras: each a V4L2 device or a GStreamer source description.
#[derive(Debug, Clone, clap::Args)]
#[command(group(ArgGroup::new("left_camera").args(["camera_left", "source_left"])))]
#[command(group(ArgGroup::new("right_camera").args(["camera_right", "source_right"])))]
pub struct CameraArgs {
    /// Left camera: a V4L2 device (MJPEG 640x480 at 30 fps unless --width,
    /// --height, --fps or --format say otherwise).
    #[arg(long, value_name = "DEVICE", requires = "right_camera")]
    pub camera_left: Option<PathBuf>,
    /// Right camera: a V4L2 device.
    #[arg(long, value_name = "DEVICE", requires = "left_camera")]
    pub camera_right: Option<PathBuf>,
    /// Left camera as a GStreamer source description ("videotestsrc
    /// is-live=true", "multifilesrc location=f%04d.png ! pngdec"); the
    /// conversion to RGB is appended.
    #[arg(long, value_name = "DESCRIPTION", requires = "right_camera")]
    pub source_left: Option<String>,
    /// Right camera as a GStreamer source description.
    #[arg(long, value_name = "DESCRIPTION", requires = "left_camera")]
    pub source_right: Option<String>,
    /// Frame width asked of the V4L2 cameras.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// Frame height asked of the V4L2 cameras.
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Frame rate asked of the V4L2 cameras.
    #[arg(long, default_value_t = 30)]
    pub fps: u32,
    /// Stream format asked of the V4L2 cameras: mjpeg (two webcams on one
    /// USB bus need it) or yuyv.
    #[arg(long, default_value = "mjpeg", value_parser = ["mjpeg", "yuyv"])]
    pub format: String,
    /// Left and right frames further apart than this (by buffer timestamp)
    /// never pair.
    #[arg(long, default_value_t = 15.0, value_name = "MS")]
    pub max_skew_ms: f64,
    /// A camera that delivers no frame for this long has stopped (an error).
    #[arg(long, default_value_t = 2.0, value_name = "S")]
    pub frame_timeout_s: f64,
}

impl CameraArgs {
    /// Whether cameras were given.
    pub fn given(&self) -> bool {
        self.camera_left.is_some() || self.source_left.is_some()
    }

    fn spec(&self, device: &Option<PathBuf>, source: &Option<String>) -> Option<SourceSpec> {
        let format = match self.format.as_str() {
            "yuyv" => PixelFormat::Yuyv,
            _ => PixelFormat::Mjpeg,
        };
        match (device, source) {
            (Some(device), _) => Some(SourceSpec::V4l2(V4l2Spec {
                width: self.width,
                height: self.height,
                fps: self.fps,
                format,
                ..V4l2Spec::new(device)
            })),
            (None, Some(text)) => Some(SourceSpec::description(text)),
            (None, None) => None,
        }
    }

    /// How long a camera may be silent.
    pub fn frame_timeout(&self) -> anyhow::Result<Duration> {
        Duration::try_from_secs_f64(self.frame_timeout_s).map_err(|_| {
            anyhow::anyhow!(
                "--frame-timeout-s {} is not a duration",
                self.frame_timeout_s
            )
        })
    }

    /// Starts the two cameras.
    pub fn open(&self) -> anyhow::Result<StereoCapture> {
        let (Some(left), Some(right)) = (
            self.spec(&self.camera_left, &self.source_left),
            self.spec(&self.camera_right, &self.source_right),
        ) else {
            anyhow::bail!(
                "give the cameras: --camera-left DEVICE --camera-right DEVICE, or \
                 --source-left DESCRIPTION --source-right DESCRIPTION"
            );
        };
        let max_skew = Duration::try_from_secs_f64(self.max_skew_ms / 1e3)
            .map_err(|_| anyhow::anyhow!("--max-skew-ms {} is not a duration", self.max_skew_ms))?;
        let options = CaptureOptions {
            max_skew,
            ..CaptureOptions::default()
        };
        StereoCapture::open(&left, &right, options).map_err(|e| match e {
            stereolink_capture::Error::Unsupported => anyhow::anyhow!(NOT_BUILT),
            e => e.into(),
        })
    }
}
