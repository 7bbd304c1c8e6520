//! Transports carry link segments (one packet each, at most `mtu` bytes):
//! a serial port to an XBee radio (API mode 1/2 or transparent mode), a UDP
//! socket (the IP fallback), and [`Fallback`], which switches between two.

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use crate::radio::{self, Address, Firmware};

/// Whether a serial read failed only because no byte came in time (or a
/// signal interrupted it): the caller waits on, it is not an error.
pub(crate) fn no_data_yet(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut | io::ErrorKind::Interrupted
    )
}
use crate::slip;
use crate::xbee::{ApiMode, Frame, Parser};

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
}

/// UDP on any address; the peer is fixed, or learnt from the first datagram.
pub struct Udp {
    socket: UdpSocket,
    peer: Option<SocketAddr>,
    mtu: usize,
}

impl Udp {
    /// Binds `local`; sends to `peer` (or to whoever sends first).
    pub fn bind(local: SocketAddr, peer: Option<SocketAddr>, mtu: usize) -> io::Result<Self> {
        Ok(Udp {
            socket: UdpSocket::bind(local)?,
            peer,
            mtu,
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

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
        self.socket
            .set_read_timeout(Some(timeout.max(Duration::from_micros(100))))?;
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

/// How packets travel over a serial line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SerialFraming {
    /// XBee API frames: packets go out as the transmit request `firmware`
    /// takes ([`radio::transmit_request`]) to `dest`, and come in as RX frames.
    Api {
        mode: ApiMode,
        firmware: Firmware,
        dest: Address,
    },
    /// Transparent (AT) mode or a plain USB cable: SLIP frames with a CRC-16.
    Transparent,
}

/// A serial port to an XBee radio or a USB cable.
pub struct Serial<P> {
    port: P,
    framing: SerialFraming,
    parser: Parser,
    deframer: slip::Deframer,
    ready: VecDeque<Vec<u8>>,
    mtu: usize,
    name: String,
    /// Frames or packets dropped as damaged (for link statistics).
    pub damaged: u64,
    /// Transmit status frames (0x89 / 0x8B) reporting a failed delivery.
    pub tx_failed: u64,
    next_frame_id: u8,
}

impl<P: Read + Write + Send> Serial<P> {
    /// Wraps an open port (its read timeout should be short, e.g. 1 ms: a
    /// zero-timeout receive costs one read).
    pub fn new(port: P, framing: SerialFraming, mtu: usize, name: impl Into<String>) -> Self {
        let mode = match framing {
            SerialFraming::Api { mode, .. } => mode,
            SerialFraming::Transparent => ApiMode::Plain,
        };
        Serial {
            port,
            framing,
            parser: Parser::new(mode),
            deframer: slip::Deframer::new(mtu.max(1) + 16),
            ready: VecDeque::new(),
            mtu,
            name: name.into(),
            damaged: 0,
            tx_failed: 0,
            next_frame_id: 1,
        }
    }

    fn feed(&mut self, bytes: &[u8]) {
        for &b in bytes {
            match self.framing {
                SerialFraming::Api { .. } => match self.parser.push(b) {
                    Some(Ok(Frame::TxStatus { status, .. }))
                    | Some(Ok(Frame::ZbTxStatus {
                        delivery: status, ..
                    })) => self.tx_failed += u64::from(status != 0),
                    Some(Ok(frame)) => {
                        if let (Some(p), false) = (
                            frame.payload(),
                            matches!(
                                frame,
                                Frame::Tx16 { .. } | Frame::Tx64 { .. } | Frame::ZbTx { .. }
                            ),
                        ) {
                            self.ready.push_back(p.to_vec());
                        }
                    }
                    Some(Err(_)) => self.damaged += 1,
                    None => {}
                },
                SerialFraming::Transparent => match self.deframer.push(b) {
                    Some(Ok(p)) => self.ready.push_back(p),
                    Some(Err(_)) => self.damaged += 1,
                    None => {}
                },
            }
        }
    }
}

impl<P: Read + Write + Send> Transport for Serial<P> {
    fn send(&mut self, packet: &[u8]) -> io::Result<()> {
        let bytes = match self.framing {
            SerialFraming::Api {
                mode,
                firmware,
                dest,
            } => {
                // Frame ids 1..=255: the radio answers each with a status.
                let id = self.next_frame_id;
                self.next_frame_id = id.checked_add(1).unwrap_or(1);
                radio::transmit_request(firmware, dest, id, packet).encode(mode)
            }
            SerialFraming::Transparent => slip::encode(packet),
        };
        self.port.write_all(&bytes)?;
        self.port.flush()
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
        let until = Instant::now() + timeout;
        let mut buf = [0u8; 512];
        loop {
            if let Some(p) = self.ready.pop_front() {
                return Ok(Some(p));
            }
            match self.port.read(&mut buf) {
                Ok(0) => {}
                Ok(n) => {
                    self.feed(&buf[..n]);
                    continue;
                }
                Err(e) if no_data_yet(&e) => {}
                Err(e) => return Err(e),
            }
            if Instant::now() >= until {
                return Ok(None);
            }
        }
    }

    fn mtu(&self) -> usize {
        self.mtu
    }

    fn describe(&self) -> String {
        self.name.clone()
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
            eprintln!(
                "link: switching from {} to {}",
                self.links[self.active].describe(),
                self.links[to].describe()
            );
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

    fn describe(&self) -> String {
        format!(
            "fallback:{},{}",
            self.links[0].describe(),
            self.links[1].describe()
        )
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
    }
}
