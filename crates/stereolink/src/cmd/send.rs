//! `stereolink send`: the sender on a real link, for one pair (sent
//! `--repeat` times), for every pair a camera writes into a folder
//! (`--watch`), or live from two cameras (`--camera-left`/`--source-left`).
//! All three feed one loop ([`Pairs`]): take a pair, prepare it, send it.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_calib::StereoRectifier;
use stereolink_image::{io, Calibration, RgbImage};
use stereolink_link::arq::Config;
use stereolink_link::endpoint::Endpoint;
use stereolink_link::spec;
use stereolink_stereo::depth::{LevelSpec, Roi};

use stereolink_capture::StereoCapture;

use super::calib::CalibArgs;
use super::camera::CameraArgs;
use super::keygen::KeyArgs;
use super::matching::MatcherArgs;
use super::segment::SegmentArgs;
use crate::pipeline::sender::{prepare, SenderConfig};
use crate::pipeline::watch::{Pair, Watcher};

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

  # live from GStreamer test sources over UDP
  stereolink send --link 'udp:127.0.0.1:9001?peer=127.0.0.1:9000' \\
      --source-left 'videotestsrc is-live=true pattern=ball' \\
      --source-right 'videotestsrc is-live=true pattern=ball' --frames 100

Live, pairs are sent at the rate the link carries: while one is prepared and
sent the cameras run on, the newest pair wins and the pairs skipped are
counted. Each frame prints a timing line (capture wait, segment, match,
encode, send). A camera that stops (no frame for --frame-timeout-s, or the end
of its stream) stops the sender with an error naming it; the board's watchdog
then stops the axis.")]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B.
    #[arg(long)]
    pub link: String,
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
    /// A camera folder: send each new pair written into it (`left*.png` with
    /// the `right*.png` of the same name, in name order; a rewritten pair is
    /// sent again) until --frames pairs are sent or the program is stopped.
    #[arg(long, value_name = "DIR", conflicts_with = "left_camera")]
    pub watch: Option<PathBuf>,
    /// With --watch: how often the folder is read, in milliseconds.
    #[arg(long, default_value_t = 200, requires = "watch")]
    pub poll_ms: u64,
    /// With --watch or cameras: stop after this many pairs.
    #[arg(long, conflicts_with = "left")]
    pub frames: Option<u32>,
    #[command(flatten)]
    pub camera: CameraArgs,
    /// Largest disparity searched for the depth report.
    #[arg(long, default_value_t = 64)]
    pub max_disp: usize,
    #[command(flatten)]
    pub calib: CalibArgs,
    /// Target region x,y,w,h (default: the central ninth of the image).
    #[arg(long)]
    pub roi: Option<Roi>,
    /// Also write the segmented views as sent (sent-left.png, sent-right.png) here.
    #[arg(long)]
    pub save: Option<PathBuf>,
    /// Give up on a message (and stop) when it is not acknowledged within
    /// this many seconds.
    #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u64).range(1..))]
    pub deadline_s: u64,
    /// Send the pair this many times (frame ids 1, 2, ...).
    #[arg(long, default_value_t = 1, conflicts_with_all = ["watch", "left_camera"])]
    pub repeat: u32,
    #[command(flatten)]
    pub segment: SegmentArgs,
    #[command(flatten)]
    pub matcher: MatcherArgs,
    #[command(flatten)]
    pub keys: KeyArgs,
}

#[derive(Serialize)]
struct Sent {
    frame_id: u32,
    frame_bytes: usize,
    report_bytes: usize,
    distance_m: f32,
    seconds: f64,
    goodput_bps: f64,
    retransmissions: u64,
    /// Pairs the cameras delivered while the one before was prepared and sent.
    skipped: u64,
    wait_ms: f64,
    rectify_ms: f64,
    segment_ms: f64,
    match_ms: f64,
    encode_ms: f64,
    send_ms: f64,
}

