//! The live chain in one process, for `stereolink bench live`: a recorded
//! sequence played as a camera ([`Pairs::sequence`]) through the sender's
//! pair loop ([`SendLoop`]), the simulated radio in real time (its
//! calibrated throughput, [`stereolink_link::throughput`]), and the board's
//! receiver driving a simulated axis. Both ends share one clock, so a
//! report's latency is exactly capture to the axis's move.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use serde::Serialize;
use stereolink_codec::container;
use stereolink_codec::control::unix_us;
use stereolink_image::Calibration;
use stereolink_link::endpoint::{Endpoint, LinkError};
use stereolink_link::sim::{self, SimConfig};
use stereolink_robot::sim::{MotorParams, SimAxis};

use crate::live::{SendLoop, Status, Update};
use crate::pairs::Pairs;
use crate::rates::{since_stamp, Figures, Rates};
use crate::receiver::{BoardReceiver, Event};
use crate::sender::SenderConfig;
use crate::uplink::Uplink;

/// What a run measured at both ends.
#[derive(Debug, Serialize)]
pub struct LiveFigures {
    /// The sender: pairs in and skipped, what the peer acknowledged.
    pub sender: Status,
    /// The receiver: reports applied to the axis (latency: capture to
    /// the move), frames shown, while the pairs arrived (from one camera
    /// period before the first report to the last).
    pub receiver: Figures,
    /// Reports the receiver refused (older than one applied, or invalid).
    pub refused: u64,
    /// Times the receiver's watchdog stopped the axis.
    pub watchdog_trips: u64,
}

/// Plays `pairs`, one every `period`, through the sender (`cfg`, `calib`,
/// frames sized to cross in `frame_interval` when given, predicted with a
/// key frame every `key_every` when given) over the simulated
/// radio `link` to a board matching up to `max_disp`, whose watchdog
/// stops the axis after `watchdog` without a report; `on_second` sees the
/// sender's status once a second.
pub fn run(
    (pairs, period): (Pairs, Duration),
    link: SimConfig,
    (cfg, calib, (frame_interval, key_every)): (
        SenderConfig,
        Calibration,
        (Option<Duration>, Option<Duration>),
    ),
    (max_disp, watchdog): (usize, Duration),
    mut on_second: impl FnMut(&Status),
) -> anyhow::Result<LiveFigures> {
    let (tx, rx) = sim::pair(link, 1.0);
    let done = Arc::new(AtomicBool::new(false));
    let receiver = {
        let done = done.clone();
        std::thread::spawn(move || {
            receive(
                Endpoint::new(Box::new(rx))?,
                (max_disp, watchdog),
                period,
                &done,
            )
        })
    };
    let uplink = Uplink::start(move || Ok((Endpoint::new(Box::new(tx))?, None)));
    let mut sender = SendLoop::new(uplink, calib, None, cfg, None);
    if let Some(interval) = frame_interval {
        sender = sender.frame_interval(interval);
    }
    if let Some(key_every) = key_every {
        sender = sender.temporal(key_every);
    }
    let sent = sender.run(pairs, None, |u| {
        if let Update::Second(s) = u {
            on_second(s)
        }
    });
    done.store(true, Ordering::Relaxed);
    let received = receiver
        .join()
        .map_err(|_| anyhow::anyhow!("the receiver thread panicked"))?;
    let sent = sent.context("the sender")?;
    let (receiver, refused, watchdog_trips) = received.context("the receiver")?;
    Ok(LiveFigures {
        sender: sent.status,
        receiver,
        refused,
        watchdog_trips,
    })
}

/// The board's side: applies each message until `done`, then answers the
/// sender's late retransmissions a moment.
fn receive(
    mut ep: Endpoint,
    (max_disp, watchdog): (usize, Duration),
    period: Duration,
    done: &AtomicBool,
) -> anyhow::Result<(Figures, u64, u64)> {
    let mut board = BoardReceiver::new(max_disp, 9, watchdog);
    board.axis = Some(Box::new(SimAxis::new(MotorParams::default())));
    // Counted from one camera period before the first report to the last:
    // the rates while the pairs arrive.
    let (mut rates, mut last_report) = (None::<Rates>, Instant::now());
    let (mut refused, mut trips) = (0, 0);
    while !done.load(Ordering::Relaxed) {
        if board.check_watchdog(Instant::now()).context("the axis")? {
            trips += 1;
        }
        let msg = match ep.recv_message(Duration::from_millis(50)) {
            Ok(msg) => msg,
            Err(LinkError::Timeout) => continue,
            Err(e) => return Err(e).context("receiving"),
        };
        let stamp_us = container::decode_header(&msg).map_or(0, |h| h.timestamp_us);
        match board.handle(&msg) {
            Event::Report { .. } => {
                let now = Instant::now();
                let rates =
                    rates.get_or_insert_with(|| Rates::new(now.checked_sub(period).unwrap_or(now)));
                rates.report(msg.len(), since_stamp(stamp_us, unix_us()));
                last_report = now;
            }
            Event::Frame { .. } => {
                if let Some(r) = rates.as_mut() {
                    r.frame(msg.len())
                }
            }
            Event::Rejected(_) => refused += 1,
            Event::Command { .. } | Event::Answered { .. } => {}
        }
        ep.dealt_with().context("link")?;
    }
    ep.linger(Duration::from_millis(300)).context("link")?;
    let rates = rates.context("no depth report arrived")?;
    Ok((rates.figures(last_report), refused, trips))
}
