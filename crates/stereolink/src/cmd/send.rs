//! `stereolink send`: the sender on a real link, for one pair (sent
//! `--repeat` times), for every pair a camera writes into a folder
//! (`--watch`), or live from two cameras (`--camera-left`/`--source-left`).
//! All three feed one loop ([`Pairs`]): take a pair, prepare it, send it.
//! Between pairs the loop obeys the commands that came over the link
//! ([`Sender::obey`]): new levels or method from the next pair, the last
//! pair again at once on a frame request; each is answered on the link.

use std::collections::{BTreeMap, VecDeque};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_calib::StereoRectifier;
use stereolink_codec::planetable::TableCoding;
use stereolink_image::{io, Calibration, RgbImage};
use stereolink_link::arq::Config;
use stereolink_link::endpoint::{Endpoint, Progress, ProgressReport, SendStats};
use stereolink_link::secure::SecureConfig;
use stereolink_link::spec;
use stereolink_link::transport::Transport;
use stereolink_stereo::depth::{LevelSpec, Roi};

use stereolink_capture::StereoCapture;
use stereolink_codec::control::{Control, Reply};
use stereolink_pipeline::sender::{prepare, Applied, SenderConfig};
use stereolink_pipeline::uplink::{Kind, Outcome, Uplink};
use stereolink_pipeline::watch::{Pair, Watcher};

use super::calib::CalibArgs;
use super::camera::CameraArgs;
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

Live, pairs are sent at the rate the link carries: while one is prepared and
sent the cameras run on, the newest pair wins and the pairs skipped are
counted. Each frame prints a timing line (capture wait, segment, match,
encode, send). A camera that stops (no frame for --frame-timeout-s, or the end
of its stream) stops the sender with an error naming it; the board's watchdog
then stops the axis.