/// Prepares and sends the pair, or each pair of the watched folder.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let spec = super::link_spec(&args.link)?;
    let sensor = args.calib.sensor(args.max_disp + 1)?;
    if let Some(w) = sensor.range_warning() {
        eprintln!("warning: {w}");
    }
    let cfg = SenderConfig {
        method: args.segment.method()?,
        levels: args.segment.levels,
        seed: args.segment.seed,
        carry_margin: args.segment.carry_margin()?,
        matcher: args.matcher.depth_spec(0, args.max_disp)?,
        roi: args.roi,
        levels_spec: LevelSpec::default(),
    };
    let transport = spec::open(&spec).with_context(|| format!("cannot open link {}", args.link))?;
    let arq = Config {
        deadline: args.deadline_s.saturating_mul(1_000_000),
        ..Config::for_mtu(transport.mtu())
    };
    let mut ep = args
        .keys
        .apply(Endpoint::with_config(transport, arq)?, false)?;
    let (link, deadline_s) = (args.link.clone(), args.deadline_s);
    ep.on_silence(
        SILENCE_HINT,
        Box::new(move |silent| eprintln!("{}", silence_hint(&link, silent, deadline_s))),
    );
    let mut sender = Sender {
        ep,
        calib: sensor.depth,
        rectifier: sensor.rectifier()?,
        rectified: Default::default(),
        cfg,
        save: args.save.clone(),
        json: out.json,
        sent: Vec::new(),
    };
    let mut pairs = match (&args.watch, &args.left, &args.right) {
        (Some(dir), _, _) => Pairs::Folder {
            dir: dir.clone(),
            poll: Duration::from_millis(args.poll_ms),
            watcher: Watcher::new(),
            pending: VecDeque::new(),
        },
        (None, Some(left), Some(right)) => Pairs::Files {
            left: io::read_rgb(left)?,
            right: io::read_rgb(right)?,
            remaining: args.repeat,
        },
        _ if args.camera.given() => Pairs::Cameras {
            timeout: args.camera.frame_timeout()?,
            capture: Box::new(args.camera.open()?),
            skipped: 0,
        },
        _ => anyhow::bail!("give --left and --right, --watch DIR, or the cameras"),
    };
    let mut frame_id = 0;
    while args.frames.is_none_or(|n| frame_id < n) {
        let Some(next) = pairs.next()? else { break };
        frame_id += 1;
        sender.send(&next, frame_id)?;
    }
    if out.json {
        out.emit(&sender.sent, String::new)?;
    }
    Ok(())
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

/// The open link and what every frame is prepared with.
struct Sender {
    ep: Endpoint,
    calib: Calibration,
    /// The maps of a raw pair (`--calib stereo.yml`).
    rectifier: Option<StereoRectifier>,
    /// The rectified views, reused from pair to pair.
    rectified: (RgbImage, RgbImage),
    cfg: SenderConfig,
    save: Option<PathBuf>,
    json: bool,
    sent: Vec<Sent>,
}

/// A pair to send, and what getting it cost.
struct Next {
    left: RgbImage,
    right: RgbImage,
    /// Time spent waiting for the pair (reading it, or for the cameras).
    wait_ms: f64,
    /// Pairs skipped since the previous one (live cameras only).
    skipped: u64,
}

/// Where the pairs come from; the send loop is the same for all.
enum Pairs {
    /// One pair of files, sent `remaining` more times.
    Files {
        left: RgbImage,
        right: RgbImage,
        remaining: u32,
    },
    /// Each new pair a capture program writes into `dir`, read every `poll`.
    Folder {
        dir: PathBuf,
        poll: Duration,
        watcher: Watcher,
        pending: VecDeque<Pair>,
    },
    /// Two live cameras; `skipped` is their count at the last pair.
    Cameras {
        capture: Box<StereoCapture>,
        timeout: Duration,
        skipped: u64,
    },
}

impl Pairs {
    /// The next pair, or `None` when there is no more. A folder is waited
    /// on forever; a camera that stops is an error.
    fn next(&mut self) -> anyhow::Result<Option<Next>> {
        let start = Instant::now();
        let wait_ms = || start.elapsed().as_secs_f64() * 1e3;
        match self {
            Pairs::Files {
                left,
                right,
                remaining,
            } => {
                if *remaining == 0 {
                    return Ok(None);
                }
                *remaining -= 1;
                Ok(Some(Next {
                    left: left.clone(),
                    right: right.clone(),
                    wait_ms: wait_ms(),
                    skipped: 0,
                }))
            }
            Pairs::Folder {
                dir,
                poll,
                watcher,
                pending,
            } => loop {
                let Some(pair) = pending.pop_front() else {
                    pending.extend(watcher.pending(dir).with_context(|| {
                        format!("cannot read the camera folder {}", dir.display())
                    })?);
                    if pending.is_empty() {
                        std::thread::sleep(*poll);
                    }
                    continue;
                };
                if let Some((left, right)) = read_pair(watcher, &pair)? {
                    return Ok(Some(Next {
                        left,
                        right,
                        wait_ms: wait_ms(),
                        skipped: 0,
                    }));
                }
            },
            Pairs::Cameras {
                capture,
                timeout,
                skipped,
            } => {
                let pair = capture.next_pair(*timeout)?;
                let new = pair.stats.skipped - *skipped;
                *skipped = pair.stats.skipped;
                Ok(Some(Next {
                    left: pair.left,
                    right: pair.right,
                    wait_ms: wait_ms(),
                    skipped: new,
                }))
            }
        }
    }
}

