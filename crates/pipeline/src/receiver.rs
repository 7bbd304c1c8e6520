//! The board's receiver: decodes messages, rebuilds the pair, matches it
//! with WTA-SAD (as the paper's ARM board does), renders the 480x272 screen
//! and moves the axis by the reported distance.
//!
//! Only a message that decoded completely (CRC-32 over the link, CRC-32 of
//! the container body, every structural check) reaches the axis, and only
//! through a [`ValidatedDistance`]; a frame that fails is reported and
//! ignored. The WTA matcher and the screen keep their buffers between frames,
//! and the disparities stay integers from the matcher to the screen (the
//! board has no FPU).
//!
//! The board keeps its last frames as the references of predicted frames
//! ([`stereolink_codec::temporal`]); one whose reference it lacks is
//! rejected, and [`BoardReceiver::key_request`] asks the sender for a key
//! frame ([`crate::key_request`]).
//! A still pair (predicted, no block changed) that repeats the pair on the
//! screen is not matched again: it is that pair.
//!
//! With [`DisparitySource::Planes`] the board does not match: it rebuilds
//! the map from the decoded left labels and the frame's plane table
//! ([`crate::planetable`]); a frame without a table is rejected.
//!
//! An axis stop from the link (a Control command,
//! [`stereolink_codec::control`]) is the safety path: it stops the axis at
//! once and holds it, so that no later report moves it again until the
//! receiver restarts. The board takes no other command (segmentation is the
//! sender's).

use std::time::Instant;

use std::fmt::Write;

use anyhow::Context;

use stereolink_codec::container::{self, Body, FrameDecoder, FrameRef};
use stereolink_codec::control::{Command, Control};
use stereolink_codec::stereo::left_disparity_into;
use stereolink_codec::temporal::{RefId, References};
use stereolink_codec::{CodecError, Limits, Message, SegmentationKind, StereoFrame, View};
use stereolink_display::{
    anaglyph_into, anaglyph_labels_shown_into, Anaglyph, Screen, ScreenStatus, Sink,
};
use stereolink_image::synth::{synthesize, SynthSpec};
use stereolink_image::{DisparityMap, RgbImage};

use crate::key_request::KeyRequests;
use stereolink_robot::policy::{MotionPolicy, ValidatedDistance, Watchdog};
use stereolink_robot::{Axis, AxisError};
use stereolink_segment::segment;
use stereolink_stereo::wta::{
    levels_to_disparity, luma_labels_into, luma_samples_into, Levels, Samples, WtaMatcher,
    WtaParams, NO_DISPARITY,
};

/// What the receiver did with one message.
#[derive(Clone, Debug, serde::Serialize)]
pub enum Event {
    /// A pair was rebuilt, matched and shown.
    Frame {
        /// Frame id.
        frame_id: u32,
        /// Size of the message.
        bytes: usize,
        /// Time to decode, match and render.
        ms: f64,
    },
    /// A depth report moved (or could not move) the axis.
    Report {
        /// Frame id.
        frame_id: u32,
        /// Reported distance, metres.
        distance_m: f32,
        /// Commanded axis position, mm (None: the distance was not valid,
        /// or the axis is held).
        commanded_mm: Option<f64>,
        /// The axis is held by a stop command: reports no longer move it.
        held: bool,
    },
    /// The sender answered the board's request for a key frame.
    Answered {
        /// The request's id.
        id: u32,
        /// Done (a key frame follows), or why not.
        result: Result<(), String>,
    },
    /// A command from the link was obeyed or refused.
    Command {
        /// The command's id.
        id: u32,
        /// What it asked.
        command: String,
        /// Done, or why not.
        result: Result<(), String>,
    },
    /// A message was rejected.
    Rejected(String),
}

/// Where the board's disparity map comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum DisparitySource {
    /// WTA-SAD block matching on the rebuilt pair (the paper's board).
    #[default]
    Wta,
    /// The sender's plane table over the decoded left labels: no matching.
    Planes,
}

