//! One station's thread: its link endpoint (its own ARQ session and, with
//! keys, its own secure channel), the board's receiver to rebuild its
//! frames, and the commands that go down to it. It turns what arrives into
//! [`Up`] events for the bridge; it never touches MQTT.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use stereolink_codec::container::{self, Body};
use stereolink_codec::control::{unix_us, Command, Control};
use stereolink_codec::Limits;
use stereolink_display::{anaglyph_into, Anaglyph};
use stereolink_image::colormap::colorize;
use stereolink_image::io::encode_png_rgb;
use stereolink_image::{Calibration, RgbImage};
use stereolink_link::arq::Config;
use stereolink_link::endpoint::{Endpoint, Lane, LinkError};
use stereolink_link::secure::{Keys, SecureConfig};
use stereolink_link::spec::{self, LinkSpec};
use stereolink_pipeline::receiver::{BoardReceiver, Event};
use stereolink_pipeline::record::{RecordError, Recorder, UNCALIBRATED};

/// A station as the gateway knows it.
#[derive(Clone, Debug)]
pub struct StationConfig {
    /// Its name: the topic level under the prefix.
    pub name: String,
    /// Its link (one UDP peer or radio address).
    pub link: LinkSpec,
    /// The link as the user wrote it (for `bridge/stations`).
    pub link_text: String,
    /// The link keys (this gateway's private key, the station's public key).
    pub keys: Option<Keys>,
    /// Largest disparity the gateway searches when it rebuilds a frame.
    pub max_disp: usize,
    /// How often the link statistics go up.
    pub stats_every: Duration,
    /// Rebuild and publish the images of at most one frame per this
    /// interval (metadata goes up for every frame).
    pub images_every: Duration,
    /// `--record FILE.mcap`, shared by the stations: each records its
    /// depth reports, the frames it rebuilds and its link statistics under
    /// `/NAME/...`.
    pub recorder: Option<Arc<Mutex<Recorder>>>,
}

/// Writes into the recording, if any, as station `cfg`'s; says why it
/// could not.
fn record(
    cfg: &StationConfig,
    write: impl FnOnce(&mut Recorder) -> Result<(), RecordError>,
) -> Option<String> {
    let mut recorder = cfg
        .recorder
        .as_ref()?
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    write(recorder.station(&cfg.name))
        .err()
        .map(|e| e.to_string())
}

/// What a station thread tells the bridge.
#[derive(Debug)]
pub enum Up {
    /// A message arrived and decoded: the station is alive.
    Heard(usize),
    /// A depth report, as its JSON payload.
    Depth {
        /// The station's index in the gateway's list.
        station: usize,
        /// The report's frame id.
        frame_id: u32,
        /// The JSON payload.
        payload: Value,
    },
    /// A frame's metadata and, when rebuilt, its images as PNG.
    Frame {
        /// The station's index in the gateway's list.
        station: usize,
        /// The frame's metadata, as its JSON payload.
        meta: Value,
        /// The rebuilt frame's images, when it was rebuilt.
        images: Option<FrameImages>,
    },
    /// The link statistics, as their JSON payload.
    Link {
        /// The station's index in the gateway's list.
        station: usize,
        /// The JSON payload.
        payload: Value,
    },
    /// How a command's delivery ended.
    Done {
        /// The station's index in the gateway's list.
        station: usize,
        /// The command.
        request: Request,
        /// Delivered (after this long), or why not.
        result: Result<Duration, String>,
    },
    /// The station's reply to a delivered command: done, or refused and why.
    Acted {
        /// The station's index in the gateway's list.
        station: usize,
        /// The command it answers.
        request: Request,
        /// Done, or refused with the reason.
        result: Result<(), String>,
    },
    /// Something worth a line on stderr.
    Notice {
        /// The station's index in the gateway's list.
        station: usize,
        /// The line.
        text: String,
    },
}

/// The PNGs of one rebuilt frame.
#[derive(Debug)]
pub struct FrameImages {
    /// The rebuilt left view.
    pub left: Vec<u8>,
    /// The 3-D view (Dubois red-cyan anaglyph).
    pub view3d: Vec<u8>,
    /// The gateway's disparity map, turbo colours.
    pub disparity: Vec<u8>,
}

/// A command on its way to a station, with what the response echoes.
#[derive(Clone, Debug)]
pub struct Request {
    /// The command.
    pub command: Command,
    /// The client's `transaction` field, if any.
    pub transaction: Option<Value>,
    /// MQTT 5: the response topic and correlation data it came with.
    pub reply: Option<crate::session::Reply>,
    /// When the gateway took it.
    pub at: Instant,
}

