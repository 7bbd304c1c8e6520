//! `stereolink send`: the sender on a real link.

use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;
use stereolink_image::{io, Calibration};
use stereolink_link::endpoint::Endpoint;
use stereolink_link::spec;
use stereolink_stereo::depth::{LevelSpec, Roi};

use super::matching::MatcherArgs;
use super::segment::SegmentArgs;
use crate::pipeline::sender::{prepare, SenderConfig};

/// Arguments of `stereolink send`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B.
    #[arg(long)]
    pub link: String,
    /// Left image.
    #[arg(long)]
    pub left: PathBuf,
    /// Right image.
    #[arg(long)]
    pub right: PathBuf,
    /// Largest disparity searched for the depth report.
    #[arg(long, default_value_t = 64)]
    pub max_disp: usize,
    /// Focal length in pixels (for distances).
    #[arg(long)]
    pub focal_px: Option<f64>,
    /// Baseline in metres (for distances).
    #[arg(long)]
    pub baseline_m: Option<f64>,
    /// Target region x,y,w,h (default: the central ninth of the image).
    #[arg(long)]
    pub roi: Option<Roi>,
    /// Also write the segmented views as sent (sent-left.png, sent-right.png) here.
    #[arg(long)]
    pub save: Option<PathBuf>,
    /// Send the pair this many times (frame ids 1, 2, ...).
    #[arg(long, default_value_t = 1)]
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

/// Prepares and sends the pair.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    let spec = super::link_spec(&args.link)?;
    let left = io::read_rgb(&args.left)?;
    let right = io::read_rgb(&args.right)?;
    let calib = Calibration {
        focal_px: args.focal_px,
        baseline_m: args.baseline_m,
        doffs: 0.0,
        ndisp: args.max_disp + 1,
    };
    let cfg = SenderConfig {
        method: args.segment.method()?,
        levels: args.segment.levels,
        seed: args.segment.seed,
        matcher: args.matcher.depth_spec(0, args.max_disp)?,
        roi: args.roi,
        levels_spec: LevelSpec::default(),
    };
    let mut ep = Endpoint::new(
        spec::open(&spec).with_context(|| format!("cannot open link {}", args.link))?,
    );
    let mut sent = Vec::new();
    for frame_id in 1..=args.repeat {
        let p = prepare(&left, &right, &calib, &cfg, frame_id)?;
        if let Some(dir) = &args.save {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            io::write_rgb(dir.join("sent-left.png"), &p.sent.0)?;
            io::write_rgb(dir.join("sent-right.png"), &p.sent.1)?;
        }
        let a = ep
            .send_message(&p.frame_bytes)
            .with_context(|| format!("sending frame {frame_id}"))?;
        let b = ep
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
        if !out.json {
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
        sent.push(s);
    }
    if out.json {
        out.emit(&sent, String::new)?;
    }
    Ok(())
}
