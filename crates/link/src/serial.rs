//! A serial port to an XBee radio in API mode, or to a USB cable or a radio
//! in transparent mode (SLIP frames with a CRC-16).
//!
//! In API mode each packet goes out as the transmit request the radio's
//! firmware takes ([`radio::transmit_request`]) with a frame id ≠ 0, and
//! [`Pacing`] keeps at most a few of them at the radio, each waiting for its
//! transmit status, so the radio's small serial buffer is never overrun. The
//! radio's answers are acted on: failures are resent and counted by cause, a
//! payload it calls too large is an error naming `NP`, a reset (modem status
//! 0x8A) sends again what it held, and transmit requests heard from the
//! other end (no radio between) are said once ([`Notice`]).

use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::time::{Duration, Instant};

use crate::arq::Micros;
use crate::pacing::{Pacing, PacingConfig, StatusAction};
use crate::radio::{self, Address, Firmware};
use crate::slip;
use crate::throughput::RadioPath;
use crate::transport::{no_data_yet, LinkStats, Notice, Transport};
use crate::xbee::{ApiMode, Frame, Parser};

/// How packets travel over a serial line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SerialFraming {
    /// XBee API frames: packets go out as the transmit request `firmware`
    /// takes ([`radio::transmit_request`]) to `dest`, and come in as RX frames.
    Api {
        /// API mode 1, or 2 with escaped bytes.
        mode: ApiMode,
        /// The radio's firmware: which transmit request it takes.
        firmware: Firmware,
        /// The peer radio's address.
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
    epoch: Instant,
    pacing: Pacing,
    stats: LinkStats,
    notices: Vec<Notice>,
    /// Kinds of notice already given (each is said once).
    said: Vec<std::mem::Discriminant<Notice>>,
    failures_said: Vec<u8>,
    /// An error to return from the next call (the radio refused a payload).
    fatal: Option<io::Error>,
    /// The air time of a full packet, when the radio's path is known.
    packet_time: Option<Duration>,
}

impl<P: Read + Write + Send> Serial<P> {
    /// Wraps an open port (its read timeout should be short, e.g. 1 ms: a
    /// zero-timeout receive costs one read), with the default pacing.
    pub fn new(port: P, framing: SerialFraming, mtu: usize, name: impl Into<String>) -> Self {
        Self::with_pacing(port, framing, mtu, name, PacingConfig::default())
    }

    /// Wraps an open port with explicit pacing parameters (API mode only).
    pub fn with_pacing(
        port: P,
        framing: SerialFraming,
        mtu: usize,
        name: impl Into<String>,
        pacing: PacingConfig,
    ) -> Self {
        let (mode, radio) = match framing {
            SerialFraming::Api { mode, .. } => (mode, true),
            SerialFraming::Transparent => (ApiMode::Plain, false),
        };
        Serial {
            port,
            framing,
            parser: Parser::new(mode),
            deframer: slip::Deframer::new(mtu.max(1) + 16),
            ready: VecDeque::new(),
            mtu,
            name: name.into(),
            epoch: Instant::now(),
            pacing: Pacing::new(pacing),
            stats: LinkStats {
                radio: radio.then(Default::default),
                ..LinkStats::default()
            },
            notices: Vec::new(),
            said: Vec::new(),
            failures_said: Vec::new(),
            fatal: None,
            packet_time: None,
        }
    }

    /// The same link, with the radio's path known: its packets' air time
    /// seeds the ARQ's first retransmission timeout.
    pub fn on_path(mut self, path: RadioPath) -> Self {
        self.packet_time = path
            .packet_us(self.mtu, self.mtu)
            .map(|us| Duration::from_secs_f64(us / 1e6));
        self
    }

    fn now(&self) -> Micros {
        self.epoch.elapsed().as_micros() as Micros
    }

    /// Queues `notice` unless one of its kind was already given.
    fn say_once(&mut self, notice: Notice) {
        let kind = std::mem::discriminant(&notice);
        if !self.said.contains(&kind) {
            self.said.push(kind);
            self.notices.push(notice);
        }
    }

