//! The sender's link in a thread of its own, so that preparing the next
//! pair never stops the link: frames go on the bulk lane one at a time, and
//! each depth report on the urgent lane, ahead of the fragments of the frame
//! still in flight. The robot's reports then wait for no 30 kB frame, and
//! the link stays busy while the next pair is segmented and matched. A
//! newer report replaces one waiting for the urgent lane, and overtakes
//! one in flight once that one has had the time to leave the radio (a few
//! packet times), without waiting for its acknowledgement: the robot acts
//! on the latest distance, and on a slow radio a report's round trip is
//! longer than the camera's period. The radio then never holds more than
//! one report, so on a link too slow for every report the newest goes as
//! fast as the air allows instead of queueing. A replaced report ends
//! [`Ended::Superseded`], never counted delivered, though the peer may
//! have had it. A report replaced while still waiting says the air carries
//! reports slower than the camera makes them: the send loop then starts no
//! new frame, so that what air there is goes to depth. With
//! a second link (the paper's two radio pairs, `send --report-link`) the
//! reports go over that one instead.
//!
//! The thread also takes what the peer sends, busy or idle: Control
//! messages (commands from a gateway, [`stereolink_codec::control`]) come
//! back to the send loop through [`Uplink::incoming`], and its replies go
//! out on the urgent lane, as the reports do. With keys, only what the paired peer
//! sealed gets this far (the secure layer refuses and counts the rest).

use std::collections::VecDeque;
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::Context;
use stereolink_codec::control::{Control, ControlError, Reply};
use stereolink_link::endpoint::{Endpoint, Lane, LinkError, SendStats};
use stereolink_link::pacing::PacingConfig;
use stereolink_link::transport::LinkStats;

/// What a message carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A StereoFrame, on the bulk lane.
    Frame,
    /// A DepthReport, on the urgent lane.
    Report,
    /// A reply to a command, on the urgent lane.
    Reply,
}

/// A message from the peer, read as a Control body (or why it is not one).
pub type Incoming = Result<Control, ControlError>;

/// How one message's send ended.
#[derive(Debug)]
pub struct Outcome {
    /// Which message it was.
    pub kind: Kind,
    /// The frame's id (a reply's: the id of the command it answers).
    pub frame_id: u32,
    /// Delivered (with what the send cost), replaced, or why it failed.
    pub ended: Ended,
    /// The link's statistics when it ended.
    pub link: LinkStats,
}

/// How a message left the link thread.
#[derive(Debug)]
pub enum Ended {
    /// The peer acknowledged it, at this cost.
    Delivered(SendStats),
    /// A newer report took its place before its acknowledgement: in flight
    /// (`sent`: the peer may have it), or still waiting for the lane (the
    /// air carries reports slower than they come).
    Superseded {
        /// It had gone on the link.
        sent: bool,
    },
    /// The link gave up on it.
    Failed(LinkError),
}

struct Job {
    kind: Kind,
    frame_id: u32,
    bytes: Vec<u8>,
    /// A newer report may take this report's place.
    replaceable: bool,
}

/// The link thread and its queues.
pub struct Uplink {
    jobs: Option<SyncSender<Job>>,
    outcomes: Receiver<Outcome>,
    incoming: Receiver<Incoming>,
    thread: Option<JoinHandle<anyhow::Result<()>>>,
    /// Frames handed over whose outcome has not come back.
    frames_in_flight: usize,
    /// Outcomes taken while waiting, not yet handed out.
    taken: VecDeque<Outcome>,
    /// What a report costs the link, once the thread has opened its
    /// endpoints.
    room: Receiver<ReportRoom>,
}

/// What one depth report costs the link.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReportRoom {
    /// The largest report that crosses in one radio packet, with the
    /// secure layer's overhead ([`Endpoint::one_packet_message`]).
    pub bytes: usize,
    /// The air a report and its acknowledgement take from the frames'
    /// link: two packet times; none when the reports have a link of their
    /// own, or the transport does not say its packet time.
    pub frames_air: Option<Duration>,
}

/// How long the link thread answers the peer's late retransmissions after
/// the last message.
const LINGER: Duration = Duration::from_millis(300);
const TICK: Duration = Duration::from_millis(5);
/// How long the idle link thread waits for the peer before it looks at
/// its queue again (a report handed over waits at most this long).
const IDLE_WAIT: Duration = Duration::from_millis(5);

