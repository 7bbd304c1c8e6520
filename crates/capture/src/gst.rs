//! The GStreamer backend: both cameras' branches in one pipeline (one clock,
//! one base time, so their timestamps compare), each ending in an appsink
//! whose callbacks copy RGB frames into the [`Hub`]. Errors posted on the
//! bus are classified (busy device, caps it cannot deliver, other) and named
//! by the branch they came from.

use std::sync::Arc;
use std::time::Duration;

use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app::{AppSink, AppSinkCallbacks};
use gstreamer_video::{prelude::*, VideoFrameRef, VideoInfo};
use stereolink_image::RgbImage;

use crate::error::{Error, Result};
use crate::hub::Hub;
use crate::source::{SourceSpec, SINK_NAME};
use crate::Side;

/// The bin of each camera's branch.
fn bin_name(side: Side) -> String {
    format!("stereolink-{side}")
}

/// Starts GStreamer (once per process; later calls are cheap).
pub(crate) fn init() -> Result<()> {
    gst::init().map_err(|e| Error::Init(e.to_string()))
}

/// A running pipeline; dropping it stops it.
pub(crate) struct Pipeline {
    pipeline: gst::Pipeline,
}

impl Pipeline {
    /// Builds both branches into one pipeline and sets it playing.
    pub(crate) fn start(specs: [&SourceSpec; 2], hub: Arc<Hub>) -> Result<Self> {
        let pipeline = gst::Pipeline::with_name("stereolink-capture");
        let this = Self { pipeline };
        let mut sinks = Vec::with_capacity(2);
        for (side, spec) in Side::BOTH.into_iter().zip(specs) {
            let bin = gst::parse::bin_from_description_with_name(
                &spec.pipeline_description(),
                false,
                &bin_name(side),
            )
            .map_err(|e| Error::Description {
                side,
                camera: spec.to_string(),
                detail: e.message().to_string(),
            })?;
            let sink = bin
                .by_name(SINK_NAME)
                .and_then(|e| e.downcast::<AppSink>().ok())
                .ok_or_else(|| Error::Description {
                    side,
                    camera: spec.to_string(),
                    detail: "its branch does not end in the capture's appsink".into(),
                })?;
            // A slow consumer must not stall the camera: frames are copied
            // out at once, and the pairer keeps only what can still pair.
            sink.set_max_buffers(2);
            sink.set_drop(true);
            sink.set_callbacks(callbacks(side, Arc::clone(&hub)));
            sinks.push(sink);
            this.pipeline.add(&bin).map_err(|e| Error::Pipeline {
                origin: "the capture pipeline".into(),
                detail: e.to_string(),
            })?;
        }
        let bus = this.pipeline.bus().ok_or_else(|| Error::Pipeline {
            origin: "the capture pipeline".into(),
            detail: "it has no bus".into(),
        })?;
        {
            let hub = Arc::clone(&hub);
            let specs = specs.map(Clone::clone);
            bus.set_sync_handler(move |_, message| {
                if let gst::MessageView::Error(e) = message.view() {
                    let side = message.src().and_then(side_of);
                    let debug = e.debug().map(|d| d.to_string()).unwrap_or_default();
                    hub.fail(classify(side, &specs, &e.error(), &debug));
                }
                gst::BusSyncReply::Drop
            });
        }
        // Live sources (cameras) are delivered as they come: waiting on the
        // clock would only add the pipeline's latency, the largest of the
        // branches'. Files and other non-live sources play at the rate of
        // their timestamps.
        let paused = this.pipeline.set_state(gst::State::Paused);
        let live = paused == Ok(gst::StateChangeSuccess::NoPreroll);
        for sink in &sinks {
            sink.set_sync(!live);
        }
        if paused.is_err() || this.pipeline.set_state(gst::State::Playing).is_err() {
            return Err(hub.failure().unwrap_or_else(|| Error::Pipeline {
                origin: "the capture pipeline".into(),
                detail: "it could not start playing".into(),
            }));
        }
        Ok(this)
    }
}

impl Drop for Pipeline {
    fn drop(&mut self) {
        // Stopping cannot fail in a way worth reporting while dropping.
        let _ = self.pipeline.set_state(gst::State::Null);
    }
}

/// The appsink callbacks of `side`: each sample becomes a frame in `hub`.
fn callbacks(side: Side, hub: Arc<Hub>) -> AppSinkCallbacks {
    let on_eos = Arc::clone(&hub);
    AppSinkCallbacks::builder()
        .new_sample(move |sink| {
            let sample = sink.pull_sample().map_err(|_| gst::FlowError::Flushing)?;
            match rgb_frame(&sample) {
                Ok(image) => {
                    let pts = running_time(&sample).or_else(|| sink.current_running_time());
                    let pts = Duration::from_nanos(pts.map_or(0, gst::ClockTime::nseconds));
                    hub.push(side, pts, image);
                    Ok(gst::FlowSuccess::Ok)
                }
                Err(detail) => {
                    hub.fail(Error::Pipeline {
                        origin: format!("{side} camera {}", hub.name(side)),
                        detail,
                    });
                    Err(gst::FlowError::Error)
                }
            }
        })
        .eos(move |_| on_eos.end(side))
        .build()
}