/// The receiver and its buffers: after the first frame of a size, a frame
/// is decoded, matched and rendered without allocating.
pub struct BoardReceiver {
    decoder: FrameDecoder,
    /// The last frames decoded, that predicted frames reference.
    references: References,
    /// A frame could not be decoded since the last key frame shown: the
    /// sender should send a key frame.
    needs_key: bool,
    /// The board's requests for a key frame.
    key_requests: KeyRequests,
    matcher: WtaMatcher,
    params: WtaParams,
    gray: (Samples, Samples),
    /// Scratch of the views' luma and anaglyph from their labels.
    luma_lut: Vec<u16>,
    label_pairs: Vec<u32>,
    levels: Levels,
    /// The map rebuilt from a plane table ([`DisparitySource::Planes`]).
    planes: DisparityMap,
    /// The sender's cell disparities for the pair shown, if it carried
    /// them or repeats a pair that did ([`stereolink_codec::stereo`]).
    carried: Vec<u16>,
    has_carried: bool,
    /// Frames shown with the sender's disparities.
    carried_frames: u32,
    screen: Screen,
    mode: Anaglyph,
    limits: Limits,
    /// The last 3-D view, kept to redraw the screen when the status changes
    /// (from labels, only the pixels the screen shows are computed).
    view: RgbImage,
    /// Whether a frame was shown (the decoder's views and `view` hold it).
    shown: bool,
    /// The frame shown.
    shown_id: Option<RefId>,
    /// The display, if any.
    pub sink: Option<Box<dyn Sink>>,
    /// The axis, if any.
    pub axis: Option<Box<dyn Axis>>,
    /// Motion limits.
    pub policy: MotionPolicy,
    /// Stops the axis when reports stop.
    pub watchdog: Watchdog,
    /// Status shown on the screen.
    pub status: ScreenStatus,
    /// Where the disparity map comes from.
    pub source: DisparitySource,
    /// A stop command holds the axis: reports no longer move it (the
    /// latch itself; `status.axis_held` only shows it).
    held: bool,
    /// The sender's time stamp of the last report applied: an older one
    /// (overtaken on the link, or replayed by a restarted sender's queue)
    /// is never applied after it.
    last_report_us: Option<u64>,
}

impl BoardReceiver {
    /// A receiver matching up to `max_disp` disparities with a `block`×`block` window.
    pub fn new(max_disp: usize, block: usize, watchdog: std::time::Duration) -> Self {
        BoardReceiver {
            decoder: FrameDecoder::default(),
            references: References::default(),
            needs_key: false,
            key_requests: KeyRequests::default(),
            matcher: WtaMatcher::new(),
            params: WtaParams {
                min_disp: 0,
                ndisp: max_disp + 1,
                block,
                // The board's fast setting: 8-bit gray, no min filter.
                gray_bits: 8,
                min_filter: 0,
                uniqueness: 0,
                subpixel: false,
            },
            gray: Default::default(),
            luma_lut: Vec::new(),
            label_pairs: Vec::new(),
            levels: Levels::default(),
            planes: DisparityMap::default(),
            carried: Vec::new(),
            has_carried: false,
            carried_frames: 0,
            screen: Screen::new(),
            mode: Anaglyph::Dubois,
            limits: Limits::default(),
            view: RgbImage::default(),
            shown: false,
            shown_id: None,
            sink: None,
            axis: None,
            policy: MotionPolicy::default(),
            watchdog: Watchdog::new(watchdog),
            status: ScreenStatus::default(),
            source: DisparitySource::default(),
            held: false,
            last_report_us: None,
        }
    }

    /// Matches with the portable kernel only, as a CPU without SIMD (the
    /// ARM9 board) does: same results, to measure what the board executes.
    pub fn portable_kernel(mut self) -> Self {
        self.matcher = WtaMatcher::portable();
        self
    }

    /// The last rebuilt pair, once a frame was shown (an indexed pair's
    /// colours are written on the first call after a frame: the board
    /// itself works on its labels).
    pub fn pair(&mut self) -> Option<(&RgbImage, &RgbImage)> {
        if !self.shown {
            return None;
        }
        self.decoder.expand_views();
        Some(self.decoder.views())
    }

