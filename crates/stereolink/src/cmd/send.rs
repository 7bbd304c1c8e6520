//! `stereolink send`: the sender on a real link, for one pair (sent
//! `--repeat` times), for every pair a camera writes into a folder
//! (`--watch`), or live from two cameras (`--camera-left`/`--source-left`).
//! The arguments open the link and choose the pairs; the pair loop is the
//! pipeline's ([`stereolink_pipeline::live`]); this prints each frame sent.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use stereolink_codec::planetable::TableCoding;
use stereolink_image::io;
use stereolink_link::arq::Config;
use stereolink_link::endpoint::{Endpoint, Progress, ProgressReport};
use stereolink_link::secure::SecureConfig;
use stereolink_link::spec;
use stereolink_link::transport::Transport;
use stereolink_pipeline::coding::CodingSpec;
use stereolink_pipeline::live::{SendLoop, Sent, Status, Update};
use stereolink_pipeline::pairs::Pairs;
use stereolink_pipeline::sender::SenderConfig;
use stereolink_pipeline::uplink::Uplink;
use stereolink_stereo::depth::{LevelSpec, Roi};

use super::calib::CalibArgs;
use super::camera::CameraArgs;
use super::codec::CodingArgs;
use super::keygen::KeyArgs;
use super::matching::MatcherArgs;
use super::segment::SegmentArgs;

/// Arguments of `stereolink send`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = "\
Examples:
  # one pair of files
  stereolink send --link 'serial:/dev/ttyUSB0?api=2' --left L.png --right R.png --method fodpso

  # every new pair a capture program writes into a folder
  stereolink send --link 'serial:/dev/ttyUSB0?api=2' --watch /var/spool/stereo --method fodpso

  # live from two webcams (needs a build with --features camera)
  stereolink send --link 'serial:/dev/ttyUSB0?api=2' --camera-left /dev/video0 \\
      --camera-right /dev/video2 --method kmeans --max-disp 32 --focal-px 670 --baseline-m 0.06

  # the paper's two radio pairs: frames on one, depth reports on the other
  stereolink send --link 'serial:/dev/ttyUSB0?api=2' --report-link 'serial:/dev/ttyUSB1?api=2' \\
      --left L.png --right R.png

  # live from GStreamer test sources over UDP
  stereolink send --link 'udp:127.0.0.1:9001?peer=127.0.0.1:9000' \\
      --source-left 'videotestsrc is-live=true pattern=ball' \\
      --source-right 'videotestsrc is-live=true pattern=ball' --frames 100

Every pair taken is matched, and its depth report (cut to one radio packet)
goes at once, ahead of any frame in flight: the robot gets depth at the
camera's rate. Live (--watch, cameras), a pair becomes a frame only when the
link has finished the frame before; the newest pair always wins and the pairs
skipped are counted. Each frame prints a timing line (capture wait, segment,
match, encode, send), and once a second a status line on stderr says what the
link carried (pairs in and skipped, reports/s and their capture-to-delivery
latency, frames/s, bytes, kb/s and retransmissions); --json prints every frame
and the run's status at the end. A camera that stops (no frame for --frame-timeout-s, or the end
of its stream) stops the sender with an error naming it; the board's watchdog
then stops the axis.

