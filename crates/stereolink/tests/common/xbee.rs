//! An emulated pair of XBee radios in API mode 2 between two pseudo-terminals,
//! behaving as Digi's 802.15.4 and Zigbee manuals describe for what the tests
//! exercise:
//!
//! * local AT queries (0x08) are answered with 0x88 from a [`Config`]:
//!   `AP VR HV NP MY SH SL CH ID` (and `OP` on Zigbee); any other command,
//!   or a command with a parameter (we emulate no settings), gets status 2
//!   "invalid command";
//! * each firmware accepts only its own transmit requests, 802.15.4 TX16
//!   0x01 / TX64 0x00, Zigbee 0x10, and ignores other API frame types
//!   without an answer (the manuals: a frame type the firmware does not
//!   support is discarded); the count of ignored frames is kept;
//! * a transmit request with frame id ≠ 0 is answered with its status: 0x89
//!   (0 success, 1 no ACK) or 0x8B (0 success, 0x24 address not found);
//!   the peer receives RX16 0x81 / RX64 0x80 or receive packet 0x90 with the
//!   sender's addresses. A broadcast always succeeds;
//! * with [`Timing`] ([`RadioLink::timed`]), the host's bytes come in at the
//!   UART's rate into a bounded serial receive buffer, and each transmit
//!   request leaves it only when the one before has had its air time (the
//!   link crate's model calibrated to Digi's measured throughput), its
//!   transmit status answered when that air time ends: a host
//!   that writes faster than the air carries overruns the buffer, and, as
//!   the manuals say happens with CTS ignored, the bytes that do not fit are
//!   lost (the frame they belong to fails its checksum and is discarded);
//! * [`RadioLink::timed_with_reset`] resets the first radio once, as a
//!   brown-out or its watchdog would: the requests it held are lost with no
//!   status, and it tells its host with modem status 0x8A "hardware reset"
//!   (0x00), then on Zigbee "joined network" (0x02).

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::TTYPort;
use stereolink_link::sim::SimConfig;
use stereolink_link::xbee::{ApiMode, Frame, Parser};

/// The firmware an emulated radio runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Firmware {
    /// XBee 802.15.4 (Series 1, VR 10EF).
    Ieee802154,
    /// XBee Zigbee (Series 2 router API, VR 23A7).
    Zigbee,
}

/// What one emulated radio reports.
#[derive(Clone, Debug)]
pub struct Config {
    pub firmware: Firmware,
    pub vr: u16,
    pub hv: u16,
    pub np: u16,
    pub my: u16,
    pub serial: u64,
    pub channel: u8,
    pub pan: u64,
}

impl Config {
    /// Radio number `n` (0 or 1) of a pair with `firmware`: distinct
    /// addresses, the same channel and PAN.
    pub fn new(firmware: Firmware, n: u8) -> Config {
        let serial = 0x0013_A200_40A1_B2C0 + u64::from(n);
        match firmware {
            Firmware::Ieee802154 => Config {
                firmware,
                vr: 0x10EF,
                hv: 0x1746,
                np: 100,
                my: 0x0001 + u16::from(n),
                serial,
                channel: 0x0C,
                pan: 0x3332,
            },
            Firmware::Zigbee => Config {
                firmware,
                vr: 0x23A7,
                hv: 0x1E46,
                np: 84,
                my: 0x7D84 + u16::from(n),
                serial,
                channel: 0x0F,
                pan: 0x2345,
            },
        }
    }

    /// The value of a query, as many bytes as the radio sends.
    fn at(&self, command: [u8; 2]) -> Option<Vec<u8>> {
        let zigbee = self.firmware == Firmware::Zigbee;
        Some(match &command {
            b"AP" => vec![2],
            b"VR" => self.vr.to_be_bytes().to_vec(),
            b"HV" => self.hv.to_be_bytes().to_vec(),
            b"NP" => self.np.to_be_bytes().to_vec(),
            b"MY" => self.my.to_be_bytes().to_vec(),
            b"SH" => ((self.serial >> 32) as u32).to_be_bytes().to_vec(),
            b"SL" => (self.serial as u32).to_be_bytes().to_vec(),
            b"CH" => vec![self.channel],
            b"ID" if zigbee => self.pan.to_be_bytes().to_vec(),
            b"ID" => (self.pan as u16).to_be_bytes().to_vec(),
            b"OP" if zigbee => self.pan.to_be_bytes().to_vec(),
            _ => return None,
        })
    }
}