    /// The last disparity map computed on the board (a new map: the
    /// board keeps integer disparities).
    pub fn disparity(&self) -> DisparityMap {
        match self.source {
            DisparitySource::Wta => levels_to_disparity(&self.levels),
            DisparitySource::Planes => self.planes.clone(),
        }
    }

    /// The current screen.
    pub fn screen(&self) -> &RgbImage {
        self.screen.image()
    }

    /// Handles one message from the link.
    pub fn handle(&mut self, bytes: &[u8]) -> Event {
        let start = Instant::now();
        match container::parse(bytes, &self.limits) {
            Err(e) => Event::Rejected(format!("message rejected: {e}")),
            Ok((header, Body::StereoFrame(frame))) => {
                let id = RefId {
                    frame_id: header.frame_id,
                    timestamp_us: header.timestamp_us,
                };
                match self.show_frame(id, &frame) {
                    Ok(()) => Event::Frame {
                        frame_id: header.frame_id,
                        bytes: bytes.len(),
                        ms: start.elapsed().as_secs_f64() * 1e3,
                    },
                    Err(e) => {
                        // What was held under this id is not what the
                        // sender believes delivered.
                        self.references.forget(header.frame_id);
                        self.needs_key = true;
                        Event::Rejected(format!("frame {} rejected: {e}", header.frame_id))
                    }
                }
            }
            Ok((header, Body::DepthReport(report))) => {
                if self
                    .last_report_us
                    .is_some_and(|last| header.timestamp_us < last)
                {
                    return Event::Rejected(format!(
                        "report of frame {} is older than the last one applied: not applied",
                        header.frame_id
                    ));
                }
                self.last_report_us = Some(header.timestamp_us);
                let d = report.target_distance_m;
                self.status.distance_m = d.is_finite().then_some(d as f64);
                let commanded = ValidatedDistance::new(d as f64).map(|v| self.policy.plan(v));
                if commanded.is_some() {
                    self.watchdog.feed(Instant::now());
                }
                let commanded = commanded.filter(|_| !self.held);
                if let (Some(m), Some(axis)) = (commanded, self.axis.as_mut()) {
                    if let Err(e) = axis.move_to(m.position_mm, m.speed_mm_s) {
                        return Event::Rejected(format!("axis: {e}"));
                    }
                }
                Event::Report {
                    frame_id: header.frame_id,
                    distance_m: d,
                    commanded_mm: commanded.map(|m| m.position_mm),
                    held: self.held,
                }
            }
            Ok((_, Body::Control(body))) => self.obey(body),
        }
    }

    /// Obeys a Control body: an axis stop stops the axis now and holds it;
    /// anything else is refused, with why.
    fn obey(&mut self, body: &[u8]) -> Event {
        let (id, command) = match Control::decode(body) {
            Ok(Control::Command { id, command }) => (id, command),
            Ok(Control::Reply(r)) if self.key_requests.answers(&r) => {
                return Event::Answered {
                    id: r.id,
                    result: r.result,
                }
            }
            Ok(Control::Reply(r)) => {
                return Event::Rejected(format!(
                    "a reply (to command {}) is not for the board",
                    r.id
                ))
            }
            Err(e) => return Event::Rejected(e.to_string()),
        };
        let result = match &command {
            Command::AxisStop => {
                self.held = true;
                self.status.axis_held = true;
                match self.axis.as_mut() {
                    Some(axis) => axis
                        .stop()
                        .map_err(|e| format!("the axis did not take the stop: {e}")),
                    None => Err("this receiver drives no axis".into()),
                }
            }
            other => Err(format!(
                "the board takes only an axis stop ({} is the sender's)",
                other.name()
            )),
        };
        Event::Command {
            id,
            command: command.name(),
            result,
        }
    }

    /// Whether a frame could not be decoded (a predicted frame's reference
    /// missing, or a corrupt frame) since the last key frame was shown: the
    /// sender should send a key frame next.
    pub fn needs_key(&self) -> bool {
        self.needs_key
    }

    /// A frame request for the sender (the whole message), when the board
    /// needs a key frame and has not asked within
    /// [`crate::key_request::ASK_AGAIN_AFTER`].
    pub fn key_request(&mut self, now: Instant) -> Option<Vec<u8>> {
        self.key_requests.due(self.needs_key, now)
    }

