//! The whole system in one process: sender and receiver as two threads over
//! the simulated XBee 802.15.4 link, the receiver rendering the screen and
//! driving the simulated axis. Results go to a folder.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use serde::Serialize;
use stereolink_display::{anaglyph, Anaglyph, Sink};
use stereolink_image::{colormap, io, metrics::reduction_percent, Scene};
use stereolink_link::arq::Config;
use stereolink_link::endpoint::Endpoint;
use stereolink_link::secure::{Keys, SecureConfig};
use stereolink_link::sim::{pair, SimConfig};
use stereolink_robot::sim::{MotorParams, SimAxis};
use stereolink_stereo::depth::{region_distance, Roi};

use crate::receiver::{BoardReceiver, Event};
use crate::sender::{default_roi, prepare, SenderConfig};
use stereolink_codec::control::unix_us;

/// Demo settings.
pub struct DemoConfig {
    /// Where results go.
    pub out: PathBuf,
    /// The scene.
    pub scene: Scene,
    /// The sender's settings.
    pub sender: SenderConfig,
    /// The simulated link.
    pub link: SimConfig,
    /// How much faster than the radio the simulated link runs.
    pub speedup: f64,
    /// An extra display (e.g. the web viewer).
    pub sink: Option<Box<dyn Sink>>,
    /// The sender's and the receiver's keys; `None` runs the link unsealed.
    pub keys: Option<(Keys, Keys)>,
}

/// What the demo measured (written as `report.json`).
#[derive(Serialize)]
pub struct DemoReport {
    /// Scene name.
    pub scene: String,
    /// Image size.
    pub size: (usize, usize),
    /// Segmentation method and levels.
    pub segmentation: String,
    /// Bytes of the two original views as PNG files.
    pub original_png_bytes: usize,
    /// Bytes of the StereoFrame message.
    pub frame_bytes: usize,
    /// Bytes of the DepthReport message.
    pub report_bytes: usize,
    /// `original_png_bytes / frame_bytes`.
    pub compression_ratio: f64,
    /// Size reduction against the original PNGs, percent (the paper's Fig. 12 measure).
    pub reduction_percent: f64,
    /// PSNR of the segmented left and right views, dB.
    pub psnr_db: (f64, f64),
    /// Link frame loss of the simulated radio.
    pub link_loss: f64,
    /// Radio time to deliver both messages, seconds.
    pub link_seconds: f64,
    /// Message bits per radio second.
    pub goodput_bps: f64,
    /// Retransmitted link segments.
    pub retransmissions: u64,
    /// Link segments sent.
    pub segments: u64,
    /// Every message was sealed by the secure layer (Noise KK).
    pub sealed: bool,
    /// Messages the receiver's secure layer refused (0 on a clean run).
    pub rejected: u64,
    /// The received views equal the sent segmented views bit for bit.
    pub received_equals_sent: bool,
    /// Reported target distance, metres.
    pub distance_m: f64,
    /// Ground-truth distance of the same region, metres (when the scene has ground truth).
    pub true_distance_m: Option<f64>,
    /// Commanded axis position, mm.
    pub axis_commanded_mm: Option<f64>,
    /// Final axis position, mm.
    pub axis_final_mm: Option<f64>,
    /// |final − commanded|, mm.
    pub axis_error_mm: Option<f64>,
    /// Sender times: segmentation, encoding, matching (ms).
    pub sender_ms: (f64, f64, f64),
    /// Receiver time for the frame (decode, match, render), ms.
    pub receiver_frame_ms: f64,
}

/// ARQ timers for a simulated radio running `speedup` times faster than real time.
fn radio_config(mtu: usize, speedup: f64) -> Config {
    let c = Config::for_mtu(mtu);
    let scale = |t: u64| ((t as f64 / speedup.max(1.0)) as u64).max(1_000);
    Config {
        initial_rto: scale(c.initial_rto),
        min_rto: scale(c.min_rto),
        ..c
    }
}

fn write_png(dir: &Path, name: &str, img: &stereolink_image::RgbImage) -> anyhow::Result<()> {
    io::write_rgb(dir.join(name), img)
        .with_context(|| format!("cannot write {}", dir.join(name).display()))
}