/// Counters of one emulated radio.
#[derive(Debug, Default)]
pub struct Counters {
    /// API frames of a type its firmware does not take.
    pub ignored: AtomicUsize,
    /// Frames handed to the peer.
    pub delivered: AtomicUsize,
    /// The largest payload handed to the peer.
    pub largest: AtomicUsize,
    /// Host bytes lost because the serial receive buffer was full.
    pub overrun: AtomicUsize,
    /// Resets.
    pub resets: AtomicUsize,
}

/// The modem status frames a radio sends its host when it restarts: 0x8A
/// "hardware reset" (0x00), then on ZigBee "joined network" (0x02).
fn reset_announcements(firmware: Firmware) -> Vec<u8> {
    let mut wire = Frame::ModemStatus { status: 0x00 }.encode(ApiMode::Escaped);
    if firmware == Firmware::Zigbee {
        wire.extend(Frame::ModemStatus { status: 0x02 }.encode(ApiMode::Escaped));
    }
    wire
}

/// The rates and buffer of a timed radio: the link crate's calibrated
/// model ([`SimConfig`]: its baud rate, serial buffer, and the air time
/// each packet takes for its firmware, hops and security, after Digi's
/// measured throughput), so the emulator and `sim:` carry the same.
#[derive(Clone, Copy, Debug)]
pub struct Timing(pub SimConfig);

impl Timing {
    /// ZigBee, one hop router to router, no security, at 115200 baud:
    /// Digi's 35 kb/s, so an 84-byte payload takes 19.2 ms on the air, more
    /// than the 8.9 ms its 102-byte request takes on the UART.
    pub fn zigbee() -> Timing {
        Timing(SimConfig {
            radio: stereolink_link::radio::Firmware::Zigbee,
            mtu: 84,
            ..SimConfig::default()
        })
    }

    /// The air time of a transmit request carrying `payload` bytes.
    fn air(&self, payload: usize) -> Duration {
        Duration::from_secs_f64(self.0.packet_air_us(payload) / 1e6)
    }
}

/// One radio: reads its host's frames from `host`, answers on `answer`,
/// delivers to the peer host on `peer` (`None`: no peer in range).
struct Radio {
    me: Config,
    peer: Option<(Config, TTYPort)>,
    corrupt_one_in: Option<u32>,
    salt: u32,
    counters: Arc<Counters>,
    timing: Option<Timing>,
    /// Reset (as on a brown-out or a watchdog) after taking this many
    /// transmit requests from the host.
    reset_after: Option<usize>,
}

impl Radio {
    /// The frame the peer receives for a request, or `None` when the request
    /// does not reach it; and whether it was a broadcast.
    fn route(&self, frame: Frame) -> (Option<Frame>, bool) {
        let Some((peer, _)) = &self.peer else {
            return (None, false);
        };
        let (rssi, me) = (0x28, &self.me);
        match frame {
            Frame::Tx16 { dest, data, .. } => {
                let broadcast = dest == 0xFFFF;
                let ok = broadcast || dest == peer.my;
                let options = if broadcast { 2 } else { 0 };
                let rx = Frame::Rx16 {
                    source: me.my,
                    rssi,
                    options,
                    data,
                };
                (ok.then_some(rx), broadcast)
            }
            Frame::Tx64 { dest, data, .. } => {
                let broadcast = dest == 0xFFFF;
                let ok = broadcast || dest == peer.serial;
                let options = if broadcast { 2 } else { 0 };
                let rx = Frame::Rx64 {
                    source: me.serial,
                    rssi,
                    options,
                    data,
                };
                (ok.then_some(rx), broadcast)
            }
            Frame::ZbTx {
                dest64,
                dest16,
                data,
                ..
            } => {
                let broadcast = dest64 == 0xFFFF;
                let ok =
                    broadcast || dest64 == peer.serial || (dest64 == u64::MAX && dest16 == peer.my);
                let rx = Frame::ZbRx {
                    source64: me.serial,
                    source16: me.my,
                    options: if broadcast { 2 } else { 1 },
                    data,
                };
                (ok.then_some(rx), broadcast)
            }
            _ => (None, false),
        }
    }