/// The longest a command waits for the station's link before it fails.
const COMMAND_DEADLINE: Duration = Duration::from_secs(5);

/// Counters behind `<station>/link`.
#[derive(Default)]
struct Counters {
    messages: u64,
    bytes: u64,
    depth_reports: u64,
    frames: u64,
    /// Messages that arrived whole but failed to decode.
    rejected_codec: u64,
    /// Messages the link gave up on (reassembly timeout, corruption).
    link_failures: u64,
    commands_sent: u64,
    commands_failed: u64,
}

/// Runs one station until `stop`; errors opening the link end the thread
/// after saying why.
pub fn run(
    index: usize,
    cfg: StationConfig,
    up: Sender<Up>,
    down: Receiver<Request>,
    stop: Arc<AtomicBool>,
) {
    let notices = up.clone();
    let say = move |text: String| {
        let _ = notices.send(Up::Notice {
            station: index,
            text,
        });
    };
    // A command that the station does not take within the deadline fails
    // (and frees the lane for the next one); receiving is unchanged.
    let open = |t: Box<dyn stereolink_link::transport::Transport>| {
        let mut arq = Config::for_mtu(t.mtu());
        arq.deadline = COMMAND_DEADLINE.as_micros() as u64;
        Endpoint::with_config(t, arq)
    };
    let mut ep = match spec::open(&cfg.link).and_then(open) {
        Ok(ep) => ep,
        Err(e) => return say(format!("cannot open its link: {e}")),
    };
    if let Some(keys) = cfg.keys.clone() {
        ep = ep.with_keys(keys, SecureConfig::default());
    }
    let mut st = Station {
        index,
        board: BoardReceiver::new(cfg.max_disp, 9, Duration::from_secs(3600)),
        limits: Limits::default(),
        counters: Counters::default(),
        view3d: RgbImage::default(),
        last_images: None,
        cfg,
        up,
        delivered: VecDeque::new(),
        in_flight: None,
        early: None,
    };
    let mut waiting: VecDeque<Request> = Default::default();
    let mut in_flight: Option<(u32, Request)> = None;
    let mut next_id = 1u32;
    let (mut window_start, mut window_bytes) = (Instant::now(), 0u64);
    while !stop.load(Ordering::Relaxed) {
        waiting.extend(down.try_iter());
        if in_flight.is_none() {
            if let Some(req) = waiting.pop_front() {
                let msg = req.command.message(next_id);
                next_id = next_id.wrapping_add(1);
                let id = next_id.wrapping_sub(1);
                match ep.submit(Lane::Urgent, &msg) {
                    Ok(()) => {
                        // Awaited from now: the reply may overtake the ACK.
                        st.awaiting_reply(id, req.clone());
                        in_flight = Some((id, req));
                    }
                    Err(e) => st.done(req, Err(format!("the link refused it: {e}"))),
                }
            }
        }
        st.in_flight = in_flight.as_ref().map(|(id, _)| *id);
        let got = if let Some((_, req)) = in_flight.as_ref() {
            // Drive the command's send (this also takes in segments).
            let ended = match ep.poll_sends(Duration::from_millis(5)) {
                Ok(ended) => ended,
                Err(e) => vec![(Lane::Urgent, Err(e))],
            };
            if let Some((_, result)) = ended.into_iter().find(|(l, _)| *l == Lane::Urgent) {
                let (id, req) = in_flight.take().expect("a command in flight");
                if result.is_ok() && req.command == Command::FrameRequest {
                    // The frame asked for is rebuilt, whatever the interval.
                    st.last_images = None;
                }
                let r = result
                    .map(|_| req.at.elapsed())
                    .map_err(|e| format!("not delivered: {e}"));
                st.settled(id, req, r);
            } else if req.at.elapsed() > COMMAND_DEADLINE * 3 {
                // The ARQ deadline ends it first; this is a backstop.
                let (id, req) = in_flight.take().expect("a command in flight");
                st.settled(id, req, Err("not delivered in time".into()));
            }
            ep.recv_message(Duration::ZERO)
        } else {
            ep.recv_message(Duration::from_millis(20))
        };
        match got {
            Ok(msg) => {
                window_bytes += msg.len() as u64;
                st.handle(&msg, &ep);
            }
            Err(LinkError::Timeout) => {}
            Err(LinkError::Arq(e)) => {
                st.counters.link_failures += 1;
                say(format!("a message was lost on the link: {e}"));
            }
            Err(e) => {
                say(format!("link error: {e}"));
                std::thread::sleep(Duration::from_millis(100));
            }
        }
        if window_start.elapsed() >= st.cfg.stats_every {
            let secs = window_start.elapsed().as_secs_f64();
            st.stats(&ep, window_bytes as f64 * 8.0 / secs);
            (window_start, window_bytes) = (Instant::now(), 0);
        }
    }
    // Answer the station's late retransmissions a moment.
    let _ = ep.linger(Duration::from_millis(100));
}