    fn write_request(&mut self, frame_id: u8, packet: &[u8]) -> io::Result<()> {
        let SerialFraming::Api {
            mode,
            firmware,
            dest,
        } = self.framing
        else {
            return Ok(());
        };
        let bytes = radio::transmit_request(firmware, dest, frame_id, packet).encode(mode);
        self.port.write_all(&bytes)?;
        self.port.flush()
    }

    /// Acts on a transmit status from the radio.
    fn on_status(&mut self, frame_id: u8, status: u8) -> io::Result<()> {
        match self.pacing.on_status(frame_id, status, self.now()) {
            StatusAction::Settled => {}
            StatusAction::Resend {
                status,
                frame_id,
                packet,
            } => {
                if !self.failures_said.contains(&status) {
                    self.failures_said.push(status);
                    self.notices.push(Notice::DeliveryFailed { status });
                }
                self.write_request(frame_id, &packet)?;
            }
            StatusAction::TooLarge { len } => {
                self.fatal = Some(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!(
                        "{}: the radio refused a {len}-byte payload as too large (status 0x74); \
                         its NP is smaller than mtu={} (encryption or source routing shrink it): \
                         give a smaller mtu= in the link spec",
                        self.name, self.mtu
                    ),
                ))
            }
            StatusAction::Stray => self.say_once(Notice::StrayStatus { frame_id }),
        }
        Ok(())
    }

    /// Acts on one API frame from the radio.
    fn on_frame(&mut self, frame: Frame) -> io::Result<()> {
        match frame {
            Frame::TxStatus { frame_id, status } => self.on_status(frame_id, status)?,
            Frame::ZbTxStatus {
                frame_id, delivery, ..
            } => self.on_status(frame_id, delivery)?,
            Frame::ModemStatus {
                status: s @ (0 | 1),
            } => {
                let again = self.pacing.on_reset(self.now());
                self.notices.push(Notice::RadioReset {
                    status: s,
                    resent: again.len(),
                });
                for (frame_id, packet) in again {
                    self.write_request(frame_id, &packet)?;
                }
            }
            Frame::ModemStatus { status } => self.notices.push(Notice::ModemStatus { status }),
            Frame::Tx16 { .. } | Frame::Tx64 { .. } | Frame::ZbTx { .. } => {
                self.stats.foreign_requests += 1;
                self.say_once(Notice::ForeignRequests);
            }
            Frame::Rx16 { rssi, data, .. } | Frame::Rx64 { rssi, data, .. } => {
                self.stats.rssi_dbm = Some(-i16::from(rssi));
                self.ready.push_back(data);
            }
            Frame::ZbRx { data, .. } => self.ready.push_back(data),
            Frame::AtCommand { .. } | Frame::AtResponse { .. } | Frame::Unknown { .. } => {}
        }
        Ok(())
    }

    fn feed(&mut self, bytes: &[u8]) -> io::Result<()> {
        for &b in bytes {
            match self.framing {
                SerialFraming::Api { .. } => match self.parser.push(b) {
                    Some(Ok(frame)) => self.on_frame(frame)?,
                    Some(Err(_)) => self.stats.damaged += 1,
                    None => {}
                },
                SerialFraming::Transparent => match self.deframer.push(b) {
                    Some(Ok(p)) => self.ready.push_back(p),
                    Some(Err(_)) => self.stats.damaged += 1,
                    None => {}
                },
            }
        }
        Ok(())
    }

    /// Reads what the port has (waiting at most its read timeout).
    fn read_some(&mut self) -> io::Result<()> {
        let mut buf = [0u8; 512];
        match self.port.read(&mut buf) {
            Ok(n) => self.feed(&buf[..n]),
            Err(e) if no_data_yet(&e) => Ok(()),
            Err(e) => Err(e),
        }
    }

    fn check_fatal(&mut self) -> io::Result<()> {
        self.fatal.take().map_or(Ok(()), Err)
    }

    /// Forgets requests whose status is overdue, saying so the first time.
    fn expire(&mut self) {
        if self.pacing.expire(self.now()) > 0 {
            let timeout = Duration::from_micros(self.pacing.config().status_timeout);
            self.say_once(Notice::NoStatus { timeout });
        }
    }
}