/// Takes a folder's pair and reads it; a pair that cannot be read (a file
/// half written, views of different sizes) is reported and skipped until
/// its files change.
fn read_pair(watcher: &mut Watcher, pair: &Pair) -> anyhow::Result<Option<(RgbImage, RgbImage)>> {
    watcher
        .take(pair)
        .with_context(|| format!("cannot read {}", pair.left.display()))?;
    let views = io::read_rgb(&pair.left).and_then(|l| Ok((l, io::read_rgb(&pair.right)?)));
    match views {
        Ok(views) if views.0.dims() == views.1.dims() => Ok(Some(views)),
        Ok(_) => {
            eprintln!("skipping {}: the views differ in size", pair.left.display());
            Ok(None)
        }
        Err(e) => {
            eprintln!(
                "skipping {}: {:#}",
                pair.left.display(),
                anyhow::Error::from(e)
            );
            Ok(None)
        }
    }
}

impl Sender {
    /// Prepares one pair (rectified first with `--calib stereo.yml`) and
    /// sends its frame and depth report.
    fn send(&mut self, next: &Next, frame_id: u32) -> anyhow::Result<()> {
        let start = Instant::now();
        let (left, right) = match &self.rectifier {
            Some(r) => {
                let (a, b) = &mut self.rectified;
                r.rectify_into(&next.left, &next.right, a, b)
                    .with_context(|| format!("cannot rectify pair {frame_id}"))?;
                (&self.rectified.0, &self.rectified.1)
            }
            None => (&next.left, &next.right),
        };
        let rectify_ms = start.elapsed().as_secs_f64() * 1e3;
        let p = prepare(left, right, &self.calib, &self.cfg, frame_id)?;
        if let Some(dir) = &self.save {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            io::write_rgb(dir.join("sent-left.png"), &p.sent.0)?;
            io::write_rgb(dir.join("sent-right.png"), &p.sent.1)?;
        }
        let a = self
            .ep
            .send_message(&p.frame_bytes)
            .with_context(|| format!("sending frame {frame_id}"))?;
        let b = self
            .ep
            .send_message(&p.report_bytes)
            .with_context(|| format!("sending depth report {frame_id}"))?;
        let seconds = (a.elapsed + b.elapsed).as_secs_f64();
        let (segment_ms, encode_ms, match_ms) = p.times_ms;
        let s = Sent {
            frame_id,
            frame_bytes: p.frame_bytes.len(),
            report_bytes: p.report_bytes.len(),
            distance_m: p.report.target_distance_m,
            seconds,
            goodput_bps: (a.bytes + b.bytes) as f64 * 8.0 / seconds.max(1e-9),
            retransmissions: a.retransmissions + b.retransmissions,
            skipped: next.skipped,
            wait_ms: next.wait_ms,
            rectify_ms,
            segment_ms,
            match_ms,
            encode_ms,
            send_ms: seconds * 1e3,
        };
        if !self.json {
            println!(
                "frame {}: {} B + {} B report sent in {:.2} s ({:.1} kb/s, {} retransmissions), distance {:.3} m",
                s.frame_id,
                s.frame_bytes,
                s.report_bytes,
                s.seconds,
                s.goodput_bps / 1e3,
                s.retransmissions,
                s.distance_m
            );
            println!(
                "  timing: capture wait {:.1} ms, rectify {:.1} ms, segment {:.1} ms, match {:.1} ms, encode {:.1} ms, send {:.1} ms; {} pairs skipped",
                s.wait_ms, s.rectify_ms, s.segment_ms, s.match_ms, s.encode_ms, s.send_ms, s.skipped
            );
        }
        self.sent.push(s);
        Ok(())
    }
}
