//! Transports carry link segments (one packet each, at most `mtu` bytes):
//! a serial port to an XBee radio ([`crate::serial`]), a UDP socket (the IP
//! fallback), and [`Fallback`], which switches between two. Below the ARQ a
//! transport may measure the link ([`LinkStats`]) and have something to say
//! about it once ([`Notice`]): a radio that reset, a delivery failure, a
//! peer wired with no radio between.

use std::fmt;
use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use crate::pacing::PacingCounters;
use crate::xbee::{delivery_status_text, modem_status_text};

pub use crate::serial::{Serial, SerialFraming};

/// Whether a read failed only because no byte came in time (or a signal
/// interrupted it): the caller waits on, it is not an error.
pub(crate) fn no_data_yet(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
    )
}

/// A packet transport.
pub trait Transport: Send {
    /// Sends one packet (at most [`Transport::mtu`] bytes).
    fn send(&mut self, packet: &[u8]) -> io::Result<()>;
    /// Waits up to `timeout` for one packet.
    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>>;
    /// Largest packet carried.
    fn mtu(&self) -> usize;
    /// A short description for logs and reports.
    fn describe(&self) -> String;
    /// What the transport measured so far.
    fn stats(&self) -> LinkStats {
        LinkStats::default()
    }
    /// The air time one full packet takes, where the transport knows its
    /// radio's pace ([`crate::throughput`]): the ARQ seeds its first
    /// retransmission timeout from it ([`crate::arq::Config::with_packet_time`]).
    fn packet_time(&self) -> Option<Duration> {
        None
    }
    /// What the transport has to say since it was last asked (each kind of
    /// trouble once).
    fn take_notices(&mut self) -> Vec<Notice> {
        Vec::new()
    }
}

/// What a transport measured below the ARQ.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LinkStats {
    /// Frames or packets dropped as damaged.
    pub damaged: u64,
    /// The radio's transmit statuses (serial links in API mode).
    pub radio: Option<PacingCounters>,
    /// XBee transmit requests heard from the other end: it is wired directly.
    pub foreign_requests: u64,
    /// Signal strength of the last received frame, in dBm (802.15.4 RX
    /// frames carry it).
    pub rssi_dbm: Option<i16>,
}

impl fmt::Display for LinkStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} damaged", self.damaged)?;
        if let Some(r) = &self.radio {
            write!(f, "; radio: {} delivered", r.delivered)?;
            for (code, n) in &r.failures {
                write!(f, ", {n} x 0x{code:02X} {}", delivery_status_text(*code))?;
            }
            for (n, what) in [
                (r.resent, "resent"),
                (r.gave_up, "left to the ARQ"),
                (r.status_lost, "without status"),
                (r.stray_status, "stray statuses"),
                (r.resets, "resets"),
            ] {
                if n > 0 {
                    write!(f, ", {n} {what}")?;
                }
            }
        }
        if self.foreign_requests > 0 {
            write!(f, "; {} transmit requests heard", self.foreign_requests)?;
        }
        if let Some(rssi) = self.rssi_dbm {
            write!(f, "; RSSI {rssi} dBm")?;
        }
        Ok(())
    }
}

/// Something a transport says once about the link.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Notice {
    /// The radio reset (modem status 0x8A) and `resent` fragments it held
    /// were sent again.
    RadioReset {
        /// The modem status.
        status: u8,
        /// Fragments sent again.
        resent: usize,
    },
    /// Another modem status (joined, disassociated, ...).
    ModemStatus {
        /// The modem status (see `xbee::modem_status_text`).
        status: u8,
    },
    /// The first delivery failure with this status code.
    DeliveryFailed {
        /// The delivery status (see `xbee::delivery_status_text`).
        status: u8,
    },
    /// The first transmit status for a frame id with nothing outstanding.
    StrayStatus {
        /// The API frame id the status named.
        frame_id: u8,
    },
    /// The first transmit request whose status never came.
    NoStatus {
        /// How long the status was waited for.
        timeout: Duration,
    },
    /// XBee transmit requests arrived: the other end writes API frames
    /// meant for its radio, so there is no radio between the two.
    ForeignRequests,
    /// A fallback link moved its traffic from one link to the other.
    Switched {
        /// The link left.
        from: String,
        /// The link taken.
        to: String,
    },
    /// A bond dropped one of its links ([`crate::bond`]).
    MemberDown {
        /// The link dropped.
        member: String,
        /// Why.
        reason: String,
    },
}

