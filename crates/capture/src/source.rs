//! What a camera is: a V4L2 device or any GStreamer source description,
//! and the GStreamer description of its branch, which ends in RGB frames at
//! an appsink.
//!
//! Two C-310 webcams on one USB bus cannot both stream raw YUYV at 640x480
//! and 30 fps (the bus bandwidth is not there), so a V4L2 camera is asked
//! for MJPEG by default and decoded by `jpegdec`.

use std::fmt;
use std::path::PathBuf;

/// The name of each branch's appsink in its bin.
pub(crate) const SINK_NAME: &str = "stereolink-sink";

/// What a V4L2 camera is asked to stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PixelFormat {
    /// Motion JPEG, decoded on the host (the default).
    #[default]
    Mjpeg,
    /// Raw YUYV 4:2:2 (more USB bandwidth, no decoding).
    Yuyv,
}

/// A V4L2 camera and the mode it is asked for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct V4l2Spec {
    /// The device (`/dev/video0`).
    pub device: PathBuf,
    /// Frame width in pixels.
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Frames per second.
    pub fps: u32,
    /// Stream format.
    pub format: PixelFormat,
}

impl V4l2Spec {
    /// `device` in MJPEG 640x480 at 30 fps.
    pub fn new(device: impl Into<PathBuf>) -> Self {
        Self {
            device: device.into(),
            width: 640,
            height: 480,
            fps: 30,
            format: PixelFormat::Mjpeg,
        }
    }

    /// The caps asked of the camera (`image/jpeg,width=640,...`).
    pub fn caps(&self) -> String {
        let media = match self.format {
            PixelFormat::Mjpeg => "image/jpeg",
            PixelFormat::Yuyv => "video/x-raw,format=YUY2",
        };
        format!(
            "{media},width={},height={},framerate={}/1",
            self.width, self.height, self.fps
        )
    }
}

/// One camera of the pair.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SourceSpec {
    /// A V4L2 device, through `v4l2src`.
    V4l2(V4l2Spec),
    /// A GStreamer source description (`videotestsrc is-live=true`,
    /// `multifilesrc location=... ! pngdec`); a converter to RGB and the
    /// appsink are appended.
    Description(String),
}

impl SourceSpec {
    /// A V4L2 device in the default mode ([`V4l2Spec::new`]).
    pub fn v4l2(device: impl Into<PathBuf>) -> Self {
        SourceSpec::V4l2(V4l2Spec::new(device))
    }

    /// A GStreamer source description.
    pub fn description(text: impl Into<String>) -> Self {
        SourceSpec::Description(text.into())
    }

    /// The caps the source is asked for, as a person reads them.
    pub fn requested_caps(&self) -> String {
        match self {
            SourceSpec::V4l2(v) => v.caps(),
            SourceSpec::Description(_) => "RGB video".to_string(),
        }
    }

    /// The GStreamer description of this camera's branch, from the source
    /// to the appsink that receives RGB frames.
    pub fn pipeline_description(&self) -> String {
        let source = match self {
            SourceSpec::V4l2(v) => {
                let device = v.device.to_string_lossy();
                let quoted = device.replace('\\', "\\\\").replace('"', "\\\"");
                let decode = match v.format {
                    PixelFormat::Mjpeg => " ! jpegdec",
                    PixelFormat::Yuyv => "",
                };
                format!("v4l2src device=\"{quoted}\" ! {}{decode}", v.caps())
            }
            SourceSpec::Description(text) => text.trim().to_string(),
        };
        format!("{source} ! videoconvert ! video/x-raw,format=RGB ! appsink name={SINK_NAME}")
    }
}

/// The device path, or the description in backquotes.
impl fmt::Display for SourceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceSpec::V4l2(v) => write!(f, "{}", v.device.display()),
            SourceSpec::Description(text) => write!(f, "`{}`", text.trim()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_v4l2_camera_defaults_to_mjpeg_640x480_at_30_fps() {
        let s = SourceSpec::v4l2("/dev/video0");
        assert_eq!(
            s.pipeline_description(),
            "v4l2src device=\"/dev/video0\" ! image/jpeg,width=640,height=480,framerate=30/1 \
             ! jpegdec ! videoconvert ! video/x-raw,format=RGB ! appsink name=stereolink-sink"
        );
        assert_eq!(s.to_string(), "/dev/video0");
    }

    #[test]
    fn a_raw_mode_needs_no_decoder() {
        let s = SourceSpec::V4l2(V4l2Spec {
            width: 320,
            height: 240,
            fps: 15,
            format: PixelFormat::Yuyv,
            ..V4l2Spec::new("/dev/v4l/by-id/my \"cam\"")
        });
        let d = s.pipeline_description();
        assert!(
            d.starts_with(
                "v4l2src device=\"/dev/v4l/by-id/my \\\"cam\\\"\" ! \
                 video/x-raw,format=YUY2,width=320,height=240,framerate=15/1 ! videoconvert"
            ),
            "{d}"
        );
        assert!(!d.contains("jpegdec"));
    }

    #[test]
    fn a_description_gets_the_converter_and_the_sink() {
        let s = SourceSpec::description(" videotestsrc is-live=true pattern=ball ");
        assert_eq!(
            s.pipeline_description(),
            "videotestsrc is-live=true pattern=ball ! videoconvert ! video/x-raw,format=RGB \
             ! appsink name=stereolink-sink"
        );
        assert_eq!(s.to_string(), "`videotestsrc is-live=true pattern=ball`");
        assert_eq!(s.requested_caps(), "RGB video");
    }
}
