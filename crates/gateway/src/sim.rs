//! A simulated station: synthetic frames and depth reports over a real
//! link, paced like a radio, and an axis that obeys the gateway's
//! commands and replies to each. The gateway tests and measurements run
//! several of them.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use stereolink_codec::container;
use stereolink_codec::control::{unix_us, Command, Control, Reply};
use stereolink_codec::{DepthReport, Message, ReportLevel};
use stereolink_image::synth::SynthSpec;
use stereolink_link::endpoint::{Endpoint, Lane, LinkError};
use stereolink_link::secure::{Keys, SecureConfig};
use stereolink_link::spec::{self, LinkSpec};
use stereolink_pipeline::receiver::synthetic_frame;
use stereolink_robot::Axis;

/// How a simulated station behaves.
#[derive(Clone, Debug)]
pub struct SimConfig {
    /// The station's link to the gateway.
    pub link: LinkSpec,
    /// The link keys (the station's private key, the gateway's public key).
    pub keys: Option<Keys>,
    /// Depth reports to send (frame ids `first_id..first_id + reports`).
    pub reports: u32,
    /// The first report's frame id.
    pub first_id: u32,
    /// A frame goes with every this many reports (0: none).
    pub frame_every: u32,
    /// The synthetic scene of the frames.
    pub scene: SynthSpec,
    /// A frame message to send instead of the synthetic scene's (an
    /// encoded pair, e.g. `stereolink encode`'s output).
    pub frame: Option<Arc<Vec<u8>>>,
    /// Time between reports.
    pub interval: Duration,
    /// Pace the link to this many message bytes a second (0: unpaced).
    pub bytes_per_s: f64,
}

impl SimConfig {
    /// `reports` reports every `interval`, a 128x96 frame every 10th.
    pub fn new(link: LinkSpec, reports: u32, interval: Duration) -> Self {
        SimConfig {
            link,
            keys: None,
            reports,
            first_id: 1,
            frame_every: 10,
            scene: SynthSpec {
                width: 128,
                height: 96,
                max_disp: 16,
                seed: 3,
            },
            frame: None,
            interval,
            bytes_per_s: 0.0,
        }
    }
}

/// What a simulated station did.
#[derive(Debug, Default)]
pub struct SimLog {
    /// Reports whose every fragment the gateway acknowledged.
    pub reports_delivered: u32,
    /// Frames whose every fragment the gateway acknowledged.
    pub frames_delivered: u32,
    /// What went wrong, one line each.
    pub failures: Vec<String>,
    /// Commands taken, with when.
    pub commands: Vec<(Command, Instant)>,
    /// Whether the axis moves (checked after each command).
    pub axis_moving: bool,
    /// Axis positions read after a stop: they must not change.
    pub stopped_at_mm: Vec<f64>,
    /// Every report was handed to the link.
    pub done: bool,
}