/// The running time of a sample's buffer: its timestamp in the pipeline's
/// clock, comparable between the branches.
fn running_time(sample: &gst::Sample) -> Option<gst::ClockTime> {
    let pts = sample.buffer()?.pts()?;
    sample
        .segment()?
        .downcast_ref::<gst::ClockTime>()?
        .to_running_time(pts)
}

/// Copies an RGB sample into an image (rows may be padded).
fn rgb_frame(sample: &gst::Sample) -> std::result::Result<RgbImage, String> {
    let caps = sample.caps().ok_or("a frame without caps")?;
    let info = VideoInfo::from_caps(caps).map_err(|e| format!("unusable caps {caps}: {e}"))?;
    let buffer = sample.buffer().ok_or("a sample without a buffer")?;
    let frame = VideoFrameRef::from_buffer_ref_readable(buffer, &info)
        .map_err(|e| format!("cannot map a frame: {e}"))?;
    let (w, h) = (frame.width() as usize, frame.height() as usize);
    let stride = usize::try_from(frame.plane_stride()[0]).map_err(|_| "a negative stride")?;
    let data = frame
        .plane_data(0)
        .map_err(|e| format!("cannot read a frame: {e}"))?;
    let mut pixels = Vec::with_capacity(w * h);
    for y in 0..h {
        let row = data
            .get(y * stride..y * stride + w * 3)
            .ok_or("a frame shorter than its caps")?;
        pixels.extend(row.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
    }
    RgbImage::from_vec(w, h, pixels).map_err(|e| e.to_string())
}

/// Which branch an object belongs to, by its ancestor bins.
fn side_of(object: &gst::Object) -> Option<Side> {
    let mut next = Some(object.clone());
    while let Some(o) = next {
        if let Some(side) = Side::BOTH.into_iter().find(|&s| o.name() == bin_name(s)) {
            return Some(side);
        }
        next = o.parent();
    }
    None
}

/// Turns a bus error into the error a person can act on.
fn classify(
    side: Option<Side>,
    specs: &[SourceSpec; 2],
    error: &gst::glib::Error,
    debug: &str,
) -> Error {
    let detail = if debug.is_empty() {
        error.message().to_string()
    } else {
        format!("{}; {debug}", error.message())
    };
    let Some(side) = side else {
        return Error::Pipeline {
            origin: "the capture pipeline".into(),
            detail,
        };
    };
    let spec = &specs[side.index()];
    let camera = spec.to_string();
    match spec {
        SourceSpec::V4l2(v) if error.matches(gst::ResourceError::NotFound) => Error::NoDevice {
            side,
            device: v.device.clone(),
        },
        _ if error.matches(gst::ResourceError::Busy) => Error::Busy {
            side,
            camera,
            detail,
        },
        _ if debug.contains("not-negotiated") || error.matches(gst::CoreError::Negotiation) => {
            Error::Caps {
                side,
                camera,
                requested: spec.requested_caps(),
                detail,
            }
        }
        _ => Error::Pipeline {
            origin: format!("{side} camera {camera}"),
            detail,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn specs() -> [SourceSpec; 2] {
        [
            SourceSpec::v4l2("/dev/video0"),
            SourceSpec::v4l2("/dev/video2"),
        ]
    }

    #[test]
    fn a_busy_device_is_named() {
        let e = gst::glib::Error::new(gst::ResourceError::Busy, "Device '/dev/video2' is busy");
        let err = classify(Some(Side::Right), &specs(), &e, "");
        assert!(
            matches!(
                err,
                Error::Busy {
                    side: Side::Right,
                    ..
                }
            ),
            "{err}"
        );
        assert!(
            err.to_string()
                .starts_with("right camera /dev/video2 is busy"),
            "{err}"
        );
    }

    #[test]
    fn a_device_that_lacks_the_mode_names_the_caps() {
        let e = gst::glib::Error::new(gst::StreamError::Failed, "Internal data stream error.");
        let debug = "streaming stopped, reason not-negotiated (-4)";
        let err = classify(Some(Side::Left), &specs(), &e, debug);
        assert!(
            err.to_string().starts_with(
                "left camera /dev/video0 cannot deliver image/jpeg,width=640,height=480,framerate=30/1"
            ),
            "{err}"
        );
    }

    #[test]
    fn a_vanished_device_and_a_pipeline_error() {
        let e = gst::glib::Error::new(gst::ResourceError::NotFound, "Cannot identify device");
        let err = classify(Some(Side::Left), &specs(), &e, "");
        assert_eq!(
            err.to_string().split(':').next(),
            Some("left camera /dev/video0")
        );
        assert!(matches!(err, Error::NoDevice { .. }));
        let err = classify(None, &specs(), &e, "");
        assert!(
            err.to_string()
                .starts_with("the capture pipeline: Cannot identify device"),
            "{err}"
        );
    }
}