/// The link quality that goes with each report: the radio's signal
/// strength (802.15.4 RX frames carry it; none on UDP), the duplicate
/// segments the ARQ dropped (retransmissions seen) and the damaged frames.
fn quality(ep: &Endpoint) -> Value {
    let s = ep.link_stats();
    json!({
        "rssi_dbm": s.rssi_dbm,
        "retransmissions": ep.duplicates(),
        "retransmission_rate": ep.duplicate_rate(),
        "damaged": s.damaged,
    })
}

struct Station {
    index: usize,
    cfg: StationConfig,
    board: BoardReceiver,
    limits: Limits,
    counters: Counters,
    view3d: RgbImage,
    last_images: Option<Instant>,
    up: Sender<Up>,
    /// Commands sent whose reply has not come, by id, oldest first.
    delivered: VecDeque<(u32, Request)>,
    /// The id of the command whose delivery is not settled yet.
    in_flight: Option<u32>,
    /// Its reply, if it came first (held to keep the responses in order).
    early: Option<(u32, Up)>,
}

/// The most delivered commands kept for their replies (a station that
/// never replies, as an older build, costs no more than this).
const AWAITING_REPLIES: usize = 32;

impl Station {
    fn send(&self, e: Up) {
        let _ = self.up.send(e);
    }

    fn done(&mut self, request: Request, result: Result<Duration, String>) {
        match result {
            Ok(_) => self.counters.commands_sent += 1,
            Err(_) => self.counters.commands_failed += 1,
        }
        self.send(Up::Done {
            station: self.index,
            request,
            result,
        });
    }

    /// The delivery of command `id` ended; a reply that overtook its ACK
    /// goes up after it.
    fn settled(&mut self, id: u32, request: Request, result: Result<Duration, String>) {
        self.in_flight = None;
        self.done(request, result);
        if let Some((_, acted)) = self.early.take_if(|e| e.0 == id) {
            self.send(acted);
        }
    }

    fn awaiting_reply(&mut self, id: u32, request: Request) {
        if self.delivered.len() == AWAITING_REPLIES {
            self.delivered.pop_front();
        }
        self.delivered.push_back((id, request));
    }

    /// A Control body from the station: the reply to a command delivered.
    fn replied(&mut self, body: &[u8]) {
        let text = match Control::decode(body) {
            Ok(Control::Reply(r)) => match self.delivered.iter().position(|(id, _)| *id == r.id) {
                Some(i) => {
                    let (id, request) = self.delivered.remove(i).expect("found");
                    let acted = Up::Acted {
                        station: self.index,
                        request,
                        result: r.result,
                    };
                    return match self.in_flight == Some(id) {
                        true => self.early = Some((id, acted)),
                        false => self.send(acted),
                    };
                }
                None => format!("a reply to command {}, which is not awaited", r.id),
            },
            Ok(Control::Command { command, .. }) => {
                format!("ignored a command from the station ({})", command.name())
            }
            Err(e) => format!("refused a control message from the station: {e}"),
        };
        self.send(Up::Notice {
            station: self.index,
            text,
        });
    }

