//! Transmit requests outstanding at the local XBee radio, paced by their
//! transmit status (0x89 on 802.15.4, 0x8B on ZigBee and DigiMesh).
//!
//! The radio's serial receive buffer is small (a few hundred bytes) and the
//! air is slower than a 115200-baud UART on ZigBee, so a host that writes
//! fragments as fast as its UART takes them overruns the buffer and the radio
//! drops bytes (with CTS ignored). [`Pacing`] keeps at most `limit` requests
//! at the radio: each carries a frame id ≠ 0, so the radio answers it with a
//! status, and the next request waits for a status or for the status timeout.
//!
//! A failed delivery (no MAC ACK, network ACK failure 0x21, address not
//! found 0x24, ...) is counted by cause and the fragment is sent again at
//! once, up to `retries` times; then it is left to the ARQ above. A payload
//! the radio calls too large (0x74) is not retried: it is a configuration
//! error ([`StatusAction::TooLarge`]). A status for a frame id with nothing
//! outstanding is counted and ignored. A radio reset (modem status 0x8A,
//! hardware or watchdog reset) lost whatever it held, so
//! [`Pacing::on_reset`] hands back every outstanding request to send again.
//!
//! Like the ARQ machines this does no I/O and reads no clock.

use alloc::collections::VecDeque;
use alloc::vec::Vec;

use crate::arq::Micros;

/// Parameters of the pacing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacingConfig {
    /// Transmit requests at the radio at once (one on the air, the others
    /// waiting in its serial buffer).
    pub limit: usize,
    /// Immediate resends of a fragment whose status reports a failure.
    pub retries: u8,
    /// How long a status may take before the request is taken as lost (a
    /// ZigBee unicast with route discovery and retries takes a few seconds).
    pub status_timeout: Micros,
}

impl PacingConfig {
    /// Requests at the radio at once by default: one on the air and the
    /// next in its buffer, ready to go. More only queue ahead of an urgent
    /// packet; fewer leave the air idle while the next request crosses the
    /// UART.
    pub const DEFAULT_LIMIT: usize = 2;
}

impl Default for PacingConfig {
    fn default() -> Self {
        PacingConfig {
            limit: Self::DEFAULT_LIMIT,
            retries: 2,
            status_timeout: 3_000_000,
        }
    }
}

/// What the pacing counted.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PacingCounters {
    /// Requests written to the radio, resends included.
    pub requests: u64,
    /// Statuses that reported success.
    pub delivered: u64,
    /// Failed deliveries by status code, in the order first seen.
    pub failures: Vec<(u8, u64)>,
    /// Fragments sent again after a failure status.
    pub resent: u64,
    /// Fragments given up after `retries` resends (the ARQ retransmits them).
    pub gave_up: u64,
    /// Requests whose status never came within the timeout.
    pub status_lost: u64,
    /// Statuses for frame ids with nothing outstanding.
    pub stray_status: u64,
    /// Radio resets (modem status 0x8A, hardware or watchdog reset).
    pub resets: u64,
}

impl PacingCounters {
    fn count_failures(&mut self, code: u8, k: u64) {
        match self.failures.iter_mut().find(|(c, _)| *c == code) {
            Some((_, n)) => *n += k,
            None => self.failures.push((code, k)),
        }
    }

    /// Adds `other`'s counts to these (the radios of a bond).
    pub fn add(&mut self, other: &PacingCounters) {
        self.requests += other.requests;
        self.delivered += other.delivered;
        for &(code, n) in &other.failures {
            self.count_failures(code, n);
        }
        self.resent += other.resent;
        self.gave_up += other.gave_up;
        self.status_lost += other.status_lost;
        self.stray_status += other.stray_status;
        self.resets += other.resets;
    }
}

/// What to do on a transmit status.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum StatusAction {
    /// Delivered, or failed and given up; nothing to send.
    Settled,
    /// Failed with `status`: send `packet` again as frame `frame_id`.
    Resend {
        /// The failed transmit status.
        status: u8,
        /// The API frame id to send it under.
        frame_id: u8,
        /// The transmit request to send again.
        packet: Vec<u8>,
    },
    /// The radio refused the payload as too large (0x74): `len` bytes.
    TooLarge {
        /// The payload's length.
        len: usize,
    },
    /// No request with this frame id is outstanding.
    Stray,
}