    /// What the radio does with one frame from its host: the answer to the
    /// host, if any.
    fn handle(&mut self, frame: Frame, count: &mut u32) -> Option<Frame> {
        let takes = match self.me.firmware {
            Firmware::Ieee802154 => matches!(
                frame,
                Frame::AtCommand { .. } | Frame::Tx16 { .. } | Frame::Tx64 { .. }
            ),
            Firmware::Zigbee => matches!(frame, Frame::AtCommand { .. } | Frame::ZbTx { .. }),
        };
        if !takes {
            self.counters.ignored.fetch_add(1, Ordering::Relaxed);
            return None;
        }
        let frame_id = frame.frame_id().unwrap_or(0);
        if let Frame::AtCommand {
            command, parameter, ..
        } = frame
        {
            let value = parameter.is_empty().then(|| self.me.at(command)).flatten();
            return Some(Frame::AtResponse {
                frame_id,
                command,
                status: if value.is_some() { 0 } else { 2 },
                data: value.unwrap_or_default(),
            });
        }
        let len = frame.payload().map_or(0, <[u8]>::len);
        let (rx, broadcast) = self.route(frame);
        let delivered = rx.is_some();
        if let (Some(rx), Some((_, port))) = (rx, self.peer.as_mut()) {
            let mut wire = rx.encode(ApiMode::Escaped);
            if let Some(every) = self.corrupt_one_in {
                for byte in wire.iter_mut().skip(1) {
                    *count = count.wrapping_add(1);
                    if count.wrapping_mul(2_654_435_761).wrapping_add(self.salt) % every == 0 {
                        *byte ^= 0x10;
                    }
                }
            }
            let _ = port.write_all(&wire);
            self.counters.delivered.fetch_add(1, Ordering::Relaxed);
            self.counters.largest.fetch_max(len, Ordering::Relaxed);
        }
        let ok = delivered || broadcast;
        let status = match self.me.firmware {
            Firmware::Ieee802154 => Frame::TxStatus {
                frame_id,
                status: if ok { 0 } else { 1 },
            },
            Firmware::Zigbee => Frame::ZbTxStatus {
                frame_id,
                dest16: match (&self.peer, delivered) {
                    (Some((peer, _)), true) => peer.my,
                    _ => 0xFFFE,
                },
                retries: 0,
                delivery: if ok { 0 } else { 0x24 },
                discovery: 0,
            },
        };
        (frame_id != 0).then_some(status)
    }

    fn run(self, host: TTYPort, stop: Arc<AtomicBool>) {
        match self.timing {
            Some(t) => self.run_timed(host, stop, t),
            None => self.run_instant(host, stop),
        }
    }