Commands from the peer (a gateway's Control messages; with keys, only the
paired peer's) are obeyed between pairs and answered on the link: levels and
method hold from the next pair, a frame request sends the last pair again at
once with the current settings (live cameras: the next pair, which goes at
once anyway), and an axis stop is refused (a sender drives no axis). Each is
logged on stderr.")]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B;
    /// several make a bond.
    #[arg(long, required = true, long_help = super::LINK_HELP)]
    pub link: Vec<String>,
    /// A second link for the depth reports (the paper's second radio pair),
    /// so that a report never shares the air with a frame; without it,
    /// reports go ahead of the frame's fragments on --link.
    #[arg(long, value_name = "SPEC")]
    pub report_link: Option<String>,
    /// Left image.
    #[arg(
        long,
        required_unless_present_any = ["watch", "left_camera"],
        conflicts_with_all = ["watch", "left_camera"]
    )]
    pub left: Option<PathBuf>,
    /// Right image.
    #[arg(
        long,
        required_unless_present_any = ["watch", "left_camera"],
        conflicts_with_all = ["watch", "left_camera"]
    )]
    pub right: Option<PathBuf>,
    /// A camera folder: send the pairs written into it (`left*.png` with
    /// the `right*.png` of the same name; a rewritten pair is new again),
    /// the newest in name order first, until --frames frames are sent or the
    /// program is stopped.
    #[arg(long, value_name = "DIR", conflicts_with = "left_camera")]
    pub watch: Option<PathBuf>,
    /// With --watch: how often the folder is read, in milliseconds.
    #[arg(long, default_value_t = 200, requires = "watch")]
    pub poll_ms: u64,
    /// With --watch or cameras: stop after this many frames.
    #[arg(long, conflicts_with = "left")]
    pub frames: Option<u32>,
    #[command(flatten)]
    /// The two cameras (live capture).
    pub camera: CameraArgs,
    /// Largest disparity searched for the depth report.
    #[arg(long, default_value_t = 64)]
    pub max_disp: usize,
    #[command(flatten)]
    /// The rig's calibration: focal length, baseline and doffs, or a stereo calibration file.
    pub calib: CalibArgs,
    /// Target region x,y,w,h (default: the central ninth of the image).
    #[arg(long)]
    pub roi: Option<Roi>,
    /// Also write the views as sent (sent-left.png, sent-right.png)
    /// and the sender's disparity map (sent-disparity.pfm) here.
    #[arg(long)]
    pub save: Option<PathBuf>,
    /// Size each frame to cross the link in about this many seconds: its
    /// byte budget is the goodput measured on the last frames times this
    /// (the coding's rate control: quality for jpeg/webp, classes for
    /// segmented; the first frame takes --bytes if given). Overrides --bytes.
    #[arg(long, value_name = "SECONDS", value_parser = positive_seconds)]
    pub frame_interval_s: Option<f64>,
    #[command(flatten)]
    /// Temporal prediction of the frames.
    pub temporal: TemporalArgs,
    /// Give up on a message (and stop) when it is not acknowledged within
    /// this many seconds.
    #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u64).range(1..))]
    pub deadline_s: u64,
    /// Send the pair this many times (frame ids 1, 2, ...).
    #[arg(long, default_value_t = 1, conflicts_with_all = ["watch", "left_camera"])]
    pub repeat: u32,
    #[command(flatten)]
    /// How the views are coded, and the frame's byte budget.
    pub coding: CodingArgs,
    #[command(flatten)]
    /// The segmentation method and its parameters.
    pub segment: SegmentArgs,
    #[command(flatten)]
    /// The matcher and its parameters.
    pub matcher: MatcherArgs,
    /// With --algo planes: fraction bits of the plane table's slants (0–16;
    /// default 12, a slant to 1/4096 px per px). Fewer bits, fewer bytes;
    /// a plane is then off by up to 2^−(bits+1)·(x + y) px at (x, y).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=16))]
    pub plane_slant_bits: Option<u8>,
    /// With --algo planes: fraction bits of the planes' offsets (0–16;
    /// default 5, 1/32 px).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=16))]
    pub plane_offset_bits: Option<u8>,
    /// With --algo planes: segments of fewer pixels take the plane of the
    /// segment above (else left of) them without a coded index (default 2:
    /// one-pixel segments; 0 codes every index). docs/wire-format.md
    /// lists the bytes and the accuracy of other choices.
    #[arg(long)]
    pub plane_implied_below: Option<u16>,
    #[command(flatten)]
    /// The pairing keys of the secure link.
    pub keys: KeyArgs,
    #[command(flatten)]
    /// `--record FILE.mcap`.
    pub record: super::record::RecordArgs,
    #[command(flatten)]
    /// `--config FILE.toml`.
    pub config: crate::config::ConfigArg,
}

impl Args {
    /// The plane table's coding from the flags and the defaults.
    fn plane_table(&self) -> TableCoding {
        let d = TableCoding::default();
        TableCoding {
            slant_bits: self.plane_slant_bits.unwrap_or(d.slant_bits),
            offset_bits: self.plane_offset_bits.unwrap_or(d.offset_bits),
            implied_below: self.plane_implied_below.unwrap_or(d.implied_below),
        }
    }
}