/// The delivery status a radio gives a payload larger than it takes.
pub const PAYLOAD_TOO_LARGE: u8 = 0x74;

struct Request {
    frame_id: u8,
    packet: Vec<u8>,
    resends: u8,
    sent_at: Micros,
}

/// The requests outstanding at the radio.
pub struct Pacing {
    cfg: PacingConfig,
    outstanding: VecDeque<Request>,
    next_id: u8,
    counters: PacingCounters,
}

impl Pacing {
    /// Nothing outstanding; frame ids from 1.
    pub fn new(cfg: PacingConfig) -> Self {
        Pacing {
            cfg: PacingConfig {
                limit: cfg.limit.clamp(1, 254),
                ..cfg
            },
            outstanding: VecDeque::new(),
            next_id: 1,
            counters: PacingCounters::default(),
        }
    }

    /// The parameters in force.
    pub fn config(&self) -> PacingConfig {
        self.cfg
    }

    /// What was counted so far.
    pub fn counters(&self) -> &PacingCounters {
        &self.counters
    }

    /// Whether another request may go to the radio now.
    pub fn has_room(&self) -> bool {
        self.outstanding.len() < self.cfg.limit
    }

    /// When the oldest outstanding request times out.
    pub fn deadline(&self) -> Option<Micros> {
        self.outstanding
            .iter()
            .map(|r| r.sent_at + self.cfg.status_timeout)
            .min()
    }

    /// A frame id in 1..=255 that no outstanding request holds.
    fn fresh_id(&mut self) -> u8 {
        loop {
            let id = self.next_id;
            self.next_id = id.checked_add(1).unwrap_or(1);
            if !self.outstanding.iter().any(|r| r.frame_id == id) {
                return id;
            }
        }
    }

    /// Records `packet` as sent now; returns the frame id to send it with.
    /// Call only when [`Pacing::has_room`] (or after [`Pacing::expire`]).
    pub fn push(&mut self, packet: &[u8], now: Micros) -> u8 {
        let frame_id = self.fresh_id();
        self.counters.requests += 1;
        self.outstanding.push_back(Request {
            frame_id,
            packet: packet.to_vec(),
            resends: 0,
            sent_at: now,
        });
        frame_id
    }

    /// Takes the status of frame `frame_id` (`status` 0: delivered).
    pub fn on_status(&mut self, frame_id: u8, status: u8, now: Micros) -> StatusAction {
        let Some(at) = self.outstanding.iter().position(|r| r.frame_id == frame_id) else {
            self.counters.stray_status += 1;
            return StatusAction::Stray;
        };
        if status == 0 {
            self.counters.delivered += 1;
            self.outstanding.remove(at);
            return StatusAction::Settled;
        }
        self.counters.count_failures(status, 1);
        let Some(mut request) = self.outstanding.remove(at) else {
            return StatusAction::Stray;
        };
        if status == PAYLOAD_TOO_LARGE {
            return StatusAction::TooLarge {
                len: request.packet.len(),
            };
        }
        if request.resends >= self.cfg.retries {
            self.counters.gave_up += 1;
            return StatusAction::Settled;
        }
        request.resends += 1;
        request.frame_id = self.fresh_id();
        request.sent_at = now;
        self.counters.resent += 1;
        self.counters.requests += 1;
        let (frame_id, packet) = (request.frame_id, request.packet.clone());
        self.outstanding.push_back(request);
        StatusAction::Resend {
            status,
            frame_id,
            packet,
        }
    }

    /// Forgets requests whose status did not come in time; returns how many.
    pub fn expire(&mut self, now: Micros) -> usize {
        let timeout = self.cfg.status_timeout;
        let before = self.outstanding.len();
        self.outstanding.retain(|r| now < r.sent_at + timeout);
        let lost = before - self.outstanding.len();
        self.counters.status_lost += lost as u64;
        lost
    }