/// Runs the demo; `progress` is told about each stage.
pub fn run(cfg: DemoConfig, progress: &dyn Fn(&str)) -> anyhow::Result<DemoReport> {
    let scene = &cfg.scene;
    let (w, h) = scene.left.dims();
    std::fs::create_dir_all(cfg.out.join("sent"))
        .with_context(|| format!("cannot create {}", cfg.out.display()))?;
    std::fs::create_dir_all(cfg.out.join("received"))?;
    progress("segmenting, encoding and matching on the sender");
    let prepared = prepare(
        &scene.left,
        &scene.right,
        &scene.calib,
        &cfg.sender,
        (1, unix_us()),
    )?;
    write_png(&cfg.out, "sent/left.png", &prepared.sent.0)?;
    write_png(&cfg.out, "sent/right.png", &prepared.sent.1)?;
    let original_png_bytes =
        io::encode_png_rgb(&scene.left).len() + io::encode_png_rgb(&scene.right).len();

    progress("sending over the simulated XBee link");
    let (tx_end, rx_end) = pair(cfg.link, cfg.speedup);
    let messages = vec![prepared.frame_bytes.clone(), prepared.report_bytes.clone()];
    let max_disp = scene
        .calib
        .ndisp
        .saturating_sub(1)
        .clamp(1, w.saturating_sub(1));
    let mut board = BoardReceiver::new(max_disp, 9, Duration::from_secs(10));
    board.axis = Some(Box::new(SimAxis::new(MotorParams::default())));
    board.sink = cfg.sink;
    // Timers follow the radio's clock, which runs `speedup` times faster.
    let arq = radio_config(cfg.link.mtu, cfg.speedup);
    let sealed = cfg.keys.is_some();
    let (tx_keys, rx_keys) = cfg.keys.unzip();
    let seal = move |ep: Endpoint, keys: Option<Keys>| match keys {
        Some(k) => ep.with_keys(k, SecureConfig::default()),
        None => ep,
    };
    let sender = std::thread::spawn(move || -> anyhow::Result<(f64, u64, u64)> {
        let mut ep = seal(Endpoint::with_config(Box::new(tx_end), arq)?, tx_keys);
        let (mut secs, mut retx, mut segs) = (0.0, 0, 0);
        for m in &messages {
            let s = ep.send_message(m)?;
            secs += s.elapsed.as_secs_f64();
            retx += s.retransmissions;
            segs += s.segments;
        }
        Ok((secs, retx, segs))
    });
    let mut ep = seal(Endpoint::with_config(Box::new(rx_end), arq)?, rx_keys);
    let mut events = Vec::new();
    for _ in 0..2 {
        let msg = ep
            .recv_message(Duration::from_secs(300))
            .context("receiving over the simulated link")?;
        events.push(board.handle(&msg));
    }
    while !sender.is_finished() {
        ep.linger(Duration::from_millis(50))?;
    }
    let rejected = ep.rejections().map_or(0, |r| r.total());
    let (wall_secs, retransmissions, segments) = sender
        .join()
        .map_err(|_| anyhow::anyhow!("the sender thread panicked"))??;
    let link_seconds = wall_secs * cfg.speedup;
    let bytes = prepared.frame_bytes.len() + prepared.report_bytes.len();

    progress("moving the axis");
    let mut frame_ms = 0.0;
    let mut commanded = None;
    for e in &events {
        match e {
            Event::Frame { ms, .. } => frame_ms = *ms,
            Event::Report { commanded_mm, .. } => commanded = *commanded_mm,
            Event::Rejected(why) => anyhow::bail!("the receiver rejected a message: {why}"),
            Event::Command { command, .. } => {
                anyhow::bail!("the demo sent no command, yet the receiver read {command}")
            }
            Event::Answered { id, .. } => {
                anyhow::bail!("the demo's receiver asked for no key frame, yet read answer {id}")
            }
        }
    }
    let axis_final = match board.axis.as_mut() {
        // Let the simulated axis finish its move (up to 60 s of its time).
        Some(axis) => stereolink_robot::wait_until_idle(axis.as_mut(), 6000)
            .ok()
            .flatten(),
        None => None,
    };
    let (received_left, received_right) = board
        .pair()
        .map(|(l, r)| (l.clone(), r.clone()))
        .context("no frame was received")?;
    write_png(&cfg.out, "received/left.png", &received_left)?;
    write_png(&cfg.out, "received/right.png", &received_right)?;
    write_png(
        &cfg.out,
        "anaglyph.png",
        &anaglyph(&received_left, &received_right, Anaglyph::Dubois),
    )?;
    let dmax = max_disp as f32;
    write_png(
        &cfg.out,
        "disparity.png",
        &colormap::colorize_with_bar(&prepared.disparity, 0.0, dmax),
    )?;
    write_png(
        &cfg.out,
        "board-disparity.png",
        &colormap::colorize_with_bar(&board.disparity(), 0.0, dmax),
    )?;
    board.status.axis_mm = axis_final;
    board.status.link_quality = Some(1.0 - retransmissions as f64 / segments.max(1) as f64);
    board.refresh()?;
    write_png(&cfg.out, "screen.png", board.screen())?;
    let roi: Roi = cfg.sender.roi.unwrap_or_else(|| default_roi(w, h));
    let true_distance_m = scene
        .gt_left
        .as_ref()
        .and_then(|gt| region_distance(gt, roi, &scene.calib).ok().flatten());
    let report = DemoReport {
        scene: scene.name.clone(),
        size: (w, h),
        segmentation: format!(
            "{} with {} levels",
            cfg.sender.method.name(),
            cfg.sender.levels
        ),
        original_png_bytes,
        frame_bytes: prepared.frame_bytes.len(),
        report_bytes: prepared.report_bytes.len(),
        compression_ratio: original_png_bytes as f64 / prepared.frame_bytes.len() as f64,
        reduction_percent: reduction_percent(original_png_bytes, prepared.frame_bytes.len()),
        psnr_db: prepared.psnr_db,
        link_loss: cfg.link.loss,
        link_seconds,
        goodput_bps: bytes as f64 * 8.0 / link_seconds.max(1e-9),
        retransmissions,
        sealed,
        rejected,
        segments,
        received_equals_sent: received_left == prepared.sent.0 && received_right == prepared.sent.1,
        distance_m: prepared.report.target_distance_m as f64,
        true_distance_m,
        axis_commanded_mm: commanded,
        axis_final_mm: axis_final,
        axis_error_mm: commanded.zip(axis_final).map(|(c, f)| (f - c).abs()),
        sender_ms: prepared.times_ms,
        receiver_frame_ms: frame_ms,
    };
    std::fs::write(
        cfg.out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    Ok(report)
}
