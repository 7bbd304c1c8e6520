//! `stereolink bench live`: the live chain on a recorded sequence over the
//! simulated radio in real time, as [`stereolink_pipeline::live_bench`]
//! runs it; prints what both ends measured.

use std::path::PathBuf;
use std::time::Duration;

use stereolink_codec::planetable::TableCoding;
use stereolink_link::spec::LinkSpec;
use stereolink_pipeline::live_bench::{self, LiveFigures};
use stereolink_pipeline::pairs::Pairs;

use super::calib::CalibArgs;
use super::codec::CodingArgs;
use super::matching::MatcherArgs;
use super::segment::SegmentArgs;

/// Arguments of `stereolink bench live`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = "\
Examples:
  stereolink bench live --sequence seq/ --rate 10 --link 'sim:?radio=zigbee' \\
      --calib seq/calib.txt --method kmeans --levels 3
  stereolink --json bench live --sequence seq/ --link 'sim:?radio=zigbee&hops=4&encrypted=1'

The folder's pairs (left*.png with the right*.png of the same name) are played
in name order as a camera delivering --rate pairs a second. The sender matches
every pair it takes and sends its depth report at once; a pair becomes a frame
when the link has finished the frame before. The receiver applies each report
to a simulated axis and shows each frame. Both ends run in this process, in
real time over the simulated radio, at its calibrated throughput (Digi's
measured figures: docs/benchmarks.md, \"Link\"). The sender and the receiver
each print what they counted; a report's latency is from its pair's capture to
the receiver's move (receiver) or to its acknowledgement (sender).")]
pub struct Args {
    /// The recorded pairs: a folder of left*.png and right*.png.
    #[arg(long, value_name = "DIR")]
    pub sequence: PathBuf,
    /// Pairs a second the camera delivers.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// The simulated radio: sim:?radio=zigbee (hops=, encrypted=, role=),
    /// sim:?radio=digimesh, or sim: (802.15.4).
    #[arg(long, default_value = "sim:?radio=zigbee")]
    pub link: String,
    /// Largest disparity searched, by the sender and by the board.
    #[arg(long, default_value_t = 64)]
    pub max_disp: usize,
    /// Size each frame to cross the link in about this many seconds (as
    /// `send --frame-interval-s`).
    #[arg(long, value_name = "SECONDS", value_parser = super::send::positive_seconds)]
    pub frame_interval_s: Option<f64>,
    /// The board stops the axis when no valid report came for this long, seconds.
    #[arg(long, default_value_t = 0.5)]
    pub watchdog_s: f64,
    #[command(flatten)]
    /// The rig's calibration: focal length, baseline and doffs, or a stereo calibration file.
    pub calib: CalibArgs,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
    #[command(flatten)]
    /// The matcher and its parameters.
    pub matcher: MatcherArgs,
    #[command(flatten)]
    /// How the views are coded, and the frame's byte budget.
    pub coding: CodingArgs,
    #[command(flatten)]
    /// Temporal prediction of the frames.
    pub temporal: super::send::TemporalArgs,
}

/// Runs the live bench and prints its figures.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let LinkSpec::Sim { config, .. } = super::link_spec(&args.link)? else {
        anyhow::bail!(
            "bench live runs over the simulated radio (--link 'sim:?radio=zigbee'); \
             on real radios, run send and receive"
        );
    };
    anyhow::ensure!(
        args.watchdog_s.is_finite() && args.watchdog_s > 0.0,
        "--watchdog-s must be a positive number of seconds (got {})",
        args.watchdog_s
    );
    let sensor = args.calib.sensor(args.max_disp + 1)?;
    let cfg = super::send::sender_config(
        (&args.segment, &args.matcher),
        args.max_disp,
        None,
        (TableCoding::default(), args.coding.spec()),
    )?;
    let pairs = Pairs::sequence(&args.sequence, args.rate)?;
    let figures = live_bench::run(
        (pairs, Duration::from_secs_f64(1.0 / args.rate)),
        config,
        (
            cfg,
            sensor.depth,
            (
                args.frame_interval_s.map(Duration::from_secs_f64),
                args.temporal.key_every(),
            ),
        ),
        (args.max_disp, Duration::from_secs_f64(args.watchdog_s)),
        |s| eprintln!("{}", super::send::status_line(s)),
    )?;
    out.emit(&figures, || human(&figures))
}

fn human(f: &LiveFigures) -> String {
    format!(
        "sender: {}\nreceiver: {}; {} refused, watchdog tripped {} times\n",
        super::send::status_line(&f.sender),
        f.receiver,
        f.refused,
        f.watchdog_trips
    )
}
