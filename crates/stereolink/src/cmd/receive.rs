//! `stereolink receive`: the board's receiver on a real link.

use std::time::{Duration, Instant};

use anyhow::Context;
use stereolink_display::open_sink;
use stereolink_link::endpoint::{Endpoint, LinkError};
use stereolink_link::secure::{Rejections, SecureConfig};
use stereolink_link::spec;
use stereolink_pipeline::receiver::{BoardReceiver, DisparitySource, Event};
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
    /// Link: serial:/dev/ttyUSB0?baud=115200&api=2, udp:BIND?peer=ADDR, fallback:A,B.
    #[arg(long)]
    pub link: String,
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
    /// Stop the axis when no valid depth report arrived for this long.
    #[arg(long, default_value_t = 10)]
    pub watchdog_s: u64,
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
    pub keys: KeyArgs,
}

/// Receives, shows and moves until done.
pub fn run(args: Args, out: &super::Output) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.matcher == "wta",
        "the board matches with wta only (got {})",
        args.matcher
    );
    let keys = args.keys.load(args.robot.is_some())?;
    let mut eps = Vec::new();
    for link in std::iter::once(&args.link).chain(&args.report_link) {
        let spec = super::link_spec(link)?;
        let mut ep =
            Endpoint::new(spec::open(&spec).with_context(|| format!("cannot open link {link}"))?)?;
        if let Some(keys) = keys.clone() {
            ep = ep.with_keys(keys, SecureConfig::default());
        }
        let name = link.clone();
        ep.on_notice(Box::new(move |notice| eprintln!("link {name}: {notice}")));
        eps.push(ep);
    }
    let mut board = BoardReceiver::new(args.max_disp, 9, Duration::from_secs(args.watchdog_s));
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
    let mut frames = 0;
    let mut halves = std::collections::BTreeSet::new();
    let mut events = Vec::new();
    let (timeout, mut heard) = (Duration::from_secs(args.timeout_s), Instant::now());
    while args.frames == 0 || frames < args.frames {
        // The watchdog is checked whether or not anything arrives: a link
        // that falls silent must stop the axis too. Short waits, so that it
        // and the screen follow the axis while the link is silent.
        check_watchdog(&mut board, args.watchdog_s);
        let msg = match next_message(&mut eps, POLL.min(timeout)) {
            Ok(m) => m,
            Err(LinkError::Timeout) if heard.elapsed() < timeout => {
                board.follow_axis().context("display")?;
                continue;
            }
            Err(LinkError::Timeout) if args.frames == 0 => break,
            Err(e) => return Err(e).context("receiving"),
        };
        heard = Instant::now();
        let event = board.handle(&msg);
        // Shown and acted on: the sender may count it delivered now, before
        // this process says so (a process killed after saying it showed a
        // frame has acknowledged it, and its next life is not sent it again).
        for ep in eps.iter_mut() {
            ep.dealt_with().context("link")?;
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
            }
        }
        if let Event::Frame { frame_id, .. } | Event::Report { frame_id, .. } = &event {
            // A frame counts once both its views and its report arrived
            // (the report usually first: it overtakes the frame).
            if !halves.remove(frame_id) {
                halves.insert(*frame_id);
                if halves.len() > 16 {
                    halves.pop_first();
                }
            } else {
                frames += 1;
            }
        }
        board.status.security = security_line(&eps);
        // What the links measure: the radio's signal where its frames
        // carry it, and the retransmitted segments received, as a count and
        // as their share of all the segments received.
        board.status.rssi_dbm = eps.iter().find_map(|e| e.link_stats().rssi_dbm);
        let duplicates: u64 = eps.iter().map(Endpoint::duplicates).sum();
        let segments: u64 = eps.iter().map(Endpoint::segments_received).sum();
        board.status.retransmitted = Some(duplicates);
        board.status.retransmit_rate = (segments > 0).then(|| duplicates as f64 / segments as f64);
        if matches!(event, Event::Report { .. } | Event::Command { .. }) {
            if let Some(axis) = board.axis.as_mut() {
                board.status.axis_mm = axis.position().ok();
            }
            board.refresh().context("display")?;
        }
        events.push(event);
    }
    // Answer late retransmissions, and let the axis finish its move.
    let share = Duration::from_millis(500) / eps.len() as u32;
    for ep in eps.iter_mut() {
        ep.linger(share)?;
    }
    if let Some(axis) = board.axis.as_mut() {
        let pos = stereolink_robot::wait_until_idle(axis.as_mut(), 6000)?
            .context("the axis is still moving")?;
        if !out.json {
            println!("axis at {pos:.3} mm");
        }
    }
    // The screen shows where the axis settled.
    board.follow_axis().context("display")?;
    if !out.json {
        for (ep, label) in eps.iter().zip(["link", "report link"]) {
            println!("{label}: {}", ep.link_stats());
            if let Some(r) = ep.rejections() {
                println!("{label}: {r}");
            }
        }
    }
    if out.json {
        out.emit(&events, String::new)?;
    }
    Ok(())
}

/// Stops the axis if no valid depth report came for `secs`, and says so.
fn check_watchdog(board: &mut BoardReceiver, secs: u64) {
    match board.check_watchdog(Instant::now()) {
        Ok(true) => eprintln!("watchdog: no valid depth report for {secs} s, axis stopped"),
        Ok(false) => {}
        Err(e) => eprintln!(
            "watchdog: no valid depth report for {secs} s, but the axis did not take the stop \
             ({e}); trying again"
        ),
    }
}

/// The next message from any of the links, waiting up to `timeout`.
fn next_message(eps: &mut [Endpoint], timeout: Duration) -> Result<Vec<u8>, LinkError> {
    let until = Instant::now() + timeout;
    let slice = Duration::from_millis(20) / eps.len().max(1) as u32;
    loop {
        for ep in eps.iter_mut() {
            match ep.recv_message(slice) {
                Err(LinkError::Timeout) => {}
                other => return other,
            }
        }
        if Instant::now() >= until {
            return Err(LinkError::Timeout);
        }
    }
}

/// The screen's security note: sealed or not, and the refusals by cause
/// over all the links.
fn security_line(eps: &[Endpoint]) -> String {
    let all: Option<Vec<Rejections>> = eps.iter().map(Endpoint::rejections).collect();
    match all {
        Some(r) => {
            let sum = |f: fn(&Rejections) -> u64| r.iter().map(f).sum::<u64>();
            format!(
                "SEALED  REJ TAG {} RPL {} SES {} HS {}",
                sum(|r| r.bad_tag),
                sum(|r| r.replay),
                sum(|r| r.unknown_session),
                sum(|r| r.handshake)
            )
        }
        None => "INSECURE".into(),
    }
}
