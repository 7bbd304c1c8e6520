//! The sender's retransmission timer, after RFC 6298: the timeout (RTO) from
//! measured round trips (Jacobson/Karels, SRTT + 4·RTTVAR) clamped to the
//! configured bounds, fed only by fragments sent once (Karn's rule), and
//! doubled when it expires (§5.5) until a new sample sets it again. The
//! first timeout is the configured one, which a radio link seeds from its
//! packets' air time ([`super::Config::with_packet_time`]). Its own module
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
    /// When the timeout was last doubled: fragments sent before it expire
    /// on the old timeout and do not double it again.
    backed_off_at: Option<Micros>,
}

impl RetransmitTimer {
    /// The timer before any round trip is measured: `cfg.initial_rto`.
    pub(super) fn new(cfg: &Config) -> Self {
        RetransmitTimer {
            srtt: None,
            rto: cfg.initial_rto,
            min_rto: cfg.min_rto,
            max_rto: cfg.max_rto,
            backed_off_at: None,
        }
    }

    /// Takes into account that a fragment sent at `sent_at` expired at
    /// `now`: the timeout doubles (RFC 6298 §5.5), once for all the
    /// fragments that were sent under the timeout that expired.
    pub(super) fn on_expired(&mut self, sent_at: Micros, now: Micros) {
        if self.backed_off_at.is_none_or(|b| sent_at >= b) {
            self.rto = self.rto.saturating_mul(2).min(self.max_rto);
            self.backed_off_at = Some(now);
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
