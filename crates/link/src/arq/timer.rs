//! The sender's retransmission timer: the timeout (RTO) from measured round
//! trips after Jacobson/Karels, SRTT + 4·RTTVAR clamped to the configured
//! bounds, fed only by fragments sent once (Karn's rule). Its own module
//! because estimating the round trip is one idea apart from the window and
//! the ACK rules: the sender keeps each fragment's send time and asks here
//! when it expires.

use super::{Config, Micros};

/// The retransmission timeout and the round-trip estimate behind it.
#[derive(Clone, Copy, Debug)]
pub(super) struct RetransmitTimer {
    /// Smoothed round trip and its mean deviation, from the first sample on.
    srtt: Option<(f64, f64)>,
    rto: Micros,
    min_rto: Micros,
    max_rto: Micros,
}

impl RetransmitTimer {
    /// The timer before any round trip is measured: `cfg.initial_rto`.
    pub(super) fn new(cfg: &Config) -> Self {
        RetransmitTimer {
            srtt: None,
            rto: cfg.initial_rto,
            min_rto: cfg.min_rto,
            max_rto: cfg.max_rto,
        }
    }

    /// The current retransmission timeout.
    pub(super) fn rto(&self) -> Micros {
        self.rto
    }

    /// When a fragment sent at `sent_at` is due to be sent again.
    pub(super) fn expires_at(&self, sent_at: Micros) -> Micros {
        sent_at + self.rto
    }

    /// Takes into account that a fragment sent `tries` times, the last at
    /// `sent_at` (`None` once counted as lost), was acknowledged at `now`.
    pub(super) fn on_acked(&mut self, tries: u32, sent_at: Option<Micros>, now: Micros) {
        // Karn: only fragments sent once give round-trip samples.
        if let (1, Some(t)) = (tries, sent_at) {
            self.sample_rtt(now.saturating_sub(t));
        }
    }

    fn sample_rtt(&mut self, rtt: Micros) {
        let r = rtt as f64;
        let (srtt, var) = match self.srtt {
            None => (r, r / 2.0),
            Some((s, v)) => (0.875 * s + 0.125 * r, 0.75 * v + 0.25 * (s - r).abs()),
        };
        self.srtt = Some((srtt, var));
        self.rto = ((srtt + 4.0 * var) as Micros).clamp(self.min_rto, self.max_rto);
    }
}
