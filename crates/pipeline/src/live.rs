//! The sender's pair loop on a real link, for one pair (sent again and
//! again), for the pairs a camera writes into a folder, a recorded sequence,
//! or live from two cameras ([`Pairs`]). Every pair taken is matched, and
//! its depth report goes at once on the urgent lane, whatever frame is in
//! flight: the robot gets depth at the camera's rate. A live pair becomes a
//! frame only when the link has finished the frame before (frames as fast
//! as the link carries them, the newest pair winning), and only while the
//! reports leave the link most of its air: on a link too slow for both,
//! depth goes alone. Each pair of files is a frame. Between pairs the loop obeys the commands that came over the
//! link ([`SendLoop::run`]): new levels or method from the next pair, the
//! last pair again at once on a frame request; each is answered on the
//! link. Once a second, and at the end, it says what the link carried
//! ([`Status`]). `stereolink send` builds it and prints what it sent.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_calib::StereoRectifier;
use stereolink_codec::container::{self, Body};
use stereolink_codec::control::{unix_us, Control, Reply};
use stereolink_codec::temporal::SkipSpec;
use stereolink_codec::{CodecError, DepthReport, Limits};
use stereolink_image::{io, Calibration, RgbImage};
use stereolink_link::endpoint::SendStats;

use crate::pairs::{Got, Next, Pairs};
use crate::rates::{Figures, Rates};
use crate::record::Recorder;
use crate::sender::{measure_depth, prepare, report_message, Applied, SenderConfig};
use crate::stream::StreamEncoder;
use crate::uplink::{Ended, Kind, Outcome, Uplink};

