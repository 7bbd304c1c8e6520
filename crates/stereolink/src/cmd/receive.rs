//! `stereolink receive`: the board's receiver on a real link.

use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_codec::container;
use stereolink_codec::control::unix_us;
use stereolink_display::open_sink;
use stereolink_link::endpoint::{Endpoint, Lane, LinkError};
use stereolink_link::secure::SecureConfig;
use stereolink_pipeline::board_links::{next_message, security_line};
use stereolink_pipeline::rates::{since_stamp, Figures, FrameCount, Rates};
use stereolink_pipeline::receiver::{AxisEnd, BoardReceiver, DisparitySource, Event};
use stereolink_robot::open_axis;
use stereolink_robot::policy::MotionPolicy;

use super::keygen::KeyArgs;

/// The longest wait for a message before the screen looks at the axis.
const POLL: Duration = Duration::from_millis(200);

/// Arguments of `stereolink receive`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = "\
An axis stop from the link (a Control command; with keys, only from the
paired peer) stops the axis at once and holds it: later depth reports no
longer move it until the receiver restarts. Other commands are refused
(segmentation is the sender's).")]
pub struct Args {
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B;
    /// several make a bond.
    #[arg(long, required = true, long_help = super::LINK_HELP)]
    pub link: Vec<String>,
    /// A second link on which the depth reports arrive (`send
    /// --report-link`); messages are taken from both.
    #[arg(long, value_name = "SPEC")]
    pub report_link: Option<String>,
    /// Display: fb:/dev/fb0, png:DIR or web:127.0.0.1:8080 (a viewer on any other
    /// address answers only requests with the token printed at start).
    #[arg(long)]
    pub display: Option<String>,
    /// Axis: grbl:/dev/ttyACM0 or sim.
    #[arg(long)]
    pub robot: Option<String>,
    /// Matcher on the board (only wta, as the paper's ARM board).
    #[arg(long = "match", default_value = "wta")]
    pub matcher: String,
    /// Where the board's disparity comes from: wta matches the rebuilt
    /// pair; planes rebuilds it from the left labels and the frame's plane
    /// table, without matching (the sender must run `--algo planes`).
    #[arg(long, value_enum, default_value_t = DisparitySource::Wta)]
    pub disparity: DisparitySource,
    /// Largest disparity the board searches.
    #[arg(long, default_value_t = 32)]
    pub max_disp: usize,
    /// Also write each received pair (received-left.png, received-right.png)
    /// and the board's disparity map (received-disparity.pfm) here.
    #[arg(long)]
    pub save: Option<std::path::PathBuf>,
    /// Stop after this many frames, each with its depth report (0: run until
    /// the link is silent for --timeout-s).
    #[arg(long, default_value_t = 0)]
    pub frames: u32,
    /// Give up after this many seconds without a message.
    #[arg(long, default_value_t = 120)]
    pub timeout_s: u64,
    /// Stop the axis when no valid depth report arrived for this long,
    /// seconds: a few report periods of a sender that reports every pair
    /// (about 0.5 s at 10 pairs/s). Raise it for a sender that reports
    /// only with each frame.
    #[arg(long, default_value_t = 0.5)]
    pub watchdog_s: f64,
    /// Stand-off: stop this far short of the target, mm.
    #[arg(long, default_value_t = 0.0)]
    pub standoff_mm: f64,
    /// Axis soft limit, mm from home.
    #[arg(long, default_value_t = 1000.0)]
    pub max_travel_mm: f64,
    /// Axis speed limit, mm/s.
    #[arg(long, default_value_t = 50.0)]
    pub max_speed: f64,
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

/// Receives, shows and moves until done.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.matcher == "wta",
        "the board matches with wta only (got {})",
        args.matcher
    );
    anyhow::ensure!(
        args.watchdog_s.is_finite() && args.watchdog_s > 0.0,
        "--watchdog-s must be a positive number of seconds (got {})",
        args.watchdog_s
    );
    let keys = args.keys.load(args.robot.is_some())?;
    let mut recorder = args.record.open()?;
    let mut eps = Vec::new();
    let links = std::iter::once(args.link.clone()).chain(args.report_link.clone().map(|r| vec![r]));
    for link in links {
        let mut ep = Endpoint::new(super::open_links(&link)?)?;
        if let Some(keys) = keys.clone() {
            ep = ep.with_keys(keys, SecureConfig::default());
        }
        let name = super::links_name(&link);
        ep.on_notice(Box::new(move |notice| eprintln!("link {name}: {notice}")));
        eps.push(ep);
    }
    let mut board = BoardReceiver::new(args.max_disp, 9, Duration::from_secs_f64(args.watchdog_s));
    board.source = args.disparity;
    board.policy = MotionPolicy {
        standoff_mm: args.standoff_mm,
        min_mm: 0.0,
        max_mm: args.max_travel_mm,
        max_speed_mm_s: args.max_speed,
    };
    if let Some(d) = &args.display {
        let sink = open_sink(d).with_context(|| format!("cannot open display {d}"))?;
        eprintln!("display: {}", sink.describe());
        board.sink = Some(sink);
    }
    if let Some(r) = &args.robot {
        board.axis = Some(open_axis(r).with_context(|| format!("cannot open axis {r}"))?);
    }
    let mut service = super::service::Service::new();
    service.ready(&format!("receiving on {}", super::links_name(&args.link)));
    let mut frames = FrameCount::default();
    let mut events = Vec::new();
    let started = Instant::now();
    let (mut total, mut second) = (Rates::new(started), Rates::new(started));
    let mut next_second = started + Duration::from_secs(1);
    let (timeout, mut heard) = (Duration::from_secs(args.timeout_s), Instant::now());
    // The loop in a closure, so that whatever ends it, the axis is dealt
    // with and the summary printed below.
    let mut receive = || -> anyhow::Result<End> {
        while args.frames == 0 || frames.counted < args.frames {
            if Instant::now() >= next_second {
                let now = Instant::now();
                let figures = second.take(now);
                eprintln!("received: {figures}");
                if let Some(r) = &mut recorder {
                    r.link(unix_us(), "stereolink receive: link", &figures)?;
                }
                next_second = now + Duration::from_secs(1);
            }
            // The watchdog is checked whether or not anything arrives: a link
            // that falls silent must stop the axis too. Short waits, so that it
            // and the screen follow the axis while the link is silent.
            check_watchdog(&mut board, args.watchdog_s);
            service.alive();
            ask_for_key(&mut board, &mut eps[0]);
            let msg = match next_message(&mut eps, POLL.min(timeout)) {
                Ok(m) => m,
                Err(LinkError::Timeout) if heard.elapsed() < timeout => {
                    board.follow_axis().context("display")?;
                    continue;
                }
                Err(LinkError::Timeout) if args.frames == 0 => return Ok(End::Quiet),
                Err(e) => return Err(e).context("receiving"),
            };
            heard = Instant::now();
            let stamp_us = container::decode_header(&msg).map_or(0, |h| h.timestamp_us);
            let event = board.handle(&msg);
            for rates in [&mut total, &mut second] {
                match &event {
                    Event::Frame { .. } => rates.frame(msg.len()),
                    Event::Report { .. } => {
                        rates.report(msg.len(), since_stamp(stamp_us, unix_us()));
                    }
                    _ => {}
                }
            }
            // Shown and acted on: the sender may count it delivered now, before
            // this process says so (a process killed after saying it showed a
            // frame has acknowledged it, and its next life is not sent it again).
            for ep in eps.iter_mut() {
                ep.dealt_with().context("link")?;
            }
            if let Some(r) = &mut recorder {
                super::record::received(r, &mut board, (&msg, stamp_us), &event)?;
            }
            if let (Some(dir), Event::Frame { .. }) = (&args.save, &event) {
                let disparity = board.disparity();
                if let Some((l, r)) = board.pair() {
                    std::fs::create_dir_all(dir)
                        .with_context(|| format!("cannot create {}", dir.display()))?;
                    stereolink_image::io::write_rgb(dir.join("received-left.png"), l)?;
                    stereolink_image::io::write_rgb(dir.join("received-right.png"), r)?;
                    stereolink_image::pfm::write(dir.join("received-disparity.pfm"), &disparity)?;
                }
            }
            if !out.json {
                match &event {
                    Event::Frame {
                        frame_id,
                        bytes,
                        ms,
                    } => println!(
                        "frame {frame_id}: {bytes} B, rebuilt, matched and shown in {ms:.1} ms"
                    ),
                    Event::Report {
                        frame_id,
                        distance_m,
                        commanded_mm,
                        held,
                    } => println!(
                        "report {frame_id}: distance {distance_m:.3} m, axis {}",
                        match (commanded_mm, held) {
                            (_, true) => "held (stopped by command)".into(),
                            (None, false) => "not moved (no valid distance)".into(),
                            (Some(p), false) => format!("to {p:.1} mm"),
                        }
                    ),
                    Event::Command {
                        id,
                        command,
                        result: Ok(()),
                    } => println!(
                        "command {id} ({command}): done{}",
                        board
                            .axis
                            .as_mut()
                            .and_then(|a| a.position().ok())
                            .map_or(String::new(), |p| format!(", axis at {p:.1} mm, held"))
                    ),
                    Event::Command {
                        id,
                        command,
                        result: Err(why),
                    } => eprintln!("command {id} ({command}): refused: {why}"),
                    Event::Rejected(why) => eprintln!("{why}"),
                    Event::Answered { id, result } => eprintln!(
                        "key frame request {id}: {}",
                        match result {
                            Ok(()) => "taken".into(),
                            Err(why) => format!("refused: {why}"),
                        }
                    ),
                }
            }
            frames.count(&event);
            board.status.security = security_line(&eps);
            // What the links measure: the radio's signal where its frames
            // carry it, and the retransmitted segments received, as a count and
            // as their share of all the segments received.
            board.status.rssi_dbm = eps.iter().find_map(|e| e.link_stats().rssi_dbm);
            let duplicates: u64 = eps.iter().map(Endpoint::duplicates).sum();
            let segments: u64 = eps.iter().map(Endpoint::segments_received).sum();
            board.status.retransmitted = Some(duplicates);
            board.status.retransmit_rate =
                (segments > 0).then(|| duplicates as f64 / segments as f64);
            if matches!(event, Event::Report { .. } | Event::Command { .. }) {
                if let Some(axis) = board.axis.as_mut() {
                    board.status.axis_mm = axis.position().ok();
                }
                board.refresh().context("display")?;
            }
            events.push(event);
        }
        Ok(End::Frames)
    };
    let ended = receive();
    service.stopping();
    // Closed whatever ended the loop; its error is said after the axis's.
    let recorded = recorder.map(|r| r.finish()).transpose();
    // Answer late retransmissions (on a link still up).
    if ended.is_ok() {
        let share = Duration::from_millis(500) / eps.len() as u32;
        for ep in eps.iter_mut() {
            if let Err(e) = ep.linger(share) {
                eprintln!("link: {e}");
            }
        }
    }
    let axis = board.settle_axis(matches!(ended, Ok(End::Frames)));
    if let Some(AxisEnd {
        position_mm: Ok(pos),
        stopped,
    }) = &axis
    {
        if *stopped {
            eprintln!("link quiet: the axis was still moving on stale data; stopped");
        }
        if !out.json {
            println!("axis at {pos:.3} mm");
        }
    }
    // The screen shows where the axis settled.
    if let Err(e) = board.follow_axis() {
        eprintln!("display: {e}");
    }
    let summary = Summary {
        link: total.figures(Instant::now()),
        ended: match &ended {
            Ok(End::Frames) => "frames".into(),
            Ok(End::Quiet) => "quiet".into(),
            Err(e) => format!("error: {e:#}"),
        },
        axis_mm: axis
            .as_ref()
            .and_then(|a| a.position_mm.as_ref().ok().copied()),
        axis_stopped: axis.as_ref().is_some_and(|a| a.stopped),
        key_requests: board.key_requests(),
        carried_disparity_frames: board.carried_frames(),
    };
    if !out.json {
        println!("{summary}");
        for (ep, label) in eps.iter().zip(["link", "report link"]) {
            println!("{label}: {}", ep.link_stats());
            if let Some(r) = ep.rejections() {
                println!("{label}: {r}");
            }
        }
    }
    if out.json {
        out.emit(
            &serde_json::json!({ "summary": summary, "events": events }),
            String::new,
        )?;
    }
    if let Some(AxisEnd {
        position_mm: Err(e),
        ..
    }) = axis
    {
        return Err(e).context("the axis after the last report");
    }
    recorded?;
    ended.map(|_| ())
}