    /// Frames shown with the sender's disparities (stereo-predicted, or
    /// repeating one that was): their disparity was not matched here.
    pub fn carried_frames(&self) -> u32 {
        self.carried_frames
    }

    /// Key frames asked of the sender so far.
    pub fn key_requests(&self) -> u32 {
        self.key_requests.made()
    }

    /// Forgets the frames kept as references (a new session: a restarted
    /// sender's frames are not predicted from an earlier one's).
    pub fn reset_references(&mut self) {
        self.references.clear();
    }

    fn show_frame(&mut self, id: RefId, frame: &FrameRef) -> Result<(), CodecError> {
        let frame_id = id.frame_id;
        let (w, h) = (frame.width, frame.height);
        if self.params.ndisp > w {
            return Err(CodecError::Invalid(format!(
                "a {w} px wide frame is narrower than the disparity range"
            )));
        }
        self.decoder.decode_with(frame, &self.references)?;
        // The sender's disparities: carried by the frame, or by the pair a
        // still pair repeats.
        let carried = match self.decoder.stereo_disparities() {
            Some(d) => Some(d),
            None => frame
                .unchanged()
                .and_then(|r| self.references.disparities(r)),
        };
        self.carried.clear();
        self.carried.extend(carried.into_iter().flatten());
        self.has_carried = carried.is_some();
        let key = frame.references().next().is_none();
        // The pair is kept as a reference: segmented views as their
        // labels, others as their colours.
        match self.decoder.indexed_views() {
            Some(views) => self.references.keep_labels(id, views),
            None => {
                self.decoder.expand_views();
                self.references.keep(id, self.decoder.views());
            }
        }
        if self.has_carried {
            self.references.keep_disparities(id, &self.carried);
            self.carried_frames += 1;
        }
        if key {
            self.needs_key = false;
        }
        // A still pair (predicted, no block changed) from the pair on the
        // screen is that pair: its disparity and its 3-D view stand.
        let still = self.source == DisparitySource::Wta
            && self.shown
            && frame.unchanged().is_some_and(|r| Some(r) == self.shown_id);
        if !still {
            self.match_and_compose(frame)?;
        }
        self.shown = true;
        self.shown_id = Some(id);
        self.status.frame_id = frame_id;
        self.status.message.clear();
        // A lossy pair is named by its codec, a segmented one by its method.
        let what = match frame.left.lossy_codec() {
            _ if !key => "predicted",
            Some(c) => c.name(),
            None => frame.kind.name(),
        };
        let _ = write!(self.status.message, "{what} PAIR {w}X{h}");
        if let Some(axis) = self.axis.as_mut() {
            self.status.axis_mm = axis.position().ok();
        }
        self.refresh()
            .map_err(|e| CodecError::Invalid(format!("display: {e}")))
    }

