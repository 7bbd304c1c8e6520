//! `stereolink link-test --report-latency`: how long a depth report takes
//! to reach the receiver while a frame is in flight on the same link. Both
//! ends run in this process over the simulated channel in real time (its
//! UART at the spec's baud rate): a frame of `--size` bytes goes on the bulk
//! lane and, every [`REPORT_EVERY`] (a camera's 10 pairs a second) while it
//! is in flight, a report on the urgent lane, as large as one radio packet
//! carries ([`Endpoint::one_packet_message`]: the sender's fitted depth
//! report); the receiver timestamps each. A report due while the last one
//! is still in flight is skipped and counted: the newest wins.

use std::time::{Duration, Instant};

use serde::Serialize;
use stereolink_link::endpoint::{Endpoint, Lane};
use stereolink_link::sim::{self, SimConfig};

/// How often a report is due while the frame is in flight.
pub const REPORT_EVERY: Duration = Duration::from_millis(100);

#[derive(Serialize)]
struct Latency {
    link: String,
    frame_bytes: usize,
    frame_seconds: f64,
    report_bytes: usize,
    /// Reports due while the one before was still in flight.
    reports_skipped: usize,
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
    let report_bytes = ep.one_packet_message();
    let mut skipped = 0;
    ep.submit(Lane::Bulk, &message(b'F', epoch, size))?;
    let start = Instant::now();
    let mut next_report = start + REPORT_EVERY;
    let frame_seconds = loop {
        if Instant::now() >= next_report {
            match ep.is_idle(Lane::Urgent) {
                true => ep.submit(Lane::Urgent, &message(b'R', epoch, report_bytes))?,
                false => skipped += 1,
            }
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
        report_bytes,
        reports_skipped: skipped,
        median_ms: sorted[sorted.len() / 2],
        max_ms: sorted[sorted.len() - 1],
        report_ms: std::mem::take(&mut report_ms),
    };
    out.emit(&r, || {
        format!(
            "{}: a {} B frame took {:.2} s; {} depth reports of {} B sent meanwhile ({} skipped: the one before still in flight) reached the receiver in {:.0} ms median, {:.0} ms at most\n",
            r.link,
            r.frame_bytes,
            r.frame_seconds,
            r.report_ms.len(),
            r.report_bytes,
            r.reports_skipped,
            r.median_ms,
            r.max_ms
        )
    })
}