    /// The radio reset and lost what it held: every outstanding request,
    /// with a fresh frame id each, to send again in order.
    pub fn on_reset(&mut self, now: Micros) -> Vec<(u8, Vec<u8>)> {
        self.counters.resets += 1;
        let requests: Vec<Request> = self.outstanding.drain(..).collect();
        requests
            .into_iter()
            .map(|mut r| {
                r.frame_id = self.fresh_id();
                r.sent_at = now;
                self.counters.requests += 1;
                let resend = (r.frame_id, r.packet.clone());
                self.outstanding.push_back(r);
                resend
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pacing() -> Pacing {
        Pacing::new(PacingConfig {
            limit: 2,
            retries: 1,
            status_timeout: 1_000,
        })
    }

    #[test]
    fn at_most_limit_requests_wait_for_their_status() {
        let mut p = pacing();
        let a = p.push(b"a", 0);
        assert!(p.has_room());
        let b = p.push(b"b", 0);
        assert!(!p.has_room());
        assert_ne!(a, b);
        assert_eq!(p.on_status(a, 0, 10), StatusAction::Settled);
        assert!(p.has_room());
        assert_eq!(p.counters().delivered, 1);
    }

    #[test]
    fn a_failure_is_resent_once_then_left_to_the_arq() {
        let mut p = pacing();
        let a = p.push(b"frag", 0);
        let StatusAction::Resend {
            status,
            frame_id,
            packet,
        } = p.on_status(a, 0x21, 5)
        else {
            panic!("expected a resend");
        };
        assert_eq!((status, packet.as_slice()), (0x21, &b"frag"[..]));
        assert_ne!(frame_id, a);
        assert_eq!(p.on_status(frame_id, 0x21, 9), StatusAction::Settled);
        let c = p.counters();
        assert_eq!((c.resent, c.gave_up, c.requests), (1, 1, 2));
        assert_eq!(c.failures, vec![(0x21, 2)]);
        assert!(p.has_room());
    }

    #[test]
    fn too_large_is_not_retried() {
        let mut p = pacing();
        let a = p.push(&[0; 90], 0);
        assert_eq!(
            p.on_status(a, PAYLOAD_TOO_LARGE, 1),
            StatusAction::TooLarge { len: 90 }
        );
        assert!(p.has_room());
    }

    #[test]
    fn unknown_ids_are_counted_and_ignored() {
        let mut p = pacing();
        p.push(b"x", 0);
        assert_eq!(p.on_status(200, 0, 1), StatusAction::Stray);
        assert_eq!(p.counters().stray_status, 1);
        assert!(p.has_room());
    }

    #[test]
    fn lost_statuses_expire() {
        let mut p = pacing();
        p.push(b"x", 0);
        p.push(b"y", 500);
        assert_eq!(p.deadline(), Some(1_000));
        assert_eq!(p.expire(999), 0);
        assert_eq!(p.expire(1_000), 1);
        assert!(p.has_room());
        assert_eq!(p.counters().status_lost, 1);
    }

    #[test]
    fn a_reset_resends_everything_outstanding_with_fresh_ids() {
        let mut p = pacing();
        let a = p.push(b"x", 0);
        let b = p.push(b"y", 0);
        let again = p.on_reset(7);
        assert_eq!(again.len(), 2);
        assert_eq!(again[0].1, b"x");
        assert_eq!(again[1].1, b"y");
        assert!(again.iter().all(|(id, _)| *id != a && *id != b));
        // The old ids are stray now; the new ones settle.
        assert_eq!(p.on_status(a, 0, 8), StatusAction::Stray);
        assert_eq!(p.on_status(again[0].0, 0, 8), StatusAction::Settled);
        assert_eq!(p.counters().resets, 1);
    }

    #[test]
    fn frame_ids_skip_zero_and_outstanding_ones() {
        let mut p = Pacing::new(PacingConfig {
            limit: 254,
            ..PacingConfig::default()
        });
        let held = p.push(b"h", 0);
        for _ in 0..600 {
            let id = p.push(b"z", 0);
            assert!(id != 0 && id != held);
            p.on_status(id, 0, 0);
        }
    }
}