    /// Matches the decoded pair (or rebuilds its map from the plane table)
    /// and composes its 3-D view.
    fn match_and_compose(&mut self, frame: &FrameRef) -> Result<(), CodecError> {
        let (w, h) = (frame.width, frame.height);
        // Indexed views (segmented: few colours) give their luma and their
        // anaglyph through the palettes, a lookup per pixel; other views
        // are matched and shown from their colours.
        let (left, right) = self.decoder.views();
        let indexed = self.decoder.indexed_views();
        let carried = self.has_carried.then_some(&self.carried[..]);
        match (self.source, carried) {
            // A stereo-predicted pair carries the sender's disparity: shown
            // as it is, no matching (the WTA is the fallback for pairs
            // without it).
            (DisparitySource::Wta, Some(carried)) => {
                left_disparity_into(carried, (w, h), NO_DISPARITY, &mut self.levels);
                let top = (self.params.min_disp + self.params.ndisp - 1) as u16;
                for l in self.levels.as_mut_slice() {
                    if *l != NO_DISPARITY {
                        *l = (*l).min(top);
                    }
                }
            }
            (DisparitySource::Wta, None) => {
                let bits = self.params.gray_bits;
                if let Some([(ll, lp), (rl, rp)]) = indexed {
                    luma_labels_into(ll, lp, bits, &mut self.luma_lut, &mut self.gray.0);
                    luma_labels_into(rl, rp, bits, &mut self.luma_lut, &mut self.gray.1);
                } else {
                    luma_samples_into(left, bits, &mut self.gray.0);
                    luma_samples_into(right, bits, &mut self.gray.1);
                }
                if self.levels.dims() != (w, h) {
                    self.levels.reset(w, h, 0);
                }
                self.matcher.compute_levels_into(
                    &self.gray.0,
                    &self.gray.1,
                    &self.params,
                    &mut self.levels,
                );
            }
            (DisparitySource::Planes, _) => {
                let (Some(table), Some(labels)) =
                    (frame.planes.as_deref(), self.decoder.left_labels(frame))
                else {
                    return Err(CodecError::Invalid(
                        "the frame has no plane table (send --algo planes)".into(),
                    ));
                };
                crate::planetable::rebuild_coded_into(labels, table, &mut self.planes)?;
            }
        }
        match indexed {
            // Only the pixels the screen's panel shows (the view is drawn
            // scaled down, and nothing else reads it).
            Some([l, r]) => anaglyph_labels_shown_into(
                l,
                r,
                self.mode,
                Screen::view_shown(w, h),
                &mut self.label_pairs,
                &mut self.view,
            ),
            None => anaglyph_into(left, right, self.mode, &mut self.view),
        }
        Ok(())
    }

    /// Redraws the screen with the current status (distance, axis, link) and shows it.
    pub fn refresh(&mut self) -> std::io::Result<()> {
        if !self.shown {
            return Ok(());
        }
        let (min, max) = (
            self.params.min_disp,
            self.params.min_disp + self.params.ndisp - 1,
        );
        let screen = match self.source {
            DisparitySource::Wta => self.screen.render_levels(
                &self.view,
                &self.levels,
                NO_DISPARITY,
                (min as u16, max as u16),
                &self.status,
            ),
            DisparitySource::Planes => self.screen.render(
                &self.view,
                &self.planes,
                min as f32,
                max as f32,
                &self.status,
            ),
        };
        match self.sink.as_mut() {
            Some(sink) => sink.show(screen, &self.status),
            None => Ok(()),
        }
    }

    /// Reads the axis and redraws the screen when its position, to the
    /// 0.1 mm the status line shows, changed: called while waiting for
    /// messages, the screen follows the axis as it moves and shows where
    /// it settles.
    pub fn follow_axis(&mut self) -> std::io::Result<()> {
        let Some(axis) = self.axis.as_mut() else {
            return Ok(());
        };
        let now = axis.position().ok();
        let shown = |mm: Option<f64>| mm.map(|a| (a * 10.0).round() as i64);
        if shown(now) != shown(self.status.axis_mm) {
            self.status.axis_mm = now;
            self.refresh()?;
        }
        Ok(())
    }

    /// Stops the axis when the watchdog trips at `now` (no valid report
    /// for its timeout); returns true when it stopped it. Call it while
    /// waiting for messages too: a silent link is what it guards against.
    /// It stops the axis once per silence (a valid report re-arms it).
    ///
    /// # Errors
    /// If the axis did not take the stop; the next check tries again.
    pub fn check_watchdog(&mut self, now: Instant) -> Result<bool, AxisError> {
        let Some(axis) = self.axis.as_mut() else {
            return Ok(false);
        };
        if !self.watchdog.trip(now) {
            return Ok(false);
        }
        axis.stop().inspect_err(|_| self.watchdog.rearm())?;
        Ok(true)
    }

    /// The axis once the messages end: it finishes the move the last fresh
    /// report commanded (`finish`: the run ended as asked), or, the link
    /// having gone quiet or failed and left no fresh data, stops where it
    /// is. `None` without an axis.
    pub fn settle_axis(&mut self, finish: bool) -> Option<AxisEnd> {
        let axis = self.axis.as_mut()?;
        let mut stopped = false;
        let position = (|| {
            if finish {
                let pos = stereolink_robot::wait_until_idle(axis.as_mut(), 6000)?;
                return pos.context("the axis is still moving");
            }
            if axis.is_moving()? {
                axis.stop()?;
                stopped = true;
            }
            Ok(axis.position()?)
        })();
        Some(AxisEnd {
            position_mm: position,
            stopped,
        })
    }
}