impl<P: Read + Write + Send> Transport for Serial<P> {
    /// In API mode, waits (reading the port) until the radio has room for
    /// another request: a status came back, or the oldest request timed out.
    fn send(&mut self, packet: &[u8]) -> io::Result<()> {
        if self.framing == SerialFraming::Transparent {
            self.port.write_all(&slip::encode(packet))?;
            return self.port.flush();
        }
        loop {
            self.check_fatal()?;
            self.expire();
            if self.pacing.has_room() {
                break;
            }
            self.read_some()?;
        }
        let frame_id = self.pacing.push(packet, self.now());
        self.write_request(frame_id, packet)
    }

    fn recv(&mut self, timeout: Duration) -> io::Result<Option<Vec<u8>>> {
        let until = Instant::now() + timeout;
        loop {
            if let Some(p) = self.ready.pop_front() {
                return Ok(Some(p));
            }
            self.read_some()?;
            self.check_fatal()?;
            self.expire();
            if self.ready.is_empty() && Instant::now() >= until {
                return Ok(None);
            }
        }
    }

    fn mtu(&self) -> usize {
        self.mtu
    }

    fn packet_time(&self) -> Option<Duration> {
        self.packet_time
    }

    fn describe(&self) -> String {
        self.name.clone()
    }

    fn stats(&self) -> LinkStats {
        LinkStats {
            radio: self
                .stats
                .radio
                .as_ref()
                .map(|_| self.pacing.counters().clone()),
            ..self.stats.clone()
        }
    }

    fn take_notices(&mut self) -> Vec<Notice> {
        std::mem::take(&mut self.notices)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One end of an in-memory serial line: what the host writes is kept,
    /// what the "radio" says is read back.
    #[derive(Default)]
    struct Line {
        written: Vec<u8>,
        incoming: VecDeque<u8>,
    }

    impl Read for Line {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            if self.incoming.is_empty() {
                return Err(io::ErrorKind::TimedOut.into());
            }
            let n = buf.len().min(self.incoming.len());
            for (b, v) in buf.iter_mut().zip(self.incoming.drain(..n)) {
                *b = v;
            }
            Ok(n)
        }
    }

    impl Write for Line {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.written.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    fn zigbee(line: Line) -> Serial<Line> {
        let framing = SerialFraming::Api {
            mode: ApiMode::Escaped,
            firmware: Firmware::Zigbee,
            dest: Address::Long(0x0013_A200_4000_0001),
        };
        Serial::new(line, framing, 84, "test")
    }

    /// The transmit requests the host wrote, parsed.
    fn requests(s: &mut Serial<Line>) -> Vec<Frame> {
        let mut parser = Parser::new(ApiMode::Escaped);
        let frames = s
            .port
            .written
            .drain(..)
            .filter_map(|b| parser.push(b))
            .map(Result::unwrap)
            .collect();
        frames
    }

    fn status(frame_id: u8, delivery: u8) -> Vec<u8> {
        Frame::ZbTxStatus {
            frame_id,
            dest16: 0xFFFE,
            retries: 0,
            delivery,
            discovery: 0,
        }
        .encode(ApiMode::Escaped)
    }

