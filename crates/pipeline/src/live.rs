//! The sender's pair loop on a real link, for one pair (sent again and
//! again), for every pair a camera writes into a folder, or live from two
//! cameras. All three feed one loop ([`Pairs`]): take a pair, rectify and
//! prepare it, send it. Between pairs the loop obeys the commands that
//! came over the link ([`SendLoop::run`]): new levels or method from the
//! next pair, the last pair again at once on a frame request; each is
//! answered on the link. `stereolink send` builds it and prints what it sent.

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_calib::StereoRectifier;
use stereolink_capture::StereoCapture;
use stereolink_codec::control::{Control, Reply};
use stereolink_image::{io, Calibration, RgbImage};
use stereolink_link::endpoint::SendStats;

use crate::sender::{prepare, Applied, SenderConfig};
use crate::uplink::{Kind, Outcome, Uplink};
use crate::watch::{Pair, Watcher};

/// One frame sent: its sizes, what preparing it cost, and how its frame
/// and depth report were delivered.
#[derive(Debug, Serialize)]
pub struct Sent {
    /// The frame's id (1, 2, ...).
    pub frame_id: u32,
    /// Bytes of the frame message.
    pub frame_bytes: usize,
    /// Bytes of the depth report message.
    pub report_bytes: usize,
    /// How the views were coded (`segmented`, `jpeg`, `webp`).
    pub view_coding: &'static str,
    /// The coding's setting: the lossy quality, or the segmentation's classes.
    pub setting: u8,
    /// PSNR of the left and right views as sent.
    pub psnr_db: (f64, f64),
    /// The reported distance to the target, metres.
    pub distance_m: f32,
    /// From handing the frame to the link until its last fragment was acknowledged.
    pub seconds: f64,
    /// From handing the depth report to the link until it was acknowledged.
    pub report_seconds: f64,
    /// The frame's goodput, bits a second.
    pub goodput_bps: f64,
    /// Retransmissions of the frame and of its report.
    pub retransmissions: u64,
    /// Pairs the cameras delivered while the one before was prepared and sent.
    pub skipped: u64,
    /// Time spent waiting for the pair (reading it, or for the cameras), ms.
    pub wait_ms: f64,
    /// Rectifying the pair, ms.
    pub rectify_ms: f64,
    /// Segmenting both views, ms.
    pub segment_ms: f64,
    /// Matching for the depth report, ms.
    pub match_ms: f64,
    /// Encoding the frame, ms.
    pub encode_ms: f64,
    /// Sending the frame (as `seconds`), ms.
    pub send_ms: f64,
    /// What the link measured so far (damaged frames, the radio's statuses).
    pub link: String,
}

/// The link thread and what every frame is prepared with.
pub struct SendLoop {
    uplink: Uplink,
    calib: Calibration,
    /// The maps of a raw pair (`--calib stereo.yml`).
    rectifier: Option<StereoRectifier>,
    /// The rectified views, reused from pair to pair.
    rectified: (RgbImage, RgbImage),
    cfg: SenderConfig,
    save: Option<PathBuf>,
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
pub struct Pairs(Source);

enum Source {
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
    /// One pair of files, sent `repeat` times.
    pub fn files(left: RgbImage, right: RgbImage, repeat: u32) -> Pairs {
        Pairs(Source::Files {
            left,
            right,
            remaining: repeat,
        })
    }

    /// Each new pair a capture program writes into `dir` (`left*.png` with
    /// the `right*.png` of the same name, in name order; a rewritten pair
    /// is sent again), the folder read every `poll`.
    pub fn folder(dir: PathBuf, poll: Duration) -> Pairs {
        Pairs(Source::Folder {
            dir,
            poll,
            watcher: Watcher::new(),
            pending: VecDeque::new(),
        })
    }

    /// Two live cameras; one that delivers nothing for `timeout` stops the
    /// loop with an error.
    pub fn cameras(timeout: Duration, capture: StereoCapture) -> Pairs {
        Pairs(Source::Cameras {
            timeout,
            capture: Box::new(capture),
            skipped: 0,
        })
    }