Commands from the peer (a gateway's Control messages; with keys, only the
paired peer's) are obeyed between pairs and answered on the link: levels and
method hold from the next pair, a frame request sends the last pair again at
once with the current settings (live cameras: the next pair, which goes at
once anyway), and an axis stop is refused (a sender drives no axis). Each is
logged on stderr.")]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B.
    #[arg(long)]
    pub link: String,
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
    /// Also write the segmented views as sent (sent-left.png, sent-right.png)
    /// and the sender's disparity map (sent-disparity.pfm) here.
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
    pub keys: KeyArgs,
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

#[derive(Serialize)]
struct Sent {
    frame_id: u32,
    frame_bytes: usize,
    report_bytes: usize,
    distance_m: f32,
    /// From handing the frame to the link until its last fragment was acknowledged.
    seconds: f64,
    /// From handing the depth report to the link until it was acknowledged.
    report_seconds: f64,
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
    /// What the link measured so far (damaged frames, the radio's statuses).
    link: String,
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
        plane_table: args.plane_table(),
    };
    let transport = spec::open(&spec).with_context(|| format!("cannot open link {}", args.link))?;
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
    let (link, report_link) = (args.link.clone(), args.report_link.clone());
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
    let mut sender = Sender {
        uplink,
        calib: sensor.depth,
        rectifier: sensor.rectifier()?,
        rectified: Default::default(),
        cfg,
        save: args.save.clone(),
        json: out.json,
        waiting: BTreeMap::new(),
        sent: Vec::new(),
        last: None,
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
        let next = match (sender.obey()?, sender.last.take()) {
            // The last pair again, now, with the current settings.
            (Applied::FrameNow, Some(last)) if !pairs.live() => Next {
                wait_ms: 0.0,
                skipped: 0,
                ..last
            },
            (_, last) => {
                sender.last = last;
                match pairs.next()? {
                    Got::Pair(next) => next,
                    Got::Wait => continue,
                    Got::End => break,
                }
            }
        };
        frame_id += 1;
        sender.send(&next, frame_id)?;
        sender.last = Some(next);
    }
    let rest = sender.uplink.finish()?;
    sender.collect(rest)?;
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

/// The link thread and what every frame is prepared with.
struct Sender {
    uplink: Uplink,
    calib: Calibration,
    /// The maps of a raw pair (`--calib stereo.yml`).
    rectifier: Option<StereoRectifier>,
    /// The rectified views, reused from pair to pair.
    rectified: (RgbImage, RgbImage),
    cfg: SenderConfig,
    save: Option<PathBuf>,
    json: bool,
    /// Frames handed to the link whose frame or report has not ended yet.
    waiting: BTreeMap<u32, Waiting>,
    sent: Vec<Sent>,
    /// The last pair sent, for a frame request.
    last: Option<Next>,
}

/// A frame on its way: what was measured preparing it, and how its two
/// messages ended so far.
struct Waiting {
    sent: Sent,
    frame: Option<SendStats>,
    report: Option<SendStats>,
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

/// What [`Pairs::next`] found.
enum Got {
    Pair(Next),
    /// Nothing yet (a folder with no new pair): ask again.
    Wait,
    /// No more pairs.
    End,
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
    /// Whether the pairs come live from cameras (the next one is always
    /// fresh, and comes at once).
    fn live(&self) -> bool {
        matches!(self, Pairs::Cameras { .. })
    }

    /// The next pair, [`Got::Wait`] after one poll interval of an empty
    /// folder (a folder is waited on forever), or [`Got::End`]. A camera
    /// that stops is an error.
    fn next(&mut self) -> anyhow::Result<Got> {
        let start = Instant::now();
        let wait_ms = || start.elapsed().as_secs_f64() * 1e3;
        match self {
            Pairs::Files {
                left,
                right,
                remaining,
            } => {
                if *remaining == 0 {
                    return Ok(Got::End);
                }
                *remaining -= 1;
                Ok(Got::Pair(Next {
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
                        return Ok(Got::Wait);
                    }
                    continue;
                };
                if let Some((left, right)) = read_pair(watcher, &pair)? {
                    return Ok(Got::Pair(Next {
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
                Ok(Got::Pair(Next {
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
            stereolink_image::pfm::write(dir.join("sent-disparity.pfm"), &p.disparity)?;
        }
        let (frame_bytes, report_bytes) = (p.frame_bytes.len(), p.report_bytes.len());
        // The report first: it goes ahead of the frame still in flight.
        self.uplink.report(frame_id, p.report_bytes)?;
        self.uplink.frame(frame_id, p.frame_bytes)?;
        let (segment_ms, encode_ms, match_ms) = p.times_ms;
        let sent = Sent {
            frame_id,
            frame_bytes,
            report_bytes,
            distance_m: p.report.target_distance_m,
            seconds: 0.0,
            report_seconds: 0.0,
            goodput_bps: 0.0,
            retransmissions: 0,
            skipped: next.skipped,
            wait_ms: next.wait_ms,
            rectify_ms,
            segment_ms,
            match_ms,
            encode_ms,
            send_ms: 0.0,
            link: String::new(),
        };
        let waiting = Waiting {
            sent,
            frame: None,
            report: None,
        };
        self.waiting.insert(frame_id, waiting);
        let outcomes = self.uplink.outcomes();
        self.collect(outcomes)
    }

    /// Obeys the commands that came over the link since the last call and
    /// answers each on the link; says whether a frame is wanted now (and
    /// there is a pair to send again).
    fn obey(&mut self) -> anyhow::Result<Applied> {
        let mut wanted = Applied::FromNextPair;
        for incoming in self.uplink.incoming() {
            let (id, command) = match incoming {
                Ok(Control::Command { id, command }) => (id, command),
                Ok(Control::Reply(r)) => {
                    eprintln!("ignored a reply from the peer (to command {})", r.id);
                    continue;
                }
                Err(e) => {
                    eprintln!("refused a message from the peer: {e}");
                    continue;
                }
            };
            let result = match self.cfg.apply(&command) {
                Ok(Applied::FrameNow) if self.last.is_none() => {
                    Err("no pair has been sent yet: the first goes when it comes".into())
                }
                Ok(applied) => {
                    if applied == Applied::FrameNow {
                        wanted = applied;
                    }
                    Ok(())
                }
                Err(e) => Err(e),
            };
            match &result {
                Ok(()) => eprintln!("command {id} ({}): done", command.name()),
                Err(why) => eprintln!("command {id} ({}): refused: {why}", command.name()),
            }
            self.uplink.reply(&Reply { id, result })?;
        }
        Ok(wanted)
    }

    /// Takes the ends of sends: a failure stops the sender, naming the
    /// message; a frame whose two messages both arrived is printed.
    fn collect(&mut self, outcomes: Vec<Outcome>) -> anyhow::Result<()> {
        for o in outcomes {
            let what = match o.kind {
                Kind::Frame => format!("sending frame {}", o.frame_id),
                Kind::Report => format!("sending the depth report of frame {}", o.frame_id),
                Kind::Reply => {
                    if let Err(e) = o.result {
                        eprintln!("the reply to command {} was not delivered: {e}", o.frame_id);
                    }
                    continue;
                }
            };
            let stats = o.result.context(what)?;
            let Some(w) = self.waiting.get_mut(&o.frame_id) else {
                continue;
            };
            match o.kind {
                Kind::Frame => w.frame = Some(stats),
                Kind::Report => w.report = Some(stats),
                Kind::Reply => {} // no frame waits for a reply (taken above)
            }
            w.sent.link = o.link.to_string();
            if let (Some(f), Some(r)) = (w.frame, w.report) {
                if let Some(w) = self.waiting.remove(&o.frame_id) {
                    self.print(w.sent, f, r);
                }
            }
        }
        Ok(())
    }

    fn print(&mut self, mut s: Sent, frame: SendStats, report: SendStats) {
        s.seconds = frame.elapsed.as_secs_f64();
        s.report_seconds = report.elapsed.as_secs_f64();
        s.goodput_bps = frame.goodput_bps();
        s.retransmissions = frame.retransmissions + report.retransmissions;
        s.send_ms = s.seconds * 1e3;
        if !self.json {
            println!(
                "frame {}: {} B sent in {:.2} s ({:.1} kb/s, {} retransmissions); its {} B depth report delivered in {:.2} s, distance {:.3} m",
                s.frame_id,
                s.frame_bytes,
                s.seconds,
                s.goodput_bps / 1e3,
                s.retransmissions,
                s.report_bytes,
                s.report_seconds,
                s.distance_m
            );
            println!(
                "  timing: capture wait {:.1} ms, rectify {:.1} ms, segment {:.1} ms, match {:.1} ms, encode {:.1} ms, send {:.1} ms; {} pairs skipped",
                s.wait_ms, s.rectify_ms, s.segment_ms, s.match_ms, s.encode_ms, s.send_ms, s.skipped
            );
            println!("  link: {}", s.link);
        }
        self.sent.push(s);
    }
}