/// A running simulated station.
pub struct SimStation {
    /// What it did so far.
    pub log: Arc<Mutex<SimLog>>,
    stop: Arc<AtomicBool>,
    kill: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl SimStation {
    /// Starts the station's thread.
    pub fn start(cfg: SimConfig) -> anyhow::Result<SimStation> {
        let frame = if let Some(f) = &cfg.frame {
            f.to_vec()
        } else if cfg.frame_every > 0 {
            synthetic_frame(&cfg.scene)?
        } else {
            Vec::new()
        };
        let log = Arc::new(Mutex::new(SimLog::default()));
        let (stop, kill) = Default::default();
        let thread = {
            let (log, stop, kill): (_, Arc<AtomicBool>, Arc<AtomicBool>) =
                (log.clone(), Arc::clone(&stop), Arc::clone(&kill));
            std::thread::spawn(move || {
                if let Err(e) = run(cfg, frame, &log, &stop, &kill) {
                    log.lock().expect("log").failures.push(format!("{e:#}"));
                }
            })
        };
        Ok(SimStation {
            log,
            stop,
            kill,
            thread: Some(thread),
        })
    }

    /// Whether every report was handed over and delivered or failed.
    pub fn finished(&self) -> bool {
        self.log.lock().expect("log").done
    }

    /// Stops sending (what is in flight ends first), then answers the
    /// gateway's last retransmissions a moment.
    pub fn stop(mut self) -> Arc<Mutex<SimLog>> {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.log.clone()
    }

    /// Stops at once, as a killed process: not another segment.
    pub fn kill(mut self) {
        self.kill.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for SimStation {
    fn drop(&mut self) {
        self.kill.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn report(frame_id: u32) -> Vec<u8> {
    let d = 0.5 + (frame_id % 100) as f32 * 0.01;
    let r = DepthReport {
        target_distance_m: d,
        target_region: [10, 10, 40, 30],
        levels: vec![
            ReportLevel {
                disparity: 12.0,
                distance_m: d,
                share: 0.6,
            },
            ReportLevel {
                disparity: 4.0,
                distance_m: 3.0 * d,
                share: 0.4,
            },
        ],
        histogram: vec![0; 17],
    };
    container::encode(&Message::DepthReport(r), frame_id, unix_us())
}

/// The frame message with its id and time set (the header is not under
/// the body's CRC).
fn restamp(frame: &mut [u8], frame_id: u32) {
    frame[8..12].copy_from_slice(&frame_id.to_le_bytes());
    frame[12..20].copy_from_slice(&unix_us().to_le_bytes());
}

fn run(
    cfg: SimConfig,
    mut frame: Vec<u8>,
    log: &Mutex<SimLog>,
    stop: &AtomicBool,
    kill: &AtomicBool,
) -> anyhow::Result<()> {
    let mut ep = Endpoint::new(spec::open(&cfg.link)?)?;
    if let Some(k) = cfg.keys.clone() {
        ep = ep.with_keys(k, SecureConfig::default());
    }
    let mut axis = stereolink_robot::open_axis("sim")?;
    // A long move, for a stop command to interrupt.
    axis.move_to(1000.0, 50.0)?;
    let mut stopped = false;
    let (mut next_id, end_id) = (cfg.first_id, cfg.first_id + cfg.reports);
    let mut next_at = Instant::now();
    let mut frame_wanted = false;
    let mut busy = [false; 2]; // urgent, bulk
                               // Replies to commands go on the urgent lane ahead of the next report.
    let (mut replies, mut urgent_is_reply) = (VecDeque::<Vec<u8>>::new(), false);
    // Pacing: the time the link is busy with what was sent.
    let mut link_free = Instant::now();
    let pace = |bytes: usize, link_free: &mut Instant| {
        if cfg.bytes_per_s > 0.0 {
            let t = Duration::from_secs_f64(bytes as f64 / cfg.bytes_per_s);
            *link_free = (*link_free).max(Instant::now()) + t;
        }
    };
    loop {
        if kill.load(Ordering::Relaxed) {
            return Ok(());
        }
        let now = Instant::now();
        let idle = !busy[0] && !busy[1];
        if next_id >= end_id && idle {
            log.lock().expect("log").done = true;
        }
        // Asked to stop: no new report; leave once the lanes are idle.
        let stopping = stop.load(Ordering::Relaxed);
        if stopping && idle {
            break;
        }
        if !busy[0] {
            if let Some(reply) = replies.pop_front() {
                ep.submit(Lane::Urgent, &reply)?;
                (busy[0], urgent_is_reply) = (true, true);
            }
        }
        // The frame that goes with a report goes before the next report.
        let frame_due = frame_wanted && !frame.is_empty();
        if !stopping
            && !frame_due
            && next_id < end_id
            && !busy[0]
            && now >= next_at
            && now >= link_free
        {
            let msg = report(next_id);
            pace(msg.len(), &mut link_free);
            ep.submit(Lane::Urgent, &msg)?;
            busy[0] = true;
            if cfg.frame_every > 0 && (next_id - cfg.first_id) % cfg.frame_every == 0 {
                frame_wanted = true;
            }
            next_id += 1;
            next_at += cfg.interval;
        }
        if frame_wanted && !busy[1] && !frame.is_empty() && Instant::now() >= link_free {
            restamp(&mut frame, next_id - 1);
            pace(frame.len(), &mut link_free);
            ep.submit(Lane::Bulk, &frame)?;
            busy[1] = true;
            frame_wanted = false;
        }
        for (lane, result) in ep.poll_sends(Duration::from_millis(2))? {
            let i = (lane == Lane::Bulk) as usize;
            busy[i] = false;
            let mut l = log.lock().expect("log");
            match (result, lane) {
                (Ok(_), Lane::Urgent) if std::mem::take(&mut urgent_is_reply) => {}
                (Ok(_), Lane::Urgent) => l.reports_delivered += 1,
                (Ok(_), Lane::Bulk) => l.frames_delivered += 1,
                (Err(e), _) => l.failures.push(e.to_string()),
            }
        }
        loop {
            match ep.recv_message(Duration::ZERO) {
                Ok(msg) => {
                    let reply =
                        on_command(&msg, axis.as_mut(), &mut stopped, &mut frame_wanted, log);
                    replies.extend(reply.map(|r| r.message()));
                }
                Err(LinkError::Timeout) => break,
                Err(e) => {
                    log.lock().expect("log").failures.push(e.to_string());
                    break;
                }
            }
        }
        if stopped {
            let p = axis.position()?;
            let mut l = log.lock().expect("log");
            if l.stopped_at_mm.len() < 100 {
                l.stopped_at_mm.push(p);
            }
        }
    }
    ep.linger(Duration::from_millis(200))?;
    Ok(())
}

/// Obeys a command (levels and method are taken and change nothing in the
/// synthetic frames); returns the reply to send.
fn on_command(
    msg: &[u8],
    axis: &mut dyn Axis,
    stopped: &mut bool,
    frame_wanted: &mut bool,
    log: &Mutex<SimLog>,
) -> Option<Reply> {
    let mut l = log.lock().expect("log");
    match Control::from_message(msg) {
        Ok(Control::Reply(r)) => l.failures.push(format!("a reply to a station: {r:?}")),
        Ok(Control::Command { command: c, id }) => {
            match c {
                Command::AxisStop => {
                    let _ = axis.stop();
                    *stopped = true;
                }
                Command::FrameRequest => *frame_wanted = true,
                Command::SetLevels(_) | Command::SetMethod(_) => {}
            }
            l.axis_moving = axis.is_moving().unwrap_or(true);
            l.commands.push((c, Instant::now()));
            return Some(Reply { id, result: Ok(()) });
        }
        Err(e) => l.failures.push(format!("command refused: {e}")),
    }
    None
}