    /// Whether the pairs come live from cameras (the next one is always
    /// fresh, and comes at once).
    fn live(&self) -> bool {
        matches!(self.0, Source::Cameras { .. })
    }

    /// The next pair, [`Got::Wait`] after one poll interval of an empty
    /// folder (a folder is waited on forever), or [`Got::End`]. A camera
    /// that stops is an error.
    fn next(&mut self) -> anyhow::Result<Got> {
        let start = Instant::now();
        let wait_ms = || start.elapsed().as_secs_f64() * 1e3;
        match &mut self.0 {
            Source::Files {
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
            Source::Folder {
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
            Source::Cameras {
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

impl SendLoop {
    /// A loop sending on `uplink`, each pair rectified by `rectifier` (a
    /// raw pair's maps) when given, prepared with `cfg` and `calib`; with
    /// `save`, the views as sent and the sender's disparity are written
    /// there (`sent-left.png`, `sent-right.png`, `sent-disparity.pfm`).
    pub fn new(
        uplink: Uplink,
        calib: Calibration,
        rectifier: Option<StereoRectifier>,
        cfg: SenderConfig,
        save: Option<PathBuf>,
    ) -> SendLoop {
        SendLoop {
            uplink,
            calib,
            rectifier,
            rectified: Default::default(),
            cfg,
            save,
            waiting: BTreeMap::new(),
            sent: Vec::new(),
            last: None,
        }
    }

    /// Sends `pairs` until they end or `frames` pairs are sent, obeying the
    /// link's commands between pairs; `on_sent` sees each frame once both
    /// its messages arrived. Returns every frame sent, in that order. A
    /// failed send stops the loop, naming the message.
    pub fn run(
        mut self,
        mut pairs: Pairs,
        frames: Option<u32>,
        mut on_sent: impl FnMut(&Sent),
    ) -> anyhow::Result<Vec<Sent>> {
        let mut frame_id = 0;
        while frames.is_none_or(|n| frame_id < n) {
            let next = match (self.obey()?, self.last.take()) {
                // The last pair again, now, with the current settings.
                (Applied::FrameNow, Some(last)) if !pairs.live() => Next {
                    wait_ms: 0.0,
                    skipped: 0,
                    ..last
                },
                (_, last) => {
                    self.last = last;
                    match pairs.next()? {
                        Got::Pair(next) => next,
                        Got::Wait => continue,
                        Got::End => break,
                    }
                }
            };
            frame_id += 1;
            self.send(&next, frame_id, &mut on_sent)?;
            self.last = Some(next);
        }
        let rest = self.uplink.finish()?;
        self.collect(rest, &mut on_sent)?;
        Ok(self.sent)
    }

    /// Prepares one pair (rectified first with `--calib stereo.yml`) and
    /// sends its frame and depth report.
    fn send(
        &mut self,
        next: &Next,
        frame_id: u32,
        on_sent: &mut impl FnMut(&Sent),
    ) -> anyhow::Result<()> {
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
            view_coding: self.cfg.coding.coding.name(),
            setting: p.setting,
            psnr_db: p.psnr_db,
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
        self.collect(outcomes, on_sent)
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
    /// message; a frame whose two messages both arrived is done.
    fn collect(
        &mut self,
        outcomes: Vec<Outcome>,
        on_sent: &mut impl FnMut(&Sent),
    ) -> anyhow::Result<()> {
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
                    self.done(w.sent, f, r, on_sent);
                }
            }
        }
        Ok(())
    }

    /// Completes a frame's record from how its two messages were delivered
    /// and hands it to `on_sent`.
    fn done(
        &mut self,
        mut s: Sent,
        frame: SendStats,
        report: SendStats,
        on_sent: &mut impl FnMut(&Sent),
    ) {
        s.seconds = frame.elapsed.as_secs_f64();
        s.report_seconds = report.elapsed.as_secs_f64();
        s.goodput_bps = frame.goodput_bps();
        s.retransmissions = frame.retransmissions + report.retransmissions;
        s.send_ms = s.seconds * 1e3;
        on_sent(&s);
        self.sent.push(s);
    }
}