/// The axis after the messages ended ([`BoardReceiver::settle_axis`]).
#[derive(Debug)]
pub struct AxisEnd {
    /// Where it settled, or why that is not known.
    pub position_mm: anyhow::Result<f64>,
    /// It was still moving on data no longer fresh, so it was stopped.
    pub stopped: bool,
}

/// The StereoFrame message of a synthetic scene (`synth`'s generator, its
/// views segmented with k-means, 3 levels, seed 1): what the board's tests
/// and its instruction budget feed the receiver.
pub fn synthetic_frame(spec: &SynthSpec) -> anyhow::Result<Vec<u8>> {
    let scene = synthesize(spec)?;
    let method = "kmeans".parse()?;
    let view = |img| anyhow::Ok(View::Indexed(segment(img, &method, 3, 1)?.image));
    let frame = StereoFrame {
        kind: SegmentationKind::KMeans,
        levels: 3,
        params: String::new(),
        thresholds: None,
        calibration: None,
        left: view(&scene.left)?,
        right: view(&scene.right)?,
        planes: None,
    };
    Ok(container::encode(
        &Message::StereoFrame(Box::new(frame)),
        1,
        0,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A report moved the axis: the status line follows it while it moves,
    /// and the screen shows where it settled.
    #[test]
    fn the_screen_follows_the_axis_until_it_settles() {
        let bytes = synthetic_frame(&SynthSpec {
            width: 96,
            height: 64,
            max_disp: 16,
            seed: 2,
        })
        .unwrap();
        let mut board = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        board.axis = Some(stereolink_robot::open_axis("sim").unwrap());
        assert!(matches!(board.handle(&bytes), Event::Frame { .. }));
        let first = board.screen().clone();
        board.axis.as_mut().unwrap().move_to(250.0, 50.0).unwrap();
        let mut shown = Vec::new();
        while board.axis.as_mut().unwrap().is_moving().unwrap() {
            board.follow_axis().unwrap();
            shown.push(board.status.axis_mm);
            assert!(shown.len() < 1_000_000, "the axis never settles");
        }
        board.follow_axis().unwrap();
        let settled = board.axis.as_mut().unwrap().position().unwrap();
        let tenths = |mm: f64| (mm * 10.0).round();
        assert_eq!(board.status.axis_mm.map(tenths), Some(tenths(settled)));
        assert!(tenths(settled) > 2000.0, "moved to {settled} mm");
        assert!(
            shown.windows(2).filter(|w| w[0] != w[1]).count() > 10,
            "the status line moved with the axis"
        );
        assert_ne!(board.screen(), &first);
    }

    /// A lossy pair (the board's budget example's frames) is decoded,
    /// matched and shown, and the status line names its codec.
    #[test]
    fn lossy_pairs_are_shown() {
        for (codec, bytes) in [
            (
                "jpeg",
                &include_bytes!("../examples/lossy/cones-320x240-jpeg.slnk")[..],
            ),
            (
                "webp",
                &include_bytes!("../examples/lossy/cones-320x240-webp.slnk")[..],
            ),
        ] {
            let mut board = BoardReceiver::new(31, 9, std::time::Duration::from_secs(10));
            let blank = board.screen().clone();
            assert!(
                matches!(board.handle(bytes), Event::Frame { .. }),
                "{codec}"
            );
            assert_eq!(board.status.message, format!("{codec} PAIR 320X240"));
            let Ok((_, Message::StereoFrame(f))) = container::decode(bytes, &Limits::default())
            else {
                panic!("{codec}: not a frame")
            };
            let (l, r) = board.pair().unwrap();
            assert_eq!((l, r), (&f.left.to_rgb(), &f.right.to_rgb()));
            assert_ne!(board.screen(), &blank);
            let d = board.disparity();
            let valid = d.as_slice().iter().filter(|v| v.is_finite()).count();
            assert!(
                valid > d.len() / 2,
                "{codec}: {valid} of {} matched",
                d.len()
            );
        }
    }

    /// A stereo-predicted pair's disparity is the one it carries, mapped
    /// onto the left view: not the WTA's, which the same pair without it
    /// gets.
    #[test]
    fn a_stereo_predicted_pair_shows_the_disparity_it_carries() {
        let bytes = &include_bytes!("../examples/lossy/cones-320x240-webp-stereo.slnk")[..];
        let mut board = BoardReceiver::new(31, 9, std::time::Duration::from_secs(10));
        assert!(matches!(board.handle(bytes), Event::Frame { .. }));
        let Ok((_, Message::StereoFrame(f))) = container::decode(bytes, &Limits::default()) else {
            panic!("not a frame")
        };
        let View::Stereo(right) = &f.right else {
            panic!("the right view is not stereo-predicted")
        };
        assert_eq!(
            board.pair().unwrap(),
            (&f.left.to_rgb(), &right.image().clone())
        );
        let mut want = Levels::default();
        left_disparity_into(right.disparities(), (320, 240), NO_DISPARITY, &mut want);
        for l in want.as_mut_slice() {
            *l = (*l).min(31);
        }
        assert_eq!(board.disparity(), levels_to_disparity(&want));
        // The same views without the disparities (the right one lossless):
        // the WTA's map, another one.
        let plain = StereoFrame {
            right: View::Rgb(right.image().clone()),
            ..*f.clone()
        };
        let plain = container::encode(&Message::StereoFrame(Box::new(plain)), 2, 2);
        let mut wta = BoardReceiver::new(31, 9, std::time::Duration::from_secs(10));
        assert!(matches!(wta.handle(&plain), Event::Frame { .. }));
        assert_eq!(wta.pair(), board.pair());
        assert_ne!(wta.disparity(), board.disparity());
    }

    /// The watchdog stops a moving axis without any message arriving, once
    /// per silence.
    #[test]
    fn the_watchdog_stops_the_axis_when_no_report_arrives() {
        let mut board = BoardReceiver::new(15, 5, std::time::Duration::from_millis(1));
        board.axis = Some(stereolink_robot::open_axis("sim").unwrap());
        board.axis.as_mut().unwrap().move_to(250.0, 50.0).unwrap();
        let later = Instant::now() + std::time::Duration::from_millis(5);
        assert!(
            board.check_watchdog(later).unwrap(),
            "no report for longer than the watchdog"
        );
        assert!(!board.axis.as_mut().unwrap().is_moving().unwrap());
        assert!(
            !board.check_watchdog(later).unwrap(),
            "stopped once per silence"
        );
    }

    /// A report older than the last one applied (by the sender's time
    /// stamp) is refused and moves nothing; a newer one moves the axis.
    #[test]
    fn a_report_older_than_the_last_applied_is_never_applied() {
        use stereolink_codec::DepthReport;
        let report = |frame_id, distance_m, at_us| {
            let r = DepthReport {
                target_distance_m: distance_m,
                target_region: [0, 0, 8, 8],
                levels: Vec::new(),
                histogram: Vec::new(),
            };
            container::encode(&Message::DepthReport(r), frame_id, at_us)
        };
        let mut board = BoardReceiver::new(15, 5, std::time::Duration::from_secs(10));
        board.axis = Some(stereolink_robot::open_axis("sim").unwrap());
        let applied = |e: &Event| {
            matches!(
                e,
                Event::Report {
                    commanded_mm: Some(_),
                    ..
                }
            )
        };
        assert!(applied(&board.handle(&report(2, 0.5, 2_000_000))));
        let stale = board.handle(&report(1, 0.9, 1_000_000));
        assert!(
            matches!(&stale, Event::Rejected(why) if why.contains("older")),
            "{stale:?}"
        );
        let target = board
            .policy
            .plan(ValidatedDistance::new(0.5).unwrap())
            .position_mm;
        let stopped_at =
            stereolink_robot::wait_until_idle(board.axis.as_mut().unwrap().as_mut(), 100_000)
                .unwrap()
                .unwrap();
        assert!(
            (stopped_at - target).abs() < 1.0,
            "{stopped_at} against {target}"
        );
        assert!(applied(&board.handle(&report(3, 0.6, 3_000_000))));
    }
}