/// One frame sent: its sizes, what preparing it cost, and how its frame
/// and depth report were delivered.
#[derive(Debug, Serialize)]
pub struct Sent {
    /// The id of the frame's pair (1, 2, ...: every pair taken has one).
    pub frame_id: u32,
    /// Bytes of the frame message.
    pub frame_bytes: usize,
    /// Bytes of the depth report message.
    pub report_bytes: usize,
    /// `key`, or `predicted` from the last frame delivered (`send
    /// --temporal`).
    pub frame_kind: &'static str,
    /// How the views were coded (`segmented`, `jpeg`, `webp`).
    pub view_coding: &'static str,
    /// Whether the right view is predicted from the left one
    /// (`--stereo-prediction`).
    pub stereo_prediction: bool,
    /// The coding's setting: the lossy quality, or the segmentation's classes.
    pub setting: u8,
    /// PSNR of the left and right views as sent.
    pub psnr_db: (f64, f64),
    /// The reported distance to the target, metres.
    pub distance_m: f32,
    /// From handing the frame to the link until its last fragment was acknowledged.
    pub seconds: f64,
    /// From handing the depth report to the link until it was
    /// acknowledged; `None` when a newer pair's report took its place first.
    pub report_seconds: Option<f64>,
    /// The frame's goodput, bits a second.
    pub goodput_bps: f64,
    /// Retransmissions of the frame and of its report.
    pub retransmissions: u64,
    /// Pairs passed over for this newer one.
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

/// What the loop did over a span: once a second, and for the whole run.
#[derive(Clone, Debug, Serialize)]
pub struct Status {
    /// Pairs taken and matched (each gave a depth report).
    pub pairs: u64,
    /// Pairs passed over for a newer one.
    pub skipped: u64,
    /// Reports overtaken by a newer one before they were acknowledged
    /// (waiting, or in flight: the peer may have had it, but it is not
    /// counted delivered).
    pub superseded: u64,
    /// The share of the frames' link's air the depth reports take at the
    /// camera's rate (over 0.5, live frames stop: depth goes alone); none
    /// when unknown or the reports have a link of their own.
    pub report_air_share: Option<f64>,
    /// Reports and frames the peer acknowledged; a report's latency runs
    /// from its pair's capture to that acknowledgement.
    #[serde(flatten)]
    pub delivered: Figures,
    /// Delivered message bits a second.
    pub goodput_bps: f64,
    /// DATA segments sent again.
    pub retransmissions: u64,
    /// What the link measured so far.
    pub link: String,
}

impl Status {
    /// Whether the reports took so much of the air that live frames
    /// stopped (depth went alone).
    pub fn depth_alone(&self) -> bool {
        self.report_air_share
            .is_some_and(|s| s > REPORTS_ALONE_ABOVE)
    }
}

/// What the loop tells its caller as it goes.
pub enum Update<'a> {
    /// A frame and its report ended.
    Frame(&'a Sent),
    /// The last second.
    Second(&'a Status),
}

/// What a run sent.
#[derive(Debug, Serialize)]
pub struct Summary {
    /// Every frame, in the order they ended.
    pub frames: Vec<Sent>,
    /// The whole run.
    pub status: Status,
}

/// How long live frames hold back after a report had to wait for the air.
const STARVED_HOLD: Duration = Duration::from_secs(2);

/// The most of the frames' air the reports may take with frames still
/// starting: above it, a frame's fragments would hold up reports that
/// already fill most of the air, so depth goes alone (a link that
/// collapses to a few kb/s carries depth and no pictures).
const REPORTS_ALONE_ABOVE: f64 = 0.5;

/// How much of the frames' link the depth reports take: a report and its
/// acknowledgement's air time (two packet times) over the time between
/// pairs, averaged (a quarter of the weight on the last interval).
#[derive(Clone, Copy, Debug)]
struct ReportLoad {
    /// A report's air on the frames' link; none on a link of its own.
    air: Option<Duration>,
    last: Option<Instant>,
    interval_s: Option<f64>,
}

impl ReportLoad {
    fn new(air: Option<Duration>) -> ReportLoad {
        ReportLoad {
            air,
            last: None,
            interval_s: None,
        }
    }

    /// A pair was taken at `now`.
    fn taken(&mut self, now: Instant) {
        if let Some(last) = self.last {
            let dt = now.duration_since(last).as_secs_f64();
            self.interval_s = Some(self.interval_s.map_or(dt, |i| 0.75 * i + 0.25 * dt));
        }
        self.last = Some(now);
    }

    /// The share of the frames' air the reports take (may exceed 1: the
    /// air carries fewer reports than the pairs come).
    fn share(&self) -> Option<f64> {
        Some(self.air?.as_secs_f64() / self.interval_s?.max(1e-6))
    }

    /// Whether depth needs the air to itself; so it is until the second
    /// pair says how often reports come, when they share the frames' air
    /// (a first frame on a collapsed link would hold it for many seconds).
    fn holds_frames(&self) -> bool {
        self.air.is_some() && self.share().is_none_or(|s| s > REPORTS_ALONE_ABOVE)
    }
}

/// The smallest frame's size, when `e` says a budget was below it.
fn smallest_frame(e: &anyhow::Error) -> Option<usize> {
    match e.downcast_ref::<CodecError>() {
        Some(CodecError::BudgetTooSmall { minimum, .. }) => Some(*minimum),
        _ => None,
    }
}

/// The counts behind a [`Status`].
#[derive(Clone)]
struct Counts {
    rates: Rates,
    pairs: u64,
    skipped: u64,
    superseded: u64,
    retransmissions: u64,
}

impl Counts {
    fn new(since: Instant) -> Counts {
        Counts {
            rates: Rates::new(since),
            pairs: 0,
            skipped: 0,
            superseded: 0,
            retransmissions: 0,
        }
    }

    fn status(&self, now: Instant, link: &str, load: &ReportLoad) -> Status {
        let delivered = self.rates.figures(now);
        Status {
            pairs: self.pairs,
            skipped: self.skipped,
            superseded: self.superseded,
            report_air_share: load.share(),
            goodput_bps: delivered.bytes as f64 * 8.0 / delivered.seconds.max(1e-9),
            delivered,
            retransmissions: self.retransmissions,
            link: link.to_string(),
        }
    }
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
    /// Reports handed to the link: when, and their pair's capture (µs).
    handed: BTreeMap<u32, (u64, u64)>,
    sent: Vec<Sent>,
    /// The last pair taken, for a frame request.
    last: Option<Next>,
    /// The whole run, and the last second.
    total: Counts,
    second: Counts,
    /// What the link said last.
    link: String,
    /// With a frame interval: each frame's byte budget follows the goodput
    /// the link measures.
    pace: Option<FramePace>,
    /// With temporal prediction: the stream's references, and how often a
    /// key frame goes anyway.
    stream: Option<(StreamEncoder, Duration)>,
    /// Until when no new live frame starts: a report had to be replaced
    /// before it could go (the air carries fewer reports than the camera
    /// makes).
    starved_until: Option<Instant>,
    /// How much of the frames' air the reports take.
    load: ReportLoad,
    /// `--record FILE.mcap`.
    recorder: Option<Recorder>,
}

/// Frames sized to the link: a frame's budget is the goodput measured on
/// the last frames times the interval wanted, so that a frame takes about
/// that long to cross whatever the link carries now (reports included).
#[derive(Clone, Copy, Debug)]
struct FramePace {
    interval: Duration,
    /// The frames' goodput, bits a second, averaged (half the weight on
    /// the last frame); none before the first frame ends.
    goodput_bps: Option<f64>,
}

impl FramePace {
    /// The next frame's budget, bytes; none until a frame has been timed.
    fn budget(&self) -> Option<usize> {
        self.goodput_bps
            .map(|g| (g * self.interval.as_secs_f64() / 8.0) as usize)
    }

    fn delivered(&mut self, frame: &SendStats) {
        let g = frame.goodput_bps();
        self.goodput_bps = Some(self.goodput_bps.map_or(g, |old| (old + g) / 2.0));
    }
}

/// A frame on its way: what was measured preparing it, and how its two
/// messages ended so far (its report: delivered, or `None` if superseded).
struct Waiting {
    sent: Sent,
    frame: Option<SendStats>,
    report: Option<Option<SendStats>>,
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
        let now = Instant::now();
        SendLoop {
            uplink,
            calib,
            rectifier,
            rectified: Default::default(),
            cfg,
            save,
            waiting: BTreeMap::new(),
            handed: BTreeMap::new(),
            sent: Vec::new(),
            last: None,
            total: Counts::new(now),
            second: Counts::new(now),
            link: String::new(),
            pace: None,
            stream: None,
            recorder: None,
            starved_until: None,
            load: ReportLoad::new(None),
        }
    }

    /// Predicts each frame from the last one the link delivered
    /// ([`StreamEncoder`]: blocks within sensor noise skipped), with a key
    /// frame first, on a frame request, and once `key_every` has passed
    /// since the last one.
    pub fn temporal(mut self, key_every: Duration) -> SendLoop {
        self.stream = Some((StreamEncoder::new(SkipSpec::default()), key_every));
        self
    }

    /// Records each frame's views, cameras and disparity, each depth
    /// report and the link's statistics once a second in `recorder`.
    pub fn record(mut self, recorder: Option<Recorder>) -> SendLoop {
        self.recorder = recorder;
        self
    }

    /// Sizes each frame (with the coding's rate control) to cross the link
    /// in about `interval` at the goodput it measures; the first frame
    /// takes the configured budget. A budget below the smallest frame
    /// sends the smallest.
    pub fn frame_interval(mut self, interval: Duration) -> SendLoop {
        self.pace = Some(FramePace {
            interval,
            goodput_bps: None,
        });
        self
    }

    /// Sends `pairs` until they end or `frames` frames are sent, obeying
    /// the link's commands between pairs; `on` sees each frame once both
    /// its messages ended, and the status once a second. A failed send
    /// stops the loop, naming the message.
    pub fn run(
        mut self,
        mut pairs: Pairs,
        frames: Option<u32>,
        mut on: impl FnMut(Update),
    ) -> anyhow::Result<Summary> {
        let room = self.uplink.report_room()?;
        self.load = ReportLoad::new(room.frames_air);
        let room = room.bytes;
        let (mut pair_id, mut frames_sent) = (0, 0);
        let mut next_second = Instant::now() + Duration::from_secs(1);
        while frames.is_none_or(|n| frames_sent < n) {
            let outcomes = self.uplink.outcomes();
            self.collect(outcomes, &mut on)?;
            let now = Instant::now();
            if now >= next_second {
                let status = self.second.status(now, &self.link, &self.load);
                self.second = Counts::new(now);
                if let Some(r) = &mut self.recorder {
                    r.link(unix_us(), "stereolink send: link", &status)?;
                }
                on(Update::Second(&status));
                next_second = now + Duration::from_secs(1);
            }
            let wanted = self.obey()?;
            let next = match (wanted, self.last.take()) {
                // The last pair again, now, with the current settings.
                (Applied::FrameNow, Some(last)) if !pairs.cameras_live() => Next {
                    wait_ms: 0.0,
                    skipped: 0,
                    ..last
                },
                (_, last) => {
                    self.last = last;
                    match pairs.take()? {
                        Got::Pair(next) => next,
                        Got::Wait => continue,
                        Got::End => break,
                    }
                }
            };
            pair_id += 1;
            self.load.taken(Instant::now());
            let starved =
                self.starved_until.is_some_and(|t| Instant::now() < t) || self.load.holds_frames();
            if starved && pairs.paced() {
                tracing::debug!(
                    pair = pair_id,
                    report_air_share = self.load.share(),
                    "no frame: depth takes the air"
                );
            }
            let frame = wanted == Applied::FrameNow
                || !pairs.paced()
                || (!starved && !self.uplink.frame_in_flight());
            if frame {
                // The frame just ended counts as delivered (a reference).
                let ended = self.uplink.outcomes();
                self.collect(ended, &mut on)?;
                let want_key = wanted == Applied::FrameNow;
                self.send_frame(&next, (pair_id, want_key), (room, pairs.paced()))?;
                frames_sent += 1;
            } else {
                self.send_report(&next, pair_id, (room, true))?;
            }
            for c in [&mut self.total, &mut self.second] {
                c.pairs += 1;
                c.skipped += next.skipped;
            }
            self.last = Some(next);
        }
        let rest = self.uplink.finish()?;
        self.collect(rest, &mut on)?;
        let status = self.total.status(Instant::now(), &self.link, &self.load);
        if let Some(r) = self.recorder.take() {
            r.finish()?;
        }
        Ok(Summary {
            frames: self.sent,
            status,
        })
    }

    /// The pair's views, rectified first with `--calib stereo.yml`, and
    /// how long that took (ms).
    fn views<'a>(
        &'a mut self,
        next: &'a Next,
        pair_id: u32,
    ) -> anyhow::Result<((&'a RgbImage, &'a RgbImage), f64)> {
        let start = Instant::now();
        let views = match &self.rectifier {
            Some(r) => {
                let (a, b) = &mut self.rectified;
                r.rectify_into(&next.left, &next.right, a, b)
                    .with_context(|| format!("cannot rectify pair {pair_id}"))?;
                (&self.rectified.0, &self.rectified.1)
            }
            None => (&next.left, &next.right),
        };
        Ok((views, start.elapsed().as_secs_f64() * 1e3))
    }