    fn handle(&mut self, msg: &[u8], ep: &Endpoint) {
        let received_us = unix_us();
        let (header, body) = match container::parse(msg, &self.limits) {
            Ok(p) => p,
            Err(e) => {
                self.counters.rejected_codec += 1;
                return self.send(Up::Notice {
                    station: self.index,
                    text: format!("message rejected: {e}"),
                });
            }
        };
        self.counters.messages += 1;
        self.counters.bytes += msg.len() as u64;
        self.send(Up::Heard(self.index));
        match body {
            Body::DepthReport(r) => {
                self.counters.depth_reports += 1;
                self.said(record(&self.cfg, |rec| rec.report(header.timestamp_us, &r)));
                let finite = |x: f32| (x.is_finite() && x > 0.0).then_some(x);
                let payload = json!({
                    "frame_id": header.frame_id,
                    "distance_m": finite(r.target_distance_m),
                    "region": r.target_region,
                    "levels": r.levels.iter().map(|l| json!({
                        "disparity_px": l.disparity,
                        "distance_m": finite(l.distance_m),
                        "share": l.share,
                    })).collect::<Vec<_>>(),
                    "time_us": header.timestamp_us,
                    "received_us": received_us,
                    "link": quality(ep),
                });
                self.send(Up::Depth {
                    station: self.index,
                    frame_id: header.frame_id,
                    payload,
                });
            }
            Body::StereoFrame(f) => {
                self.counters.frames += 1;
                let mut meta = json!({
                    "frame_id": header.frame_id,
                    "width": f.width,
                    "height": f.height,
                    "segmentation": f.kind.name(),
                    "levels": f.levels,
                    "bytes": msg.len(),
                    "planes": f.planes.is_some(),
                    "time_us": header.timestamp_us,
                    "received_us": received_us,
                });
                let due = self
                    .last_images
                    .is_none_or(|t| t.elapsed() >= self.cfg.images_every);
                let images = if due {
                    self.last_images = Some(Instant::now());
                    self.rebuild(msg, (header.timestamp_us, f.calibration), &mut meta)
                } else {
                    None
                };
                meta["images"] = json!(images.is_some());
                self.send(Up::Frame {
                    station: self.index,
                    meta,
                    images,
                });
            }
            Body::Control(c) => self.replied(c),
        }
    }

    /// Says why the recording could not be written, if it could not.
    fn said(&self, why: Option<String>) {
        if let Some(text) = why {
            self.send(Up::Notice {
                station: self.index,
                text,
            });
        }
    }

    /// Rebuilds the pair, matches it as the board does and encodes the
    /// PNGs; records the views and the disparity with the frame's capture
    /// time stamp and calibration.
    fn rebuild(
        &mut self,
        msg: &[u8],
        (stamp_us, calib): (u64, Option<Calibration>),
        meta: &mut Value,
    ) -> Option<FrameImages> {
        match self.board.handle(msg) {
            Event::Frame { ms, .. } => {
                let map = self.board.disparity();
                let disparity = colorize(&map, 0.0, self.cfg.max_disp as f32);
                let (l, r) = self.board.pair()?;
                let c = calib.unwrap_or(UNCALIBRATED);
                let why = record(&self.cfg, |rec| {
                    rec.views(stamp_us, (l, r), &c)?;
                    rec.disparity(stamp_us, &map, &c)
                });
                anaglyph_into(l, r, Anaglyph::Dubois, &mut self.view3d);
                let left = encode_png_rgb(l);
                self.said(why);
                meta["rebuild_ms"] = json!((ms * 10.0).round() / 10.0);
                Some(FrameImages {
                    left,
                    view3d: encode_png_rgb(&self.view3d),
                    disparity: encode_png_rgb(&disparity),
                })
            }
            Event::Rejected(why) => {
                self.counters.rejected_codec += 1;
                meta["rejected"] = json!(why);
                None
            }
            Event::Report { .. } | Event::Command { .. } | Event::Answered { .. } => None,
        }
    }

    fn stats(&mut self, ep: &Endpoint, goodput_bps: f64) {
        let link = ep.link_stats();
        let c = &self.counters;
        let secure = ep.rejections().map(|r| {
            json!({
                "bad_tag": r.bad_tag,
                "replay": r.replay,
                "unknown_session": r.unknown_session,
                "handshake": r.handshake,
            })
        });
        let payload = json!({
            "goodput_bps": goodput_bps.round(),
            "messages": c.messages,
            "bytes": c.bytes,
            "depth_reports": c.depth_reports,
            "frames": c.frames,
            "retransmissions": ep.duplicates(),
            "retransmission_rate": ep.duplicate_rate(),
            "segments": ep.segments_received(),
            "damaged": link.damaged,
            "rssi_dbm": link.rssi_dbm,
            "rejected": {
                "decode": c.rejected_codec,
                "link": c.link_failures,
                "secure": secure,
            },
            "secured": secure.is_some(),
            "commands": { "delivered": c.commands_sent, "failed": c.commands_failed },
            "link_description": ep.describe(),
        });
        self.said(record(&self.cfg, |rec| {
            rec.link(unix_us(), "stereolink gateway: link", &payload)
        }));
        self.send(Up::Link {
            station: self.index,
            payload,
        });
    }
}
