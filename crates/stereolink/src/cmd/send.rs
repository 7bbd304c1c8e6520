//! `stereolink send`: the sender on a real link, for one pair (sent
//! `--repeat` times) or for every pair a camera writes into a folder
//! (`--watch`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use serde::Serialize;
use stereolink_calib::StereoRectifier;
use stereolink_image::{io, Calibration, RgbImage};
use stereolink_link::endpoint::Endpoint;
use stereolink_link::spec;
use stereolink_stereo::depth::{LevelSpec, Roi};

use super::calib::CalibArgs;
use super::matching::MatcherArgs;
use super::segment::SegmentArgs;
use crate::pipeline::sender::{prepare, SenderConfig};
use crate::pipeline::watch::Watcher;

/// Arguments of `stereolink send`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B.
    #[arg(long)]
    pub link: String,
    /// Left image.
    #[arg(long, required_unless_present = "watch", conflicts_with = "watch")]
    pub left: Option<PathBuf>,
    /// Right image.
    #[arg(long, required_unless_present = "watch", conflicts_with = "watch")]
    pub right: Option<PathBuf>,
    /// A camera folder: send each new pair written into it (`left*.png` with
    /// the `right*.png` of the same name, in name order; a rewritten pair is
    /// sent again) until --frames pairs are sent or the program is stopped.
    #[arg(long, value_name = "DIR")]
    pub watch: Option<PathBuf>,
    /// With --watch: how often the folder is read, in milliseconds.
    #[arg(long, default_value_t = 200, requires = "watch")]
    pub poll_ms: u64,
    /// With --watch: stop after this many pairs.
    #[arg(long, requires = "watch")]
    pub frames: Option<u32>,
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
    /// Send the pair this many times (frame ids 1, 2, ...).
    #[arg(long, default_value_t = 1, conflicts_with = "watch")]
    pub repeat: u32,
    #[command(flatten)]
    pub segment: SegmentArgs,
    #[command(flatten)]
    pub matcher: MatcherArgs,
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
    let mut sender = Sender {
        ep: Endpoint::new(
            spec::open(&spec).with_context(|| format!("cannot open link {}", args.link))?,
        ),
        calib: sensor.depth,
        rectifier: sensor.rectifier,
        rectified: Default::default(),
        cfg,
        save: args.save.clone(),
        json: out.json,
        sent: Vec::new(),
    };
    match (&args.watch, &args.left, &args.right) {
        (Some(dir), _, _) => sender.watch(dir, Duration::from_millis(args.poll_ms), args.frames)?,
        (None, Some(left), Some(right)) => {
            let (left, right) = (io::read_rgb(left)?, io::read_rgb(right)?);
            for frame_id in 1..=args.repeat {
                sender.send(&left, &right, frame_id)?;
            }
        }
        _ => anyhow::bail!("give --left and --right, or --watch DIR"),
    }
    if out.json {
        out.emit(&sender.sent, String::new)?;
    }
    Ok(())
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

impl Sender {
    /// Prepares one pair (rectified first with `--calib stereo.yml`) and
    /// sends its frame and depth report.
    fn send(&mut self, left: &RgbImage, right: &RgbImage, frame_id: u32) -> anyhow::Result<()> {
        let (left, right) = match &self.rectifier {
            Some(r) => {
                let (a, b) = &mut self.rectified;
                r.rectify_into(left, right, a, b)
                    .with_context(|| format!("cannot rectify pair {frame_id}"))?;
                (&self.rectified.0, &self.rectified.1)
            }
            None => (left, right),
        };
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
        let s = Sent {
            frame_id,
            frame_bytes: p.frame_bytes.len(),
            report_bytes: p.report_bytes.len(),
            distance_m: p.report.target_distance_m,
            seconds,
            goodput_bps: (a.bytes + b.bytes) as f64 * 8.0 / seconds.max(1e-9),
            retransmissions: a.retransmissions + b.retransmissions,
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
        }
        self.sent.push(s);
        Ok(())
    }

    /// Sends each new pair of `dir`, reading it every `poll`, until `frames`
    /// pairs are sent (or forever). A pair that cannot be read (a file half
    /// written, views of different sizes) is reported and skipped until its
    /// files change.
    fn watch(&mut self, dir: &Path, poll: Duration, frames: Option<u32>) -> anyhow::Result<()> {
        let mut watcher = Watcher::new();
        let mut frame_id = 0;
        loop {
            let pending = watcher
                .pending(dir)
                .with_context(|| format!("cannot read the camera folder {}", dir.display()))?;
            for pair in pending {
                if frames.is_some_and(|n| frame_id >= n) {
                    return Ok(());
                }
                watcher
                    .take(&pair)
                    .with_context(|| format!("cannot read {}", pair.left.display()))?;
                let views =
                    io::read_rgb(&pair.left).and_then(|l| Ok((l, io::read_rgb(&pair.right)?)));
                let (left, right) = match views {
                    Ok(views) if views.0.dims() == views.1.dims() => views,
                    Ok(_) => {
                        eprintln!("skipping {}: the views differ in size", pair.left.display());
                        continue;
                    }
                    Err(e) => {
                        eprintln!(
                            "skipping {}: {:#}",
                            pair.left.display(),
                            anyhow::Error::from(e)
                        );
                        continue;
                    }
                };
                frame_id += 1;
                self.send(&left, &right, frame_id)?;
            }
            if frames.is_some_and(|n| frame_id >= n) {
                return Ok(());
            }
            std::thread::sleep(poll);
        }
    }
}