/// Temporal prediction on the link (shared by `send` and `bench live`).
#[derive(Debug, clap::Args)]
pub struct TemporalArgs {
    /// Predict each frame from the last one the link delivered: blocks
    /// that changed no more than sensor noise are skipped, the others
    /// coded (lossy views), or the label maps coded from the previous ones
    /// (segmented). The sender keeps what the receiver rebuilt, bit for
    /// bit. A receiver without the reference (restarted) shows nothing
    /// wrong: it refuses predicted frames until the next key frame.
    #[arg(long)]
    pub temporal: bool,
    /// With --temporal: a key frame at least this often, seconds (and on a
    /// frame request, and first).
    #[arg(long, default_value_t = 10.0, value_parser = positive_seconds, requires = "temporal")]
    pub key_every_s: f64,
}

impl TemporalArgs {
    /// How often a key frame goes, with temporal prediction on.
    pub fn key_every(&self) -> Option<Duration> {
        self.temporal
            .then(|| Duration::from_secs_f64(self.key_every_s))
    }
}

/// A positive, finite number of seconds (at most a day).
pub fn positive_seconds(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(s) if s.is_finite() && s > 0.0 && s <= 86_400.0 => Ok(s),
        _ => Err(format!(
            "{text:?} is not a number of seconds between 0 and 86400"
        )),
    }
}

/// What the sender does with each pair, from the segmentation and matcher
/// flags (shared by `send` and `bench live`).
pub fn sender_config(
    (segment, matcher): (&SegmentArgs, &MatcherArgs),
    max_disp: usize,
    roi: Option<Roi>,
    (plane_table, coding): (TableCoding, CodingSpec),
) -> anyhow::Result<SenderConfig> {
    Ok(SenderConfig {
        method: segment.method()?,
        levels: segment.levels,
        seed: segment.seed,
        carry_margin: segment.carry_margin()?,
        matcher: matcher.depth_spec(0, max_disp)?,
        roi,
        levels_spec: LevelSpec::default(),
        plane_table,
        coding,
    })
}

/// Prepares and sends the pair, or each pair of the watched folder.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let sensor = args.calib.sensor(args.max_disp + 1)?;
    let recorder = args.record.open()?;
    if let Some(w) = sensor.range_warning() {
        eprintln!("warning: {w}");
    }
    let cfg = sender_config(
        (&args.segment, &args.matcher),
        args.max_disp,
        args.roi,
        (args.plane_table(), args.coding.spec()),
    )?;
    let transport = super::open_links(&args.link)?;
    let report_transport = match &args.report_link {
        Some(text) => Some(
            spec::open(&super::link_spec(text)?)
                .with_context(|| format!("cannot open report link {text}"))?,
        ),
        None => None,
    };
    let keys = args.keys.load(false)?;
    let deadline_s = args.deadline_s;
    let endpoint = move |transport: Box<dyn Transport>, link: String| {
        let arq = Config {
            deadline: deadline_s.saturating_mul(1_000_000),
            ..Config::for_mtu(transport.mtu())
        };
        let mut ep = Endpoint::with_config(transport, arq)?;
        if let Some(keys) = keys.clone() {
            ep = ep.with_keys(keys, SecureConfig::default());
        }
        let hint = link.clone();
        ep.on_silence(
            SILENCE_HINT,
            Box::new(move |silent| eprintln!("{}", silence_hint(&hint, silent, deadline_s))),
        );
        ep.on_notice(Box::new(move |notice| eprintln!("link {link}: {notice}")));
        anyhow::Ok(ep)
    };
    let (link, report_link) = (super::links_name(&args.link), args.report_link.clone());
    let uplink = Uplink::start(move || {
        let mut frames = endpoint(transport, link)?;
        if std::io::stderr().is_terminal() {
            frames.on_progress(progress_bar());
        }
        let reports = match (report_transport, report_link) {
            (Some(t), Some(l)) => Some(endpoint(t, l)?),
            _ => None,
        };
        Ok((frames, reports))
    });
    let mut sender = SendLoop::new(
        uplink,
        sensor.depth,
        sensor.rectifier()?,
        cfg,
        args.save.clone(),
    )
    .record(recorder);
    if let Some(s) = args.frame_interval_s {
        sender = sender.frame_interval(Duration::from_secs_f64(s));
    }
    if let Some(key_every) = args.temporal.key_every() {
        sender = sender.temporal(key_every);
    }
    let pairs = match (&args.watch, &args.left, &args.right) {
        (Some(dir), _, _) => Pairs::folder(dir.clone(), Duration::from_millis(args.poll_ms)),
        (None, Some(left), Some(right)) => {
            Pairs::files(io::read_rgb(left)?, io::read_rgb(right)?, args.repeat)
        }
        _ if args.camera.given() => {
            Pairs::cameras(args.camera.frame_timeout()?, args.camera.open()?)
        }
        _ => anyhow::bail!("give --left and --right, --watch DIR, or the cameras"),
    };
    let json = out.json;
    let summary = sender.run(pairs, args.frames, |p| match p {
        Update::Frame(s) if !json => print(s),
        Update::Second(s) => eprintln!("{}", status_line(s)),
        Update::Frame(_) => {}
    })?;
    out.emit(&summary, || format!("{}\n", status_line(&summary.status)))
}