/// Asks the sender for a key frame when the board needs one (a predicted
/// frame's reference missing), on the frames' link's urgent lane, and
/// drives that request's send.
fn ask_for_key(board: &mut BoardReceiver, ep: &mut Endpoint) {
    if ep.is_idle(Lane::Urgent) {
        if let Some(request) = board.key_request(Instant::now()) {
            match ep.submit(Lane::Urgent, &request) {
                Ok(()) => {
                    tracing::info!("a frame could not be shown: asked the sender for a key frame")
                }
                Err(e) => eprintln!("could not ask the sender for a key frame: {e}"),
            }
        }
    }
    if !ep.is_idle(Lane::Urgent) {
        match ep.poll_sends(Duration::ZERO) {
            Ok(ended) => {
                for (_, result) in ended {
                    if let Err(e) = result {
                        eprintln!("a key frame request was not delivered: {e}");
                    }
                }
            }
            Err(e) => eprintln!("link: {e}"),
        }
    }
}

/// Stops the axis if no valid depth report came for `secs`, and says so.
fn check_watchdog(board: &mut BoardReceiver, secs: f64) {
    match board.check_watchdog(Instant::now()) {
        Ok(true) => eprintln!("watchdog: no valid depth report for {secs} s, axis stopped"),
        Ok(false) => {}
        Err(e) => eprintln!(
            "watchdog: no valid depth report for {secs} s, but the axis did not take the stop \
             ({e}); trying again"
        ),
    }
}

/// Why the receive loop ended without an error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum End {
    /// `--frames` frames arrived, each with its report.
    Frames,
    /// Nothing arrived for `--timeout-s`.
    Quiet,
}

/// The receiver's summary, printed on every way out.
#[derive(Serialize)]
struct Summary {
    /// Depth reports applied (their latency: from the sender's time stamp,
    /// its capture, to the report's move) and frames shown.
    #[serde(flatten)]
    link: Figures,
    /// `frames`, `quiet` (nothing for --timeout-s) or `error: …`.
    ended: String,
    axis_mm: Option<f64>,
    /// The link went quiet or failed mid-move, so the axis was stopped.
    axis_stopped: bool,
    /// Key frames asked of the sender (predicted frames that could not be
    /// shown).
    key_requests: u32,
    /// Frames whose disparity is the sender's, carried by a
    /// stereo-predicted frame (the others were matched on the board).
    carried_disparity_frames: u32,
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "summary: {}, ended: {}", self.link, self.ended)
    }
}