    #[test]
    fn a_network_ack_failure_is_resent_at_once_and_counted() {
        let mut s = zigbee(Line::default());
        s.send(b"fragment").unwrap();
        let sent = requests(&mut s);
        let id = sent[0].frame_id().unwrap();
        assert_ne!(id, 0, "a status must be requested");
        s.port.incoming.extend(status(id, 0x21));
        assert_eq!(s.recv(Duration::ZERO).unwrap(), None);
        let again = requests(&mut s);
        assert_eq!(again.len(), 1);
        assert_eq!(again[0].payload(), Some(&b"fragment"[..]));
        let stats = s.stats();
        let radio = stats.radio.as_ref().unwrap();
        assert_eq!((radio.resent, radio.failures.clone()), (1, vec![(0x21, 1)]));
        assert!(stats.to_string().contains("0x21 network ACK failure"));
        assert_eq!(
            s.take_notices(),
            vec![Notice::DeliveryFailed { status: 0x21 }]
        );
    }

    #[test]
    fn sends_wait_for_room_at_the_radio() {
        let mut s = zigbee(Line::default());
        s.send(b"a").unwrap();
        s.send(b"b").unwrap();
        let ids: Vec<u8> = requests(&mut s)
            .iter()
            .map(|f| f.frame_id().unwrap())
            .collect();
        // The third send can only go once a status frees a place.
        s.port.incoming.extend(status(ids[0], 0));
        s.send(b"c").unwrap();
        assert_eq!(requests(&mut s).len(), 1);
        assert_eq!(s.stats().radio.unwrap().delivered, 1);
    }

    #[test]
    fn payload_too_large_is_an_error_naming_mtu() {
        let mut s = zigbee(Line::default());
        s.send(&[7; 80]).unwrap();
        let id = requests(&mut s)[0].frame_id().unwrap();
        s.port.incoming.extend(status(id, 0x74));
        let e = s.recv(Duration::ZERO).unwrap_err();
        assert!(e.to_string().contains("mtu="), "{e}");
    }

    #[test]
    fn a_reset_mid_stream_sends_again_what_the_radio_held() {
        let mut s = zigbee(Line::default());
        s.send(b"one").unwrap();
        s.send(b"two").unwrap();
        requests(&mut s);
        s.port
            .incoming
            .extend(Frame::ModemStatus { status: 0 }.encode(ApiMode::Escaped));
        s.port.incoming.extend(status(250, 0));
        assert_eq!(s.recv(Duration::ZERO).unwrap(), None);
        let again: Vec<Vec<u8>> = requests(&mut s)
            .iter()
            .map(|f| f.payload().unwrap().to_vec())
            .collect();
        assert_eq!(again, vec![b"one".to_vec(), b"two".to_vec()]);
        let notices = s.take_notices();
        assert!(notices.contains(&Notice::RadioReset {
            status: 0,
            resent: 2
        }));
        assert!(notices.contains(&Notice::StrayStatus { frame_id: 250 }));
        assert_eq!(s.stats().radio.unwrap().resets, 1);
    }

    #[test]
    fn transmit_requests_from_the_other_end_are_said_once() {
        let mut s = zigbee(Line::default());
        for _ in 0..3 {
            let request = radio::transmit_request(Firmware::Zigbee, Address::BROADCAST, 1, b"x");
            s.port.incoming.extend(request.encode(ApiMode::Escaped));
        }
        assert_eq!(s.recv(Duration::ZERO).unwrap(), None);
        assert_eq!(s.take_notices(), vec![Notice::ForeignRequests]);
        assert_eq!(s.stats().foreign_requests, 3);
    }

    #[test]
    fn rssi_comes_from_802154_rx_frames() {
        let framing = SerialFraming::Api {
            mode: ApiMode::Escaped,
            firmware: Firmware::Ieee802154,
            dest: Address::Short(2),
        };
        let mut s = Serial::new(Line::default(), framing, 100, "test");
        let rx = Frame::Rx16 {
            source: 2,
            rssi: 0x28,
            options: 0,
            data: b"seg".to_vec(),
        };
        s.port.incoming.extend(rx.encode(ApiMode::Escaped));
        assert_eq!(s.recv(Duration::ZERO).unwrap(), Some(b"seg".to_vec()));
        assert_eq!(s.stats().rssi_dbm, Some(-40));
    }
}