    /// The host's bytes at the UART's rate into the bounded buffer; one
    /// transmit request on the air at a time; AT commands answered at once.
    fn run_timed(mut self, mut host: TTYPort, stop: Arc<AtomicBool>, t: Timing) {
        let mut answer = host.try_clone_native().unwrap();
        let mut parser = Parser::new(ApiMode::Escaped);
        let byte_time = Duration::from_secs_f64(10.0 / t.0.baud as f64);
        let mut uart_clock = Instant::now();
        let (mut partial, mut waiting) = (0usize, VecDeque::<(Frame, usize)>::new());
        let mut on_air: Option<(Frame, Instant)> = None;
        let (mut count, mut taken) = (0u32, 0usize);
        let mut buf = [0u8; 64];
        while !stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            if let Some((frame, _)) = on_air.take_if(|(_, end)| *end <= now) {
                if let Some(reply) = self.handle(frame, &mut count) {
                    let _ = answer.write_all(&reply.encode(ApiMode::Escaped));
                }
            }
            if on_air.is_none() {
                if let Some((frame, _)) = waiting.pop_front() {
                    let payload = frame.payload().map_or(0, <[u8]>::len);
                    on_air = Some((frame, now + t.air(payload)));
                }
            }
            // The UART delivers no faster than its baud rate.
            if uart_clock < now {
                uart_clock = now;
            }
            let ahead = uart_clock.saturating_duration_since(now);
            if ahead > Duration::from_millis(2) {
                std::thread::sleep(Duration::from_micros(500));
                continue;
            }
            let Ok(n) = host.read(&mut buf) else { continue };
            uart_clock += byte_time * n as u32;
            for &b in &buf[..n] {
                let held = partial + waiting.iter().map(|(_, len)| len).sum::<usize>();
                if held >= t.0.buffer {
                    self.counters.overrun.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                partial += 1;
                match parser.push(b) {
                    Some(Ok(frame @ Frame::AtCommand { .. })) => {
                        partial = 0;
                        if let Some(reply) = self.handle(frame, &mut count) {
                            let _ = answer.write_all(&reply.encode(ApiMode::Escaped));
                        }
                    }
                    Some(Ok(frame)) => {
                        waiting.push_back((frame, std::mem::take(&mut partial)));
                        taken += 1;
                        if self.reset_after == Some(taken) {
                            // What the radio held is lost without a status;
                            // it announces the restart, and a ZigBee router
                            // that it joined the network again.
                            (waiting, on_air, partial) = (VecDeque::new(), None, 0);
                            parser = Parser::new(ApiMode::Escaped);
                            self.counters.resets.fetch_add(1, Ordering::Relaxed);
                            let _ = answer.write_all(&reset_announcements(self.me.firmware));
                            break;
                        }
                    }
                    Some(Err(_)) => partial = 0,
                    None => {}
                }
            }
        }
    }

    fn run_instant(mut self, mut host: TTYPort, stop: Arc<AtomicBool>) {
        let mut answer = host.try_clone_native().unwrap();
        let mut parser = Parser::new(ApiMode::Escaped);
        let mut buf = [0u8; 256];
        let mut count = 0u32;
        while !stop.load(Ordering::Relaxed) {
            let Ok(n) = host.read(&mut buf) else { continue };
            for &b in &buf[..n] {
                if let Some(Ok(frame)) = parser.push(b) {
                    if let Some(reply) = self.handle(frame, &mut count) {
                        let _ = answer.write_all(&reply.encode(ApiMode::Escaped));
                    }
                }
            }
        }
    }
}

/// Two pty pairs, each with an emulated radio on its master side, in range
/// of each other (or, with [`RadioLink::single`], one radio alone): the
/// slave device paths, the radios' configurations and counters, and a guard
/// that stops the radios when dropped.
pub struct RadioLink {
    /// Device path of the first side.
    pub a: String,
    /// Device path of the second side (empty for a single radio).
    pub b: String,
    /// The radios' configurations.
    pub configs: Vec<Config>,
    /// The radios' counters.
    pub counters: Vec<Arc<Counters>>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    _slaves: Vec<TTYPort>,
}

fn pty() -> (TTYPort, TTYPort) {
    use serialport::SerialPort;
    let (mut master, slave) = TTYPort::pair().unwrap();
    master
        .set_timeout(std::time::Duration::from_millis(5))
        .unwrap();
    (master, slave)
}

impl RadioLink {
    /// Two radios with `firmware`; with `corrupt_one_in = Some(n)`, about one
    /// delivered byte in n is flipped, so the link's CRCs must catch it.
    pub fn new(firmware: Firmware, corrupt_one_in: Option<u32>) -> Self {
        Self::build(firmware, corrupt_one_in, None, None)
    }

