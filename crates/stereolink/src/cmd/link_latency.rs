//! `stereolink link-test --report-latency`: how long a depth report takes
//! to reach the receiver while a frame is in flight on the same link. Both
//! ends run in this process over the simulated channel in real time (its
//! UART at the spec's baud rate): a frame of `--size` bytes goes on the bulk
//! lane and, every [`REPORT_EVERY`] while it is in flight, a report of
//! [`REPORT_BYTES`] on the urgent lane; the receiver timestamps each.

use std::time::{Duration, Instant};

use serde::Serialize;
use stereolink_link::endpoint::{Endpoint, Lane};
use stereolink_link::sim::{self, SimConfig};

/// A depth report's size on the wire (the sender's container for a
/// 480x272 pair with nine depth levels).
pub const REPORT_BYTES: usize = 293;
/// How often a report is submitted while the frame is in flight.
pub const REPORT_EVERY: Duration = Duration::from_millis(400);

#[derive(Serialize)]
struct Latency {
    link: String,
    frame_bytes: usize,
    frame_seconds: f64,
    report_bytes: usize,
    report_ms: Vec<f64>,
    median_ms: f64,
    max_ms: f64,
}

/// A message: its kind ('F' or 'R'), when it was submitted (µs since
/// `epoch`), padding.
fn message(kind: u8, epoch: Instant, size: usize) -> Vec<u8> {
    let mut m = vec![kind];
    m.extend_from_slice(&(epoch.elapsed().as_micros() as u64).to_le_bytes());
    m.resize(size.max(9), 0xA5);
    m
}

/// Runs the measurement and prints it.
pub fn run(config: SimConfig, link: &str, size: usize, out: &super::Output) -> anyhow::Result<()> {
    let (a, b) = sim::pair(config, 1.0);
    let epoch = Instant::now();
    let receiver = std::thread::spawn(move || -> anyhow::Result<Vec<f64>> {
        let mut ep = Endpoint::new(Box::new(b))?;
        let mut latencies = Vec::new();
        loop {
            let m = ep.recv_message(Duration::from_secs(60))?;
            let sent = u64::from_le_bytes(m[1..9].try_into()?);
            let ms = (epoch.elapsed().as_micros() as u64).saturating_sub(sent) as f64 / 1e3;
            match m[0] {
                b'R' => latencies.push(ms),
                _ => break,
            }
        }
        ep.linger(Duration::from_millis(300))?;
        Ok(latencies)
    });
    let mut ep = Endpoint::new(Box::new(a))?;
    ep.submit(Lane::Bulk, &message(b'F', epoch, size))?;
    let start = Instant::now();
    let mut next_report = start + REPORT_EVERY;
    let frame_seconds = loop {
        if Instant::now() >= next_report && ep.is_idle(Lane::Urgent) {
            ep.submit(Lane::Urgent, &message(b'R', epoch, REPORT_BYTES))?;
            next_report += REPORT_EVERY;
        }
        let ended = ep.poll_sends(Duration::from_millis(5))?;
        if let Some((_, r)) = ended.into_iter().find(|(l, _)| *l == Lane::Bulk) {
            break r?.elapsed.as_secs_f64();
        }
    };
    // Reports still in flight end before the receiver hears the frame's end.
    while !ep.is_idle(Lane::Urgent) {
        ep.poll_sends(Duration::from_millis(5))?;
    }
    let mut report_ms = receiver
        .join()
        .map_err(|_| anyhow::anyhow!("the receiver thread panicked"))??;
    anyhow::ensure!(
        !report_ms.is_empty(),
        "the frame took less than {} ms: give a larger --size",
        REPORT_EVERY.as_millis()
    );
    let mut sorted = report_ms.clone();
    sorted.sort_by(f64::total_cmp);
    let r = Latency {
        link: link.to_string(),
        frame_bytes: size,
        frame_seconds,
        report_bytes: REPORT_BYTES,
        median_ms: sorted[sorted.len() / 2],
        max_ms: sorted[sorted.len() - 1],
        report_ms: std::mem::take(&mut report_ms),
    };
    out.emit(&r, || {
        format!(
            "{}: a {} B frame took {:.2} s; {} depth reports of {} B sent meanwhile reached the receiver in {:.0} ms median, {:.0} ms at most\n",
            r.link,
            r.frame_bytes,
            r.frame_seconds,
            r.report_ms.len(),
            r.report_bytes,
            r.median_ms,
            r.max_ms
        )
    })
}
