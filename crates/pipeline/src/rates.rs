//! What a live link carried, counted as it goes: depth reports with their
//! capture-to-arrival latency, frames and bytes. The sender and the
//! receiver both print these once a second and in their summaries
//! (`send`, `receive`, `bench live`), so the two ends and the benchmark
//! speak of the same figures in the same words.
//!
//! Latencies are kept as a histogram of fixed size ([`LatencyHistogram`]:
//! 1 ms bins up to a second, 10 ms bins up to a minute), so a sender or
//! receiver that runs for months counts in constant memory.

use std::time::{Duration, Instant};

use serde::Serialize;

use crate::receiver::Event;

/// Counts since a start: the whole run, or the last second.
#[derive(Clone, Debug)]
pub struct Rates {
    since: Instant,
    reports: u64,
    frames: u64,
    bytes: u64,
    latency: LatencyHistogram,
}

/// Latencies counted in bins: 1 ms wide below [`FINE_MS`], 10 ms wide up
/// to [`LONGEST_MS`]; a longer one counts in the last bin.
#[derive(Clone, Debug)]
pub struct LatencyHistogram {
    bins: Vec<u64>,
    count: u64,
}

/// Where the bins widen from 1 to 10 ms.
const FINE_MS: usize = 1_000;
/// The longest latency told apart; longer ones count as this.
const LONGEST_MS: usize = 60_000;
const BINS: usize = FINE_MS + (LONGEST_MS - FINE_MS) / 10 + 1;

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram {
            bins: vec![0; BINS],
            count: 0,
        }
    }
}

impl LatencyHistogram {
    /// Counts a latency of `ms` (rounded to its bin).
    pub fn add(&mut self, ms: f64) {
        let ms = ms.max(0.0).round().min(LONGEST_MS as f64) as usize;
        let bin = match ms {
            ms if ms < FINE_MS => ms,
            ms => FINE_MS + (ms - FINE_MS) / 10,
        };
        self.bins[bin] += 1;
        self.count += 1;
    }

    /// The latency at quantile `q` (0..1, nearest rank), ms: the bin's
    /// lower edge; `None` when empty.
    fn quantile(&self, q: f64) -> Option<f64> {
        let rank = ((self.count.checked_sub(1)?) as f64 * q).round() as u64;
        let mut seen = 0;
        let bin = self.bins.iter().position(|&n| {
            seen += n;
            seen > rank
        })?;
        Some(match bin {
            b if b < FINE_MS => b as f64,
            b => (FINE_MS + (b - FINE_MS) * 10) as f64,
        })
    }

    /// Empties it, keeping its bins (no allocation).
    pub fn clear(&mut self) {
        self.bins.fill(0);
        self.count = 0;
    }

    /// The median and 99th percentile; `None` when empty.
    pub fn latency(&self) -> Option<Latency> {
        Some(Latency {
            p50: self.quantile(0.5)?,
            p99: self.quantile(0.99)?,
        })
    }
}

/// Latency percentiles, ms.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Latency {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
}

/// The figures of a span.
#[derive(Clone, Debug, Serialize)]
pub struct Figures {
    /// Depth reports.
    pub reports: u64,
    /// Depth reports a second.
    pub report_rate_hz: f64,
    /// From a report's capture time stamp to its arrival (at the receiver:
    /// its move; at the sender: its acknowledgement); the two ends' clocks
    /// must agree (same host, or NTP).
    pub report_latency_ms: Option<Latency>,
    /// Frames.
    pub frames: u64,
    /// Frames a second.
    pub frame_rate_hz: f64,
    /// Message bytes, reports and frames.
    pub bytes: u64,
    /// The span, seconds.
    pub seconds: f64,
}

impl Rates {
    /// Nothing counted yet, from `since`.
    pub fn new(since: Instant) -> Rates {
        Rates {
            since,
            reports: 0,
            frames: 0,
            bytes: 0,
            latency: LatencyHistogram::default(),
        }
    }

    /// A report of `bytes`, captured `latency` before it arrived (unknown
    /// for a sender without a clock).
    pub fn report(&mut self, bytes: usize, latency: Option<Duration>) {
        self.reports += 1;
        self.bytes += bytes as u64;
        if let Some(l) = latency {
            self.latency.add(l.as_secs_f64() * 1e3);
        }
    }

    /// A frame of `bytes`.
    pub fn frame(&mut self, bytes: usize) {
        self.frames += 1;
        self.bytes += bytes as u64;
    }