    /// Two radios with `firmware` and the rates and buffer of `timing`.
    pub fn timed(firmware: Firmware, timing: Timing) -> Self {
        Self::build(firmware, None, Some(timing), None)
    }

    /// As [`RadioLink::timed`], and the first radio resets once, after
    /// taking `after` transmit requests from its host.
    pub fn timed_with_reset(firmware: Firmware, timing: Timing, after: usize) -> Self {
        Self::build(firmware, None, Some(timing), Some(after))
    }

    fn build(
        firmware: Firmware,
        corrupt_one_in: Option<u32>,
        timing: Option<Timing>,
        reset_after: Option<usize>,
    ) -> Self {
        use serialport::SerialPort;
        let ((m1, s1), (m2, s2)) = (pty(), pty());
        let configs = vec![Config::new(firmware, 0), Config::new(firmware, 1)];
        let counters = vec![Arc::default(), Arc::default()];
        let stop = Arc::new(AtomicBool::new(false));
        let peers = [
            m2.try_clone_native().unwrap(),
            m1.try_clone_native().unwrap(),
        ];
        let threads = [m1, m2]
            .into_iter()
            .zip(peers)
            .enumerate()
            .map(|(i, (host, peer))| {
                let radio = Radio {
                    me: configs[i].clone(),
                    peer: Some((configs[1 - i].clone(), peer)),
                    corrupt_one_in,
                    salt: i as u32 + 1,
                    counters: Arc::clone(&counters[i]),
                    timing,
                    reset_after: reset_after.filter(|_| i == 0),
                };
                let stop = stop.clone();
                std::thread::spawn(move || radio.run(host, stop))
            })
            .collect();
        RadioLink {
            a: s1.name().unwrap(),
            b: s2.name().unwrap(),
            configs,
            counters,
            stop,
            threads,
            _slaves: vec![s1, s2],
        }
    }

    /// One radio configured as `config`, with no peer in range.
    pub fn single(config: Config) -> Self {
        use serialport::SerialPort;
        let (host, slave) = pty();
        let counters = Arc::<Counters>::default();
        let stop = Arc::new(AtomicBool::new(false));
        let radio = Radio {
            me: config.clone(),
            peer: None,
            corrupt_one_in: None,
            salt: 0,
            counters: Arc::clone(&counters),
            timing: None,
            reset_after: None,
        };
        let thread = {
            let stop = stop.clone();
            std::thread::spawn(move || radio.run(host, stop))
        };
        RadioLink {
            a: slave.name().unwrap(),
            b: String::new(),
            configs: vec![config],
            counters: vec![counters],
            stop,
            threads: vec![thread],
            _slaves: vec![slave],
        }
    }
}

impl Drop for RadioLink {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Two pty pairs joined by a plain cable with no radio between (a common
/// wiring mistake): what one host writes, the other reads, byte for byte.
pub struct Cable {
    /// Device path of the first end.
    pub a: String,
    /// Device path of the second end.
    pub b: String,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    _slaves: Vec<TTYPort>,
}

impl Cable {
    pub fn new() -> Self {
        use serialport::SerialPort;
        let ((m1, s1), (m2, s2)) = (pty(), pty());
        let stop = Arc::new(AtomicBool::new(false));
        let copy = |mut from: TTYPort, mut to: TTYPort, stop: Arc<AtomicBool>| {
            std::thread::spawn(move || {
                let mut buf = [0u8; 256];
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(n) = from.read(&mut buf) {
                        let _ = to.write_all(&buf[..n]);
                    }
                }
            })
        };
        let (r1, r2) = (
            m1.try_clone_native().unwrap(),
            m2.try_clone_native().unwrap(),
        );
        let threads = vec![copy(m1, r2, stop.clone()), copy(m2, r1, stop.clone())];
        Cable {
            a: s1.name().unwrap(),
            b: s2.name().unwrap(),
            stop,
            threads,
            _slaves: vec![s1, s2],
        }
    }
}

impl Drop for Cable {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}
