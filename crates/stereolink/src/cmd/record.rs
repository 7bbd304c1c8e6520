//! `--record FILE.mcap`, as `send` and `receive` take it (docs/recording.md).

use std::path::PathBuf;

use stereolink_codec::container::{self, Body};
use stereolink_codec::Limits;
use stereolink_pipeline::receiver::{BoardReceiver, Event};
use stereolink_pipeline::record::{OnError, Recorder, UNCALIBRATED};

/// The recording flags.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Record the run in FILE.mcap: ROS 2 messages (views, cameras,
    /// disparity, depth reports, link statistics, the baseline) that
    /// `ros2 bag play`, Foxglove, Lichtblick and Rerun open as they are.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// When the recording cannot be written mid-run (a full disk): it is
    /// closed, and the run goes on without it or stops.
    #[arg(long, value_enum, default_value_t = OnError::Continue, requires = "record")]
    pub record_errors: OnError,
}

impl RecordArgs {
    /// The recording, created now: a path that cannot be written fails
    /// before any work.
    pub fn open(&self) -> anyhow::Result<Option<Recorder>> {
        let Some(path) = &self.record else {
            return Ok(None);
        };
        Ok(Some(Recorder::create(path, self.record_errors)?))
    }
}

/// What the board took from one message, into the recording: a frame's
/// views as received, their cameras and the board's disparity (with the
/// calibration the frame carries), or a depth report; stamped with the
/// sender's capture time (`stamp_us`, from the message's header).
pub fn received(
    recorder: &mut Recorder,
    board: &mut BoardReceiver,
    (msg, stamp_us): (&[u8], u64),
    event: &Event,
) -> anyhow::Result<()> {
    let limits = Limits::default();
    match (event, container::parse(msg, &limits)) {
        (Event::Frame { .. }, Ok((_, Body::StereoFrame(frame)))) => {
            let calib = frame.calibration.unwrap_or(UNCALIBRATED);
            let disparity = board.disparity();
            if let Some(views) = board.pair() {
                recorder.views(stamp_us, views, &calib)?;
                recorder.disparity(stamp_us, &disparity, &calib)?;
            }
        }
        (Event::Report { .. }, Ok((_, Body::DepthReport(report)))) => {
            recorder.report(stamp_us, &report)?;
        }
        _ => {}
    }
    Ok(())
}