impl fmt::Display for Notice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Notice::RadioReset { status, resent } => write!(
                f,
                "the radio reset mid-stream ({}); {resent} fragments it held were sent again",
                modem_status_text(*status)
            ),
            Notice::ModemStatus { status } => {
                write!(f, "the radio reports: {}", modem_status_text(*status))
            }
            Notice::DeliveryFailed { status } => write!(
                f,
                "the radio could not deliver a fragment: 0x{status:02X} {} (sent again; see the link statistics)",
                delivery_status_text(*status)
            ),
            Notice::StrayStatus { frame_id } => write!(
                f,
                "the radio sent a transmit status for frame id {frame_id}, which nothing awaits (ignored)"
            ),
            Notice::NoStatus { timeout } => write!(
                f,
                "the radio gave no transmit status within {:.0} s: is an XBee in API mode on this port, \
                 at this baud rate? A direct cable between two computers needs api=0",
                timeout.as_secs_f64()
            ),
            Notice::ForeignRequests => f.write_str(
                "heard XBee transmit requests on this line: the other end is wired directly, \
                 with no radio between; use api=0 on both ends, or put the radios between them",
            ),
            Notice::Switched { from, to } => write!(f, "switching from {from} to {to}"),
            Notice::MemberDown { member, reason } => write!(
                f,
                "the bond dropped {member}: {reason}; what it held is sent again over the others"
            ),
        }
    }
}

/// UDP on any address; the peer is fixed, or learnt from the first datagram.
pub struct Udp {
    socket: UdpSocket,
    peer: Option<SocketAddr>,
    mtu: usize,
    nonblocking: bool,
}