    /// The figures from the start until `now`.
    pub fn figures(&self, now: Instant) -> Figures {
        let seconds = now.saturating_duration_since(self.since).as_secs_f64();
        let per_second = |n: u64| n as f64 / seconds.max(1e-9);
        Figures {
            reports: self.reports,
            report_rate_hz: per_second(self.reports),
            report_latency_ms: self.latency.latency(),
            frames: self.frames,
            frame_rate_hz: per_second(self.frames),
            bytes: self.bytes,
            seconds,
        }
    }

    /// The figures until `now`, and a fresh start from `now`: the last
    /// second's status line (without allocating).
    pub fn take(&mut self, now: Instant) -> Figures {
        let figures = self.figures(now);
        (self.since, self.reports, self.frames, self.bytes) = (now, 0, 0, 0);
        self.latency.clear();
        figures
    }
}

/// Microseconds from a time stamp (µs since the Unix epoch) until `now_us`;
/// `None` for a zero stamp (a sender without a clock) or one in the future
/// by more than a second (clocks that disagree).
pub fn since_stamp(stamp_us: u64, now_us: u64) -> Option<Duration> {
    if stamp_us == 0 || stamp_us > now_us + 1_000_000 {
        return None;
    }
    Some(Duration::from_micros(now_us.saturating_sub(stamp_us)))
}

impl std::fmt::Display for Figures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} reports ({:.1}/s", self.reports, self.report_rate_hz)?;
        if let Some(l) = &self.report_latency_ms {
            write!(f, ", latency p50 {:.0} ms, p99 {:.0} ms", l.p50, l.p99)?;
        }
        write!(
            f,
            "), {} frames ({:.2}/s), {} B in {:.1} s",
            self.frames, self.frame_rate_hz, self.bytes, self.seconds
        )
    }
}

/// Frames complete on the board: a frame counts once its views and a
/// depth report of its pair or a later one arrived (the reports overtake the
/// frames, and a newer pair's report may have taken its own's place).
#[derive(Debug, Default)]
pub struct FrameCount {
    /// Frames complete so far.
    pub counted: u32,
    /// The newest report's pair.
    last_report: Option<u32>,
    /// Frames whose report has not come yet.
    waiting: std::collections::BTreeSet<u32>,
}

impl FrameCount {
    /// Counts what the board made of a message.
    pub fn count(&mut self, event: &Event) {
        match *event {
            Event::Report { frame_id, .. } => {
                self.last_report = self.last_report.max(Some(frame_id));
                let later = self.waiting.split_off(&(frame_id + 1));
                self.counted += self.waiting.len() as u32;
                self.waiting = later;
            }
            Event::Frame { frame_id, .. } if self.last_report >= Some(frame_id) => {
                self.counted += 1;
            }
            Event::Frame { frame_id, .. } => {
                self.waiting.insert(frame_id);
                if self.waiting.len() > 16 {
                    self.waiting.pop_first();
                }
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_and_percentiles_over_a_span() {
        let t0 = Instant::now();
        let mut r = Rates::new(t0);
        for ms in 1..=100 {
            r.report(50, Some(Duration::from_millis(ms)));
        }
        r.report(50, None);
        r.frame(4000);
        let f = r.figures(t0 + Duration::from_secs(2));
        assert_eq!((f.reports, f.frames, f.bytes), (101, 1, 101 * 50 + 4000));
        assert_eq!(f.report_rate_hz, 50.5);
        assert_eq!(f.frame_rate_hz, 0.5);
        let l = f.report_latency_ms.unwrap();
        assert_eq!((l.p50.round(), l.p99.round()), (51.0, 99.0));
        let second = r.take(t0 + Duration::from_secs(2));
        assert_eq!(second.reports, 101);
        assert_eq!(r.figures(t0 + Duration::from_secs(3)).reports, 0);
    }

    #[test]
    fn latencies_count_in_constant_memory_to_their_bin() {
        let mut h = LatencyHistogram::default();
        assert_eq!(h.latency(), None);
        h.add(-3.0);
        h.add(2_345.6);
        h.add(3_600_000.0);
        assert_eq!(h.bins.len(), BINS);
        assert_eq!(h.quantile(0.0), Some(0.0));
        assert_eq!(h.quantile(0.5), Some(2_340.0));
        assert_eq!(h.quantile(1.0), Some(LONGEST_MS as f64));
    }

    #[test]
    fn stamps_from_no_clock_or_the_future_give_no_latency() {
        assert_eq!(since_stamp(0, 5_000_000), None);
        assert_eq!(since_stamp(7_000_000, 5_000_000), None);
        assert_eq!(
            since_stamp(4_000_000, 5_000_000),
            Some(Duration::from_secs(1))
        );
        assert_eq!(since_stamp(5_500_000, 5_000_000), Some(Duration::ZERO));
    }
}