impl Uplink {
    /// Starts the link thread; `make` builds the endpoints there (an
    /// endpoint with callbacks does not move between threads): the one for
    /// frames and, if any, a second one for the reports.
    pub fn start(
        make: impl FnOnce() -> anyhow::Result<(Endpoint, Option<Endpoint>)> + Send + 'static,
    ) -> Self {
        let (jobs, job_rx) = mpsc::sync_channel::<Job>(8);
        let (done_tx, outcomes) = mpsc::channel();
        let (incoming_tx, incoming) = mpsc::channel();
        let (room_tx, room) = mpsc::sync_channel(1);
        let thread = std::thread::spawn(move || {
            let (frames, reports) = make()?;
            let room = ReportRoom {
                bytes: reports.as_ref().unwrap_or(&frames).one_packet_message(),
                frames_air: match reports {
                    Some(_) => None,
                    None => frames.packet_time().map(|t| t * 2),
                },
            };
            let _ = room_tx.send(room);
            run(frames, reports, job_rx, (done_tx, incoming_tx))
        });
        Uplink {
            jobs: Some(jobs),
            outcomes,
            incoming,
            thread: Some(thread),
            frames_in_flight: 0,
            taken: VecDeque::new(),
            room,
        }
    }

    /// What a report costs the link (the reports' link for its size);
    /// waits for the link thread to open its links.
    pub fn report_room(&mut self) -> anyhow::Result<ReportRoom> {
        match self.room.recv() {
            Ok(room) => Ok(room),
            Err(_) => {
                self.finish()?;
                anyhow::bail!("the link thread stopped")
            }
        }
    }

    fn hand_over(&mut self, job: Job) -> anyhow::Result<()> {
        let sent = self.jobs.as_ref().is_some_and(|j| j.send(job).is_ok());
        if sent {
            return Ok(());
        }
        // The thread ended: its error says why.
        self.finish()?;
        anyhow::bail!("the link thread stopped")
    }

    /// Sends a depth report at once, on the urgent lane. A `replaceable`
    /// one gives way to a newer replaceable one (see the module doc); the
    /// others each go in turn.
    pub fn report(
        &mut self,
        frame_id: u32,
        bytes: Vec<u8>,
        replaceable: bool,
    ) -> anyhow::Result<()> {
        self.hand_over(Job {
            kind: Kind::Report,
            frame_id,
            bytes,
            replaceable,
        })
    }

    /// Sends a reply to a command, on the urgent lane.
    pub fn reply(&mut self, reply: &Reply) -> anyhow::Result<()> {
        self.hand_over(Job {
            kind: Kind::Reply,
            frame_id: reply.id,
            bytes: reply.message(),
            replaceable: false,
        })
    }

    /// What the peer sent since the last call, in order.
    pub fn incoming(&self) -> Vec<Incoming> {
        self.incoming.try_iter().collect()
    }

    /// Sends a frame on the bulk lane once the previous frame has ended
    /// (waiting for it here, so at most one frame is queued behind the one
    /// in flight).
    pub fn frame(&mut self, frame_id: u32, bytes: Vec<u8>) -> anyhow::Result<()> {
        while self.frames_in_flight > 0 {
            let Ok(o) = self.outcomes.recv() else {
                self.finish()?;
                anyhow::bail!("the link thread stopped");
            };
            self.take(o);
        }
        self.frames_in_flight += 1;
        self.hand_over(Job {
            kind: Kind::Frame,
            frame_id,
            bytes,
            replaceable: false,
        })
    }

    /// Whether a frame handed over has not ended yet (without waiting).
    pub fn frame_in_flight(&mut self) -> bool {
        while let Ok(o) = self.outcomes.try_recv() {
            self.take(o);
        }
        self.frames_in_flight > 0
    }

    fn take(&mut self, o: Outcome) {
        if o.kind == Kind::Frame {
            self.frames_in_flight -= 1;
        }
        self.taken.push_back(o);
    }

    /// The outcomes that came back so far.
    pub fn outcomes(&mut self) -> Vec<Outcome> {
        while let Ok(o) = self.outcomes.try_recv() {
            self.take(o);
        }
        self.taken.drain(..).collect()
    }

    /// Waits until every message handed over has ended; returns the
    /// outcomes not yet taken, or the link thread's error.
    pub fn finish(&mut self) -> anyhow::Result<Vec<Outcome>> {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            t.join()
                .map_err(|_| anyhow::anyhow!("the link thread panicked"))??;
        }
        Ok(self.outcomes())
    }
}

impl Drop for Uplink {
    fn drop(&mut self) {
        let _ = self.finish();
    }
}