impl Udp {
    /// Binds `local`; sends to `peer` (or to whoever sends first).
    pub fn bind(local: SocketAddr, peer: Option<SocketAddr>, mtu: usize) -> io::Result<Self> {
        Ok(Udp {
            socket: UdpSocket::bind(local)?,
            peer,
            mtu,
            nonblocking: false,
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.socket.local_addr()
    }
}

impl Transport for Udp {
    fn send(&mut self, packet: &[u8]) -> io::Result<()> {
        match self.peer {
            Some(p) => self.socket.send_to(packet, p).map(|_| ()),
            None => Ok(()), // nobody to talk to yet: like a radio with no peer in range
        }
    }

    /// A zero timeout reads without blocking: the socket's read timeout
    /// counts in scheduler ticks (4 ms and more), far too long to take in
    /// ACKs between segments.
    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
        let nonblocking = timeout.is_zero();
        if nonblocking != self.nonblocking {
            self.socket.set_nonblocking(nonblocking)?;
            self.nonblocking = nonblocking;
        }
        if !nonblocking {
            self.socket.set_read_timeout(Some(timeout))?;
        }
        let mut buf = [0u8; 2048];
        match self.socket.recv_from(&mut buf) {
            Ok((n, from)) => {
                if self.peer.is_none() {
                    self.peer = Some(from);
                }
                Ok((Some(from) == self.peer).then(|| buf[..n].to_vec()))
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }

    fn mtu(&self) -> usize {
        self.mtu
    }

    fn describe(&self) -> String {
        format!(
            "udp:{}",
            self.socket
                .local_addr()
                .map_or("?".into(), |a| a.to_string())
        )
    }
}

/// Two transports: traffic goes over the primary until it stays silent for
/// `silence` after we sent, then over the secondary; the first packet heard
/// on the primary again switches back. The ARQ above keeps the message
/// stream intact across switches.
pub struct Fallback {
    links: [Box<dyn Transport>; 2],
    active: usize,
    silence: Duration,
    last_heard: Instant,
    last_sent: Option<Instant>,
    /// Every switch, as "primary->secondary" or "secondary->primary".
    pub switches: Vec<String>,
    notices: Vec<Notice>,
}

impl Fallback {
    /// Primary and secondary, switching after `silence` without an answer.
    pub fn new(
        primary: Box<dyn Transport>,
        secondary: Box<dyn Transport>,
        silence: Duration,
    ) -> Self {
        Fallback {
            links: [primary, secondary],
            active: 0,
            silence,
            last_heard: Instant::now(),
            last_sent: None,
            switches: Vec::new(),
            notices: Vec::new(),
        }
    }

    /// 0 for the primary, 1 for the secondary.
    pub fn active(&self) -> usize {
        self.active
    }

    fn switch_to(&mut self, to: usize) {
        if self.active != to {
            let names = ["primary", "secondary"];
            self.switches
                .push(format!("{}->{}", names[self.active], names[to]));
            self.notices.push(Notice::Switched {
                from: self.links[self.active].describe(),
                to: self.links[to].describe(),
            });
            self.active = to;
            self.last_heard = Instant::now();
        }
    }
}

impl Transport for Fallback {
    fn send(&mut self, packet: &[u8]) -> io::Result<()> {
        let now = Instant::now();
        if self.active == 0
            && self.last_sent.is_some()
            && now.duration_since(self.last_heard) > self.silence
        {
            self.switch_to(1);
        }
        self.last_sent = Some(now);
        let r = self.links[self.active].send(packet);
        if r.is_err() && self.active == 0 {
            self.switch_to(1);
            return self.links[1].send(packet);
        }
        r
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
        let half = timeout / 2;
        // Listen on the primary first: it wins back the traffic when it answers.
        if let Ok(Some(p)) = self.links[0].recv(if self.active == 0 {
            timeout - half
        } else {
            half
        }) {
            self.last_heard = Instant::now();
            self.switch_to(0);
            return Ok(Some(p));
        }
        match self.links[1].recv(half)? {
            Some(p) => {
                if self.active == 1 {
                    self.last_heard = Instant::now();
                } else if Instant::now().duration_since(self.last_heard) > self.silence {
                    self.switch_to(1);
                }
                Ok(Some(p))
            }
            None => Ok(None),
        }
    }

    fn mtu(&self) -> usize {
        self.links[0].mtu().min(self.links[1].mtu())
    }

    fn packet_time(&self) -> Option<Duration> {
        self.links[0].packet_time().max(self.links[1].packet_time())
    }

    fn describe(&self) -> String {
        format!(
            "fallback:{},{}",
            self.links[0].describe(),
            self.links[1].describe()
        )
    }

    /// The primary's statistics (the radio, usually).
    fn stats(&self) -> LinkStats {
        self.links[0].stats()
    }

    fn take_notices(&mut self) -> Vec<Notice> {
        let mut notices = core::mem::take(&mut self.notices);
        notices.extend(self.links[0].take_notices());
        notices.extend(self.links[1].take_notices());
        notices
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::endpoint::Endpoint;

    fn udp() -> Udp {
        Udp::bind("127.0.0.1:0".parse().unwrap(), None, 100).unwrap()
    }

    /// The primary carries nothing (its peer is absent), so the sender falls
    /// back to the secondary; the message stream arrives intact, the switch is
    /// reported, and the first packet heard on the primary switches back.
    #[test]
    fn fallback_switches_to_the_secondary_and_back() {
        let (dead, mut peer_secondary) = (udp(), udp());
        let secondary = Udp::bind(
            "127.0.0.1:0".parse().unwrap(),
            Some(peer_secondary.local_addr().unwrap()),
            100,
        )
        .unwrap();
        peer_secondary.peer = Some(secondary.local_addr().unwrap());
        let fallback = Fallback::new(
            Box::new(dead),
            Box::new(secondary),
            Duration::from_millis(100),
        );
        let rx = std::thread::spawn(move || {
            let mut e = Endpoint::new(Box::new(peer_secondary)).unwrap();
            let got: Vec<Vec<u8>> = (0..2)
                .map(|_| e.recv_message(Duration::from_secs(20)).unwrap())
                .collect();
            e.linger(Duration::from_millis(300)).unwrap();
            got
        });
        let mut ep = Endpoint::new(Box::new(fallback)).unwrap();
        let msgs = [vec![7u8; 3000], vec![9u8; 500]];
        for m in &msgs {
            ep.send_message(m).unwrap();
        }
        assert_eq!(rx.join().unwrap(), msgs.to_vec());
        // The primary speaks again: one packet there switches traffic back.
        let primary = udp();
        let primary_addr = primary.local_addr().unwrap();
        let mut fb = Fallback::new(
            Box::new(primary),
            Box::new(udp()),
            Duration::from_millis(10),
        );
        fb.active = 1;
        UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .send_to(b"hello", primary_addr)
            .unwrap();
        assert_eq!(
            fb.recv(Duration::from_millis(200)).unwrap(),
            Some(b"hello".to_vec())
        );
        assert_eq!(fb.active(), 0);
        assert_eq!(fb.switches, vec!["secondary->primary".to_string()]);
        let said = fb.take_notices();
        assert!(
            matches!(&said[..], [Notice::Switched { from, to }] if from.starts_with("udp") && to.starts_with("udp")),
            "{said:?}"
        );
        assert!(fb.take_notices().is_empty(), "said once");
    }
}