/// A status line: pairs in and skipped, what was delivered, the link.
pub fn status_line(s: &Status) -> String {
    let depth_alone = match s.report_air_share {
        Some(share) if s.depth_alone() => format!(
            " (reports need {:.0} % of the air: depth goes alone, no frames)",
            share * 100.0
        ),
        _ => String::new(),
    };
    format!(
        "pairs: {} in, {} skipped; acknowledged: {} ({} more reports overtaken before their acknowledgement){depth_alone}; link: {:.1} kb/s, {} retransmissions; {}",
        s.pairs,
        s.skipped,
        s.delivered,
        s.superseded,
        s.goodput_bps / 1e3,
        s.retransmissions,
        s.link
    )
}

/// How long a message waits with nothing heard back before the sender says
/// what to check.
const SILENCE_HINT: Duration = Duration::from_secs(3);

/// What to check when the peer on `link` has been silent for `silent`.
fn silence_hint(link: &str, silent: Duration, deadline_s: u64) -> String {
    format!(
        "nothing has come back from the peer on {link} for {:.0} s (still retrying, \
         up to {deadline_s} s per message). Check:
  - is the peer running `stereolink receive` on the other end of this link?
  - do both ends use the same link settings: the API mode (api=, and the radios' AP) \
and the baud rate (baud=)?
  - does the destination (dest=, or udp peer=) match the peer's address (its MY or SH/SL)?
  - is this a direct cable or USB link with no radios between the ends? then both need api=0",
        silent.as_secs_f64()
    )
}

/// A terminal progress bar for each message: fragments acknowledged, the
/// goodput so far and the retransmissions; cleared when the message is done.
fn progress_bar() -> ProgressReport {
    let mut bar: Option<indicatif::ProgressBar> = None;
    Box::new(move |p: &Progress| {
        let b = bar.get_or_insert_with(|| super::progress(p.fragments as u64, "sending"));
        b.set_position(p.acked as u64);
        b.set_message(format!(
            "fragments, {:.1} kb/s, {} retransmissions",
            p.goodput_bps() / 1e3,
            p.retransmissions
        ));
        if p.acked == p.fragments {
            if let Some(b) = bar.take() {
                b.finish_and_clear();
            }
        }
    })
}

/// The lines of one frame sent.
fn print(s: &Sent) {
    println!(
        "frame {}: {} B sent in {:.2} s ({:.1} kb/s, {} retransmissions); its {} B depth report {}, distance {:.3} m",
        s.frame_id,
        s.frame_bytes,
        s.seconds,
        s.goodput_bps / 1e3,
        s.retransmissions,
        s.report_bytes,
        s.report_seconds.map_or("overtaken by a newer one before its acknowledgement".into(), |t| format!("delivered in {t:.2} s")),
        s.distance_m
    );
    println!(
        "  timing: capture wait {:.1} ms, rectify {:.1} ms, segment {:.1} ms, match {:.1} ms, encode {:.1} ms, send {:.1} ms; {} pairs skipped",
        s.wait_ms, s.rectify_ms, s.segment_ms, s.match_ms, s.encode_ms, s.send_ms, s.skipped
    );
    println!("  link: {}", s.link);
}
