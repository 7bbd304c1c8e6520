//! `stereolink capture`: stereo pairs from two cameras into a folder, as
//! `left_0001.png` and `right_0001.png` onward, the names `send --watch`
//! and calibration read.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_image::io;

use super::camera::CameraArgs;

/// Arguments of `stereolink capture`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = "\
Examples:
  # two webcams (MJPEG 640x480 at 30 fps): 25 chessboard pairs for
  # `stereolink calibrate`, one every 3 s while the board is moved
  stereolink capture --camera-left /dev/video0 --camera-right /dev/video2 \
      --out shots/ --frames 25 --interval-s 3

  # a raw mode, frames at most 8 ms apart
  stereolink capture --camera-left /dev/video0 --camera-right /dev/video2 \\
      --format yuyv --width 320 --height 240 --fps 15 --max-skew-ms 8 --out pairs/ --frames 100

  # any GStreamer source (here test patterns), with a JSON summary
  stereolink --json capture --source-left 'videotestsrc is-live=true pattern=ball' \\
      --source-right 'videotestsrc is-live=true pattern=snow' --out test/ --frames 30

Left and right frames are paired by buffer timestamp: frames further apart than
--max-skew-ms are dropped and counted; when writing is slower than the cameras,
the newest pair wins and the pairs skipped are counted. A camera that delivers
nothing for --frame-timeout-s, or whose stream ends, stops the capture with an
error naming it. Needs a build with `--features camera` (GStreamer).")]
pub struct Args {
    #[command(flatten)]
    /// The two cameras (live capture).
    pub camera: CameraArgs,
    /// Folder to write the pairs into (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Pairs to write.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// Seconds between the pairs written, to move a chessboard between
    /// shots (the newest pair is written; 0 writes every pair).
    #[arg(long, default_value_t = 0.0)]
    pub interval_s: f64,
}

#[derive(Serialize)]
struct Summary {
    frames: u32,
    out: PathBuf,
    dropped_left: u64,
    dropped_right: u64,
    skipped: u64,
    max_skew_ms: f64,
    mean_skew_ms: f64,
    seconds: f64,
    fps: f64,
}

/// Captures `--frames` pairs into `--out`.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let timeout = args.camera.frame_timeout()?;
    let interval = Duration::try_from_secs_f64(args.interval_s)
        .with_context(|| format!("--interval-s {} is not a duration", args.interval_s))?;
    let mut capture = args.camera.open()?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let bar = super::progress(u64::from(args.frames), "capture");
    let start = Instant::now();
    for i in 1..=args.frames {
        if i > 1 {
            std::thread::sleep(interval);
        }
        let pair = capture.next_pair(timeout)?;
        for (side, image) in [("left", &pair.left), ("right", &pair.right)] {
            io::write_rgb(args.out.join(format!("{side}_{i:04}.png")), image)?;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let stats = capture.stats();
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    let summary = Summary {
        frames: args.frames,
        out: args.out,
        dropped_left: stats.dropped_left,
        dropped_right: stats.dropped_right,
        skipped: stats.skipped,
        max_skew_ms: ms(stats.max_skew),
        mean_skew_ms: ms(stats.mean_skew()),
        seconds,
        fps: f64::from(args.frames) / seconds.max(1e-9),
    };
    out.emit(&summary, || {
        format!(
            "{} pairs in {} ({:.1} pairs/s); skew max {:.2} ms, mean {:.2} ms; \
             dropped {} left, {} right; {} pairs skipped\n",
            summary.frames,
            summary.out.display(),
            summary.fps,
            summary.max_skew_ms,
            summary.mean_skew_ms,
            summary.dropped_left,
            summary.dropped_right,
            summary.skipped
        )
    })
}