    /// Hands a depth report to the link, cut down to one radio packet; a
    /// live pair's (`newest_wins`) gives way to a newer pair's.
    fn hand_report(
        &mut self,
        report: &DepthReport,
        (pair_id, captured_us): (u32, u64),
        (room, newest_wins): (usize, bool),
    ) -> anyhow::Result<usize> {
        let fitted = report.fitted(room).with_context(|| {
            format!("a depth report does not fit the link's {room}-byte packet")
        })?;
        let bytes = report_message(&fitted, pair_id, captured_us);
        let len = bytes.len();
        self.uplink.report(pair_id, bytes, newest_wins)?;
        self.handed.insert(pair_id, (unix_us(), captured_us));
        Ok(len)
    }

    /// Matches a pair and sends its depth report alone.
    fn send_report(
        &mut self,
        next: &Next,
        pair_id: u32,
        report_as: (usize, bool),
    ) -> anyhow::Result<()> {
        let (calib, cfg) = (self.calib, self.cfg.clone());
        let (views, _) = self.views(next, pair_id)?;
        let depth = measure_depth(views, None, &calib, &cfg)?;
        if let Some(r) = &mut self.recorder {
            r.report(next.captured_us, &depth.report)?;
        }
        self.hand_report(&depth.report, (pair_id, next.captured_us), report_as)?;
        Ok(())
    }