/// The link thread: takes jobs, keeps each lane busy, hands back outcomes
/// and what the peer sent.
fn run(
    frames: Endpoint,
    reports: Option<Endpoint>,
    jobs: Receiver<Job>,
    (done, incoming): (mpsc::Sender<Outcome>, mpsc::Sender<Incoming>),
) -> anyhow::Result<()> {
    // Reports take the urgent lane of the frames' link, or the second link.
    let mut eps = vec![frames];
    eps.extend(reports);
    let ep_of = |lane: Lane| match lane {
        Lane::Urgent => eps.len() - 1,
        Lane::Bulk => 0,
    };
    let (bulk_ep, urgent_ep) = (ep_of(Lane::Bulk), ep_of(Lane::Urgent));
    let mut queued: [VecDeque<Job>; 2] = Default::default();
    let mut current: [Option<(Kind, u32, bool)>; 2] = [None, None];
    let mut open = true;
    // One packet time for each transmit request the radio may hold ahead
    // of a report, and one for the report itself.
    let overtake_after = eps[urgent_ep].packet_time().map_or(Duration::ZERO, |t| {
        t * (PacingConfig::DEFAULT_LIMIT as u32 + 1)
    });
    let mut report_sent = Instant::now();
    loop {
        let idle = current.iter().all(Option::is_none) && queued.iter().all(VecDeque::is_empty);
        if idle && !open {
            break;
        }
        // Every job handed over since the last round (the link may have
        // been busy a few packet times): the send loop never waits on it.
        loop {
            match jobs.try_recv() {
                Ok(job) => {
                    let i = lane_of(job.kind) as usize;
                    if job.replaceable {
                        // The newest report wins over one still waiting.
                        if let Some(k) = queued[i].iter().position(|j| j.replaceable) {
                            if let Some(old) = queued[i].remove(k) {
                                tracing::debug!(
                                    report = old.frame_id,
                                    by = job.frame_id,
                                    "a waiting report replaced by a newer one"
                                );
                                superseded(&done, (old.frame_id, false), &eps[urgent_ep]);
                            }
                        }
                    }
                    queued[i].push_back(job);
                }
                Err(TryRecvError::Disconnected) => {
                    open = false;
                    break;
                }
                Err(TryRecvError::Empty) => break,
            }
        }
        // A report waiting behind one in flight overtakes it once that one
        // has had the time to leave the radio: its acknowledgement is not
        // waited for, and the radio never holds more than one report.
        let u = Lane::Urgent as usize;
        if let (
            Some((_, id, true)),
            Some(Job {
                replaceable: true, ..
            }),
        ) = (current[u], queued[u].front())
        {
            if report_sent.elapsed() >= overtake_after {
                tracing::debug!(
                    report = id,
                    after_ms = report_sent.elapsed().as_millis() as u64,
                    "the report in flight overtaken by a newer one"
                );
                eps[urgent_ep].abandon(Lane::Urgent);
                current[u] = None;
                superseded(&done, (id, true), &eps[urgent_ep]);
            }
        }
        for (lane, e) in [(Lane::Urgent, urgent_ep), (Lane::Bulk, bulk_ep)] {
            let i = lane as usize;
            if current[i].is_none() && eps[e].is_idle(lane) {
                if let Some(job) = queued[i].pop_front() {
                    eps[e]
                        .submit(lane, &job.bytes)
                        .with_context(|| format!("sending {:?} {}", job.kind, job.frame_id))?;
                    current[i] = Some((job.kind, job.frame_id, job.replaceable));
                    if job.replaceable {
                        report_sent = Instant::now();
                    }
                }
            }
        }
        if current.iter().all(Option::is_none) {
            // Nothing to drive: listen to the peer a moment.
            if !open {
                continue;
            }
            let wait = IDLE_WAIT / eps.len() as u32;
            for ep in eps.iter_mut() {
                take_messages(ep, wait, &incoming)?;
            }
            continue;
        }
        let wait = TICK / eps.len() as u32;
        for ep in eps.iter_mut() {
            for (lane, result) in ep.poll_sends(wait).context("link")? {
                if let Some((kind, frame_id, _)) = current[lane as usize].take() {
                    let link = ep.link_stats();
                    let ended = match result {
                        Ok(stats) => Ended::Delivered(stats),
                        Err(e) => Ended::Failed(e),
                    };
                    let _ = done.send(Outcome {
                        kind,
                        frame_id,
                        ended,
                        link,
                    });
                }
            }
            take_messages(ep, Duration::ZERO, &incoming)?;
        }
    }
    for ep in eps.iter_mut() {
        ep.linger(LINGER / 2).context("link")?;
    }
    Ok(())
}

/// Says that the report of pair `frame_id` was overtaken by a newer one
/// (`sent`: in flight).
fn superseded(done: &mpsc::Sender<Outcome>, (frame_id, sent): (u32, bool), ep: &Endpoint) {
    let _ = done.send(Outcome {
        kind: Kind::Report,
        frame_id,
        ended: Ended::Superseded { sent },
        link: ep.link_stats(),
    });
}

/// Hands up every message the peer completed, waiting up to `wait` for
/// the first; taking the next one acknowledges the one before (it was
/// dealt with: handed to the send loop).
fn take_messages(
    ep: &mut Endpoint,
    mut wait: Duration,
    incoming: &mpsc::Sender<Incoming>,
) -> anyhow::Result<()> {
    loop {
        match ep.recv_message(wait) {
            Ok(msg) => {
                let _ = incoming.send(Control::from_message(&msg));
                wait = Duration::ZERO;
            }
            Err(LinkError::Timeout) => return Ok(()),
            Err(LinkError::Arq(e)) => tracing::warn!("a message from the peer was lost: {e}"),
            Err(e) => return Err(e).context("link"),
        }
    }
}

fn lane_of(kind: Kind) -> Lane {
    match kind {
        Kind::Frame => Lane::Bulk,
        Kind::Report | Kind::Reply => Lane::Urgent,
    }
}