    /// Prepares a pair and sends its depth report and its frame (waiting
    /// here until the frame before has ended).
    fn send_frame(
        &mut self,
        next: &Next,
        (pair_id, want_key): (u32, bool),
        report_as: (usize, bool),
    ) -> anyhow::Result<()> {
        let (calib, mut cfg, paced) = (self.calib, self.cfg.clone(), self.pace.is_some());
        if let Some(budget) = self.pace.and_then(|p| p.budget()) {
            cfg.coding.budget = Some(budget);
        }
        // Out while the views borrow the loop (an error drops the recorder:
        // closed).
        let mut stream = self.stream.take();
        let mut recorder = self.recorder.take();
        let ((left, right), rectify_ms) = self.views(next, pair_id)?;
        let stamp = (pair_id, next.captured_us);
        let mut make = |cfg: &SenderConfig| match &mut stream {
            Some((encoder, key_every)) => {
                let due = encoder
                    .last_key_us()
                    .is_none_or(|t| stamp.1.saturating_sub(t) >= key_every.as_micros() as u64);
                let (p, kind) =
                    encoder.prepare((left, right), &calib, cfg, stamp, want_key || due)?;
                anyhow::Ok((p, kind.name()))
            }
            None => Ok((prepare(left, right, &calib, cfg, stamp)?, "key")),
        };
        let made = match make(&cfg) {
            // The link is slower than the smallest frame allows: send it.
            Err(e) if paced && smallest_frame(&e).is_some() => {
                cfg.coding.budget = smallest_frame(&e);
                make(&cfg)
            }
            made => made,
        };
        let recorded = match (&made, &mut recorder) {
            (Ok((p, _)), Some(r)) => {
                let captured_us = next.captured_us;
                r.views(captured_us, (left, right), &calib)
                    .and_then(|()| r.disparity(captured_us, &p.disparity, &calib))
                    .and_then(|()| r.report(captured_us, &p.report))
            }
            _ => Ok(()),
        };
        self.stream = stream;
        self.recorder = recorder;
        let (p, frame_kind) = made?;
        recorded?;
        if let Some(dir) = &self.save {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            io::write_rgb(dir.join("sent-left.png"), &p.sent.0)?;
            io::write_rgb(dir.join("sent-right.png"), &p.sent.1)?;
            stereolink_image::pfm::write(dir.join("sent-disparity.pfm"), &p.disparity)?;
        }
        // The report first: it goes ahead of the frame still in flight.
        let report_bytes = self.hand_report(&p.report, (pair_id, next.captured_us), report_as)?;
        let frame_bytes = p.frame_bytes.len();
        let stereo_prediction = matches!(
            container::parse(&p.frame_bytes, &Limits::default()),
            Ok((_, Body::StereoFrame(f))) if f.right.is_stereo()
        );
        self.uplink.frame(pair_id, p.frame_bytes)?;
        let (segment_ms, encode_ms, match_ms) = p.times_ms;
        let sent = Sent {
            frame_id: pair_id,
            frame_bytes,
            report_bytes,
            view_coding: self.cfg.coding.coding.name(),
            stereo_prediction,
            frame_kind,
            setting: p.setting,
            psnr_db: p.psnr_db,
            distance_m: p.report.target_distance_m,
            seconds: 0.0,
            report_seconds: None,
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
        self.waiting.insert(pair_id, waiting);
        Ok(())
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
                    tracing::warn!("ignored a reply from the peer (to command {})", r.id);
                    continue;
                }
                Err(e) => {
                    tracing::warn!("refused a message from the peer: {e}");
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
                Ok(()) => tracing::info!("command {id} ({}): done", command.name()),
                Err(why) => tracing::warn!("command {id} ({}): refused: {why}", command.name()),
            }
            self.uplink.reply(&Reply { id, result })?;
        }
        Ok(wanted)
    }

    /// Takes the ends of sends: a failure stops the sender, naming the
    /// message; a delivered message is counted; a frame whose two messages
    /// both ended is done.
    fn collect(
        &mut self,
        outcomes: Vec<Outcome>,
        on: &mut impl FnMut(Update),
    ) -> anyhow::Result<()> {
        for o in outcomes {
            let what = match o.kind {
                Kind::Frame => format!("sending frame {}", o.frame_id),
                Kind::Report => format!("sending the depth report of pair {}", o.frame_id),
                Kind::Reply => {
                    if let Ended::Failed(e) = o.ended {
                        tracing::warn!(
                            "the reply to command {} was not delivered: {e}",
                            o.frame_id
                        );
                    }
                    continue;
                }
            };
            self.link = o.link.to_string();
            let stats = match o.ended {
                Ended::Failed(e) => return Err(e).context(what),
                Ended::Superseded { sent } => {
                    if !sent {
                        // Reports wait for the air: frames give way.
                        self.starved_until = Some(Instant::now() + STARVED_HOLD);
                    }
                    None
                }
                Ended::Delivered(stats) => Some(stats),
            };
            let handed = match o.kind {
                Kind::Report => self.handed.remove(&o.frame_id),
                _ => None,
            };
            for c in [&mut self.total, &mut self.second] {
                match (o.kind, stats) {
                    (Kind::Report, Some(s)) => {
                        // Capture to hand-over, then hand-over to acknowledgement.
                        let latency = handed.map(|(handed_us, captured_us)| {
                            Duration::from_micros(handed_us.saturating_sub(captured_us)) + s.elapsed
                        });
                        c.rates.report(s.bytes as usize, latency);
                    }
                    (Kind::Report, None) => c.superseded += 1,
                    (_, Some(s)) => c.rates.frame(s.bytes as usize),
                    (_, None) => {}
                }
                c.retransmissions += stats.map_or(0, |s| s.retransmissions);
            }
            if let (Kind::Frame, Some(s), Some(pace)) = (o.kind, stats, self.pace.as_mut()) {
                pace.delivered(&s);
            }
            if let (Kind::Frame, Some(_), Some((encoder, _))) =
                (o.kind, stats, self.stream.as_mut())
            {
                encoder.acknowledge(o.frame_id);
            }
            let Some(w) = self.waiting.get_mut(&o.frame_id) else {
                continue;
            };
            match o.kind {
                Kind::Frame => w.frame = stats,
                _ => w.report = Some(stats),
            }
            w.sent.link = self.link.clone();
            if let (Some(f), Some(r)) = (w.frame, w.report) {
                if let Some(w) = self.waiting.remove(&o.frame_id) {
                    self.done(w.sent, f, r, on);
                }
            }
        }
        Ok(())
    }

    /// Completes a frame's record from how its two messages were delivered
    /// and hands it to `on`.
    fn done(
        &mut self,
        mut s: Sent,
        frame: SendStats,
        report: Option<SendStats>,
        on: &mut impl FnMut(Update),
    ) {
        s.seconds = frame.elapsed.as_secs_f64();
        s.report_seconds = report.map(|r| r.elapsed.as_secs_f64());
        s.goodput_bps = frame.goodput_bps();
        s.retransmissions = frame.retransmissions + report.map_or(0, |r| r.retransmissions);
        s.send_ms = s.seconds * 1e3;
        on(Update::Frame(&s));
        self.sent.push(s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(bytes: u64, ms: u64) -> SendStats {
        SendStats {
            bytes,
            segments: 1,
            retransmissions: 0,
            elapsed: Duration::from_millis(ms),
        }
    }

    #[test]
    fn a_frames_budget_follows_the_goodput_measured() {
        let mut pace = FramePace {
            interval: Duration::from_millis(500),
            goodput_bps: None,
        };
        assert_eq!(pace.budget(), None);
        // 4000 B in 1 s: 32 kb/s, so 2000 B in half a second.
        pace.delivered(&frame(4000, 1000));
        assert_eq!(pace.budget(), Some(2000));
        // The link slows to 16 kb/s: the average halves the step.
        pace.delivered(&frame(2000, 1000));
        assert_eq!(pace.budget(), Some(1500));
    }

    #[test]
    fn depth_takes_the_air_alone_when_reports_fill_half_of_it() {
        let t0 = Instant::now();
        let at = |ms| t0 + Duration::from_millis(ms);
        // 10 pairs a second; a report and its acknowledgement take 40 ms.
        let mut load = ReportLoad::new(Some(Duration::from_millis(40)));
        load.taken(at(0));
        assert!(load.holds_frames(), "before the rate is known");
        for i in 1..10 {
            load.taken(at(100 * i));
        }
        assert!((load.share().unwrap() - 0.4).abs() < 1e-3);
        assert!(!load.holds_frames());
        // The link collapses: 270 ms a report, 2.7 times the air there is.
        let mut slow = ReportLoad::new(Some(Duration::from_millis(270)));
        for i in 0..10 {
            slow.taken(at(100 * i));
        }
        assert!(slow.holds_frames());
        // Reports on a link of their own never hold frames back.
        let mut own = ReportLoad::new(None);
        own.taken(at(0));
        own.taken(at(1));
        assert_eq!(own.share(), None);
        assert!(!own.holds_frames());
    }

    #[test]
    fn only_a_too_small_budget_names_the_smallest_frame() {
        let e = anyhow::Error::from(CodecError::BudgetTooSmall {
            budget: 900,
            minimum: 1200,
        });
        assert_eq!(smallest_frame(&e), Some(1200));
        assert_eq!(smallest_frame(&anyhow::anyhow!("other")), None);
    }
}
