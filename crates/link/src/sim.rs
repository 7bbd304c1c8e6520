//! A simulated XBee link, 802.15.4 or ZigBee firmware, seeded and
//! deterministic.
//!
//! Each packet crosses the sender's UART (10 bits a byte at `baud`, wrapped
//! in the firmware's transmit request: TX16 0x01 adds 9 bytes, ZigBee 0x10
//! adds 18) into the radio's serial buffer, which holds `buffer` bytes: when
//! it is full the radio deasserts CTS and the host waits, as a host with
//! hardware flow control does. Then the air, shared by both directions: on
//! 802.15.4, 250 kb/s plus the PHY/MAC overhead, the MAC acknowledgement and
//! turnaround; on ZigBee and DigiMesh, the time per packet that Digi's
//! measured throughput for the path's hops, security and roles gives
//! ([`crate::throughput`]). Then the receiver's UART (RX16 0x81 adds 9
//! bytes, ZigBee 0x90 adds 16). A transmission
//! attempt is lost with probability `loss`; the MAC retries `mac_retries`
//! times. Delivered packets may get a flipped bit (`bit_error`), which the
//! receiving end's frame check (the XBee API frame's checksum) finds and
//! drops, unless `unchecked`; be duplicated (`duplicate`) or delayed past
//! their successors (`reorder`).
//!
//! [`transfer`] runs the ARQ machines over this model in *simulated* time,
//! so the loss sweep and thousands of randomized transfers take moments;
//! [`pair`] gives two [`Transport`] ends in *real* time (optionally sped up)
//! for two threads, as the demo uses.

use std::collections::{BinaryHeap, VecDeque};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::arq::{ArqError, Config, Micros, Receiver, Segment, SendState, Sender, SessionId};
use crate::radio::Firmware;
use crate::throughput::{RadioPath, Role};
use crate::transport::Transport;

/// Channel model parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    /// UART baud rate on both sides.
    pub baud: u32,
    /// Air bit rate.
    pub air_bps: u32,
    /// Largest packet (XBee 802.15.4: 100).
    pub mtu: usize,
    /// Probability that one transmission attempt is lost.
    pub loss: f64,
    /// MAC-level retries after a lost attempt.
    pub mac_retries: u32,
    /// Probability that a delivered packet has one flipped bit.
    pub bit_error: f64,
    /// Hand packets with a flipped bit up instead of dropping them as the
    /// receiving end's frame check does: damage that slipped past it.
    pub unchecked: bool,
    /// Probability that a packet is delivered twice.
    pub duplicate: f64,
    /// Probability that a packet is delayed by several packet times.
    pub reorder: f64,
    /// Seed of every random choice.
    pub seed: u64,
    /// The radios' firmware: their frame and air overheads.
    pub radio: Firmware,
    /// Radio hops between the two ends (ZigBee and DigiMesh).
    pub hops: u8,
    /// Network security enabled on the radios (ZigBee and DigiMesh).
    pub encrypted: bool,
    /// The two ends' roles (ZigBee).
    pub role: Role,
    /// The radio's serial receive buffer, bytes: the host waits (CTS) while
    /// a packet does not fit.
    pub buffer: usize,
    /// Transmit requests the host keeps at the radio at once, paced by
    /// their transmit status as a serial link in API mode does
    /// ([`crate::pacing`]): one on the air and the next waiting, so that an
    /// urgent packet queues behind one packet, not a full buffer. 0: the
    /// host writes whenever CTS lets it.
    pub paced: usize,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            baud: 115_200,
            air_bps: 250_000,
            mtu: 100,
            loss: 0.0,
            mac_retries: 0,
            bit_error: 0.0,
            unchecked: false,
            duplicate: 0.0,
            reorder: 0.0,
            seed: 1,
            radio: Firmware::Ieee802154,
            hops: 1,
            encrypted: false,
            role: Role::RouterToRouter,
            buffer: RADIO_BUFFER,
            paced: crate::pacing::PacingConfig::DEFAULT_LIMIT,
        }
    }
}

/// The serial receive buffer the model gives a radio, bytes. Digi's manuals
/// give the CTS thresholds (17 bytes left on 802.15.4), not the size; 256
/// holds two full ZigBee transmit requests.
pub const RADIO_BUFFER: usize = 256;

/// Bytes an XBee TX16 API frame adds around a payload on the UART.
pub const API_OVERHEAD: usize = 9;

/// What a firmware adds around a payload, on the UART and on the air.
struct Overheads {
    /// Transmit request (host to radio).
    uart_tx: usize,
    /// Receive frame (radio to host).
    uart_rx: usize,
    /// PHY, MAC (short addressing) and, on ZigBee, NWK and APS headers.
    air: usize,
    /// Acknowledgements, turnaround and average backoff, µs.
    air_fixed_us: f64,
}

fn overheads(radio: Firmware) -> Overheads {
    match radio {
        // TX16 / RX16; PHY 6 + MAC 11; MAC ACK, turnaround and backoff.
        Firmware::Ieee802154 => Overheads {
            uart_tx: API_OVERHEAD,
            uart_rx: API_OVERHEAD,
            air: 17,
            air_fixed_us: 1_100.0,
        },
        // 0x10 / 0x90; PHY 6 + MAC 11 + NWK 8 + APS 8; the MAC ACK as on
        // 802.15.4, plus the APS acknowledgement frame (33 bytes) with its
        // own MAC ACK and backoff.
        Firmware::Zigbee | Firmware::DigiMesh => Overheads {
            uart_tx: 18,
            uart_rx: 16,
            air: 33,
            air_fixed_us: 1_100.0 + 33.0 * 32.0 + 1_100.0,
        },
    }
}

impl SimConfig {
    fn uart_us(&self, payload: usize, overhead: usize) -> f64 {
        (payload + overhead) as f64 * 10.0 * 1e6 / self.baud as f64
    }

    /// The path between the two radios.
    pub fn path(&self) -> RadioPath {
        RadioPath {
            firmware: self.radio,
            hops: self.hops,
            encrypted: self.encrypted,
            role: self.role,
        }
    }

    /// The air time one packet of `payload` bytes holds the channel for,
    /// µs: the firmware's frame, acknowledgements and every hop included.
    pub fn packet_air_us(&self, payload: usize) -> f64 {
        if let Some(t) = self.path().packet_us(payload, self.mtu) {
            return t;
        }
        let o = overheads(self.radio);
        (payload + o.air) as f64 * 8.0 * 1e6 / self.air_bps as f64 + o.air_fixed_us
    }

    /// The goodput bound set by the UART and the transmit request's
    /// overhead, in bit/s: `baud / 10 · mtu / (mtu + overhead) · 8` (84.6
    /// kb/s at 115200 baud with 100-byte 802.15.4 payloads, 75.9 kb/s with
    /// 84-byte ZigBee ones).
    pub fn uart_bound_bps(&self) -> f64 {
        let overhead = overheads(self.radio).uart_tx;
        self.baud as f64 / 10.0 * self.mtu as f64 / (self.mtu + overhead) as f64 * 8.0
    }

    /// The most payload the model carries one way, bit/s: the UART bound,
    /// or on ZigBee and DigiMesh the air's rate for full packets (Digi's
    /// measured throughput for the path), whichever is lower.
    pub fn bound_bps(&self) -> f64 {
        let air = self.mtu as f64 * 8.0 / (self.packet_air_us(self.mtu) / 1e6);
        self.uart_bound_bps().min(air)
    }
}

/// The shared state of the channel: busy-until times and the random source.
struct Channel {
    cfg: SimConfig,
    rng: ChaCha8Rng,
    uart_tx: [f64; 2],
    uart_rx: [f64; 2],
    air: f64,
    /// Per side, the packets in the radio's buffer: when each goes on the
    /// air (and so leaves the buffer), and its size on the UART.
    held: [VecDeque<(f64, usize)>; 2],
    /// Per side, when the packets the host handed the radio end on the
    /// air (their transmit status), for `paced`.
    unanswered: [VecDeque<f64>; 2],
    sequence: u64,
}

impl Channel {
    fn new(cfg: SimConfig) -> Self {
        Channel {
            cfg,
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            uart_tx: [0.0; 2],
            uart_rx: [0.0; 2],
            air: 0.0,
            held: Default::default(),
            unanswered: Default::default(),
            sequence: 0,
        }
    }

    /// Sends `packet` from side `from` at time `now` (µs); returns the arrivals
    /// (time, bytes) at the other side, and when the sender's UART is free again.
    fn send(&mut self, from: usize, now: f64, packet: &[u8]) -> (Vec<(f64, Vec<u8>)>, f64) {
        let to = 1 - from;
        let cfg = self.cfg;
        let o = overheads(cfg.radio);
        // CTS: the host starts the request once the radio's buffer has room.
        let size = packet.len() + o.uart_tx;
        let mut start = now.max(self.uart_tx[from]);
        let (held, unanswered) = (&mut self.held[from], &mut self.unanswered[from]);
        loop {
            held.retain(|&(on_air, _)| on_air > start);
            unanswered.retain(|&status| status > start);
            let bytes: usize = held.iter().map(|&(_, n)| n).sum();
            match (held.front(), unanswered.front()) {
                (_, Some(&status)) if cfg.paced > 0 && unanswered.len() >= cfg.paced => {
                    start = status
                }
                (Some(&(on_air, _)), _) if bytes + size > cfg.buffer => start = on_air,
                _ => break,
            }
        }
        let uart_done = start + cfg.uart_us(packet.len(), o.uart_tx);
        self.uart_tx[from] = uart_done;
        let mut t = uart_done.max(self.air);
        self.held[from].push_back((t, size));
        let mut delivered = false;
        for _ in 0..=cfg.mac_retries {
            t += cfg.packet_air_us(packet.len());
            if !self.rng.gen_bool(cfg.loss.clamp(0.0, 1.0)) {
                delivered = true;
                break;
            }
        }
        self.air = t;
        self.unanswered[from].push_back(t);
        if !delivered {
            return (Vec::new(), uart_done);
        }
        let mut bytes = packet.to_vec();
        if !bytes.is_empty() && self.rng.gen_bool(cfg.bit_error.clamp(0.0, 1.0)) {
            let bit = self.rng.gen_range(0..bytes.len() * 8);
            bytes[bit / 8] ^= 1 << (bit % 8);
            if !cfg.unchecked {
                return (Vec::new(), uart_done);
            }
        }
        let mut arrive = t.max(self.uart_rx[to]) + cfg.uart_us(packet.len(), o.uart_rx);
        self.uart_rx[to] = arrive;
        if self.rng.gen_bool(cfg.reorder.clamp(0.0, 1.0)) {
            arrive += cfg.uart_us(cfg.mtu, o.uart_rx) * self.rng.gen_range(2.0..6.0);
        }
        let mut out = vec![(arrive, bytes.clone())];
        if self.rng.gen_bool(cfg.duplicate.clamp(0.0, 1.0)) {
            out.push((arrive + cfg.uart_us(packet.len(), o.uart_rx), bytes));
        }
        (out, uart_done)
    }
}

/// What one simulated transfer did.
#[derive(Clone, Debug, PartialEq)]
pub struct TransferReport {
    /// The message arrived intact.
    pub delivered: bool,
    /// A message different from the one sent was handed up (must never happen).
    pub corrupted: bool,
    /// Messages handed up (must be 0 or 1).
    pub deliveries: usize,
    /// Why it failed, if it did.
    pub error: Option<ArqError>,
    /// Simulated time until delivery (or failure), seconds.
    pub seconds: f64,
    /// Message bits per second of that time.
    pub goodput_bps: f64,
    /// DATA segments sent.
    pub segments: u64,
    /// DATA segments retransmitted.
    pub retransmissions: u64,
}

#[derive(PartialEq)]
struct Event(f64, u64, usize, Vec<u8>);

impl Eq for Event {}

impl PartialOrd for Event {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Event {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        // Earliest first in a max-heap.
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

/// Sends `message` from side 0 to side 1 over the model, in simulated time.
pub fn transfer(sim: SimConfig, arq: Config, message: &[u8]) -> TransferReport {
    let sim = SimConfig {
        mtu: arq.mtu,
        ..sim
    };
    let arq = arq.with_packet_time(sim.packet_air_us(sim.mtu) as Micros);
    let mut ch = Channel::new(sim);
    // Two fixed sessions: the model has one life of each side.
    let (mut tx, mut rx) = (
        Sender::new(arq, SessionId(1)),
        Receiver::new(arq, SessionId(2)),
    );
    let mut events: BinaryHeap<Event> = BinaryHeap::new();
    let mut now = 0.0f64;
    let us = |t: f64| t as Micros;
    if let Err(e) = tx.start(message, 0) {
        return TransferReport {
            delivered: false,
            corrupted: false,
            deliveries: 0,
            error: Some(e),
            seconds: 0.0,
            goodput_bps: 0.0,
            segments: 0,
            retransmissions: 0,
        };
    }
    let (mut delivered_at, mut deliveries, mut corrupted, mut rx_error) =
        (None, 0usize, false, None);
    let mut sender_free = 0.0f64;
    loop {
        // The sender hands segments to its UART while the UART can take them.
        while sender_free <= now {
            let Some(seg) = tx.poll_transmit(us(now)) else {
                break;
            };
            let (arrivals, free) = ch.send(0, now, &seg);
            sender_free = free;
            for (t, b) in arrivals {
                ch.sequence += 1;
                events.push(Event(t, ch.sequence, 1, b));
            }
        }
        let finished = !matches!(tx.state(), SendState::Sending);
        if finished && events.is_empty() {
            break;
        }
        let mut next = events.peek().map_or(f64::INFINITY, |e| e.0);
        if !finished {
            let timer = tx.poll_at().map_or(f64::INFINITY, |t| t as f64);
            next = next.min(if sender_free > now {
                sender_free
            } else {
                timer.max(now + 1.0)
            });
        }
        if !next.is_finite() || next > 3.6e9 {
            break;
        }
        now = next;
        while events.peek().is_some_and(|e| e.0 <= now) {
            let Event(t, _, side, bytes) = events.pop().expect("peeked");
            let Some(seg) = Segment::parse(&bytes) else {
                continue;
            };
            if side == 1 {
                let (ack, got) = rx.on_segment(&seg, us(t));
                match got {
                    Some(Ok(m)) => {
                        deliveries += 1;
                        corrupted |= m != message;
                        delivered_at.get_or_insert(t);
                    }
                    Some(Err((_, e))) => rx_error = Some(e),
                    None => {}
                }
                if let Some(a) = ack {
                    let (arrivals, _) = ch.send(1, t, &a);
                    for (t2, b) in arrivals {
                        ch.sequence += 1;
                        events.push(Event(t2, ch.sequence, 0, b));
                    }
                }
            } else {
                tx.on_segment(&seg, us(t));
            }
        }
    }
    let c = tx.counters();
    let seconds = delivered_at.unwrap_or(now) / 1e6;
    let error = match tx.state() {
        SendState::Failed(e) => Some(e),
        _ => rx_error,
    };
    TransferReport {
        delivered: deliveries > 0 && !corrupted,
        corrupted,
        deliveries,
        error: if deliveries > 0 { None } else { error },
        seconds,
        goodput_bps: if deliveries > 0 && seconds > 0.0 {
            message.len() as f64 * 8.0 / seconds
        } else {
            0.0
        },
        segments: c.segments,
        retransmissions: c.retransmissions,
    }
}

struct Shared {
    channel: Channel,
    epoch: Instant,
    scale: f64,
    queues: [BinaryHeap<Event>; 2],
}

/// One end of a real-time simulated link (see [`pair`]).
pub struct SimEnd {
    side: usize,
    shared: Arc<(Mutex<Shared>, Condvar)>,
}

/// Two ends of a simulated link that run in real time, `speedup` times faster
/// than the radio would (1.0 = as the radio). Side 0 is the sender's radio.
pub fn pair(cfg: SimConfig, speedup: f64) -> (SimEnd, SimEnd) {
    let shared = Arc::new((
        Mutex::new(Shared {
            channel: Channel::new(cfg),
            epoch: Instant::now(),
            scale: speedup.max(1e-3),
            queues: Default::default(),
        }),
        Condvar::new(),
    ));
    (
        SimEnd {
            side: 0,
            shared: shared.clone(),
        },
        SimEnd { side: 1, shared },
    )
}

impl SimEnd {
    /// Radio time elapsed since the pair was made (real time × speedup).
    pub fn radio_time(&self) -> Duration {
        let s = self.shared.0.lock().expect("sim lock");
        Duration::from_secs_f64(s.epoch.elapsed().as_secs_f64() * s.scale)
    }
}

impl Transport for SimEnd {
    fn send(&mut self, packet: &[u8]) -> std::io::Result<()> {
        let (lock, cv) = &*self.shared;
        let mut s = lock.lock().expect("sim lock");
        let now = s.epoch.elapsed().as_secs_f64() * 1e6 * s.scale;
        let (arrivals, uart_done) = s.channel.send(self.side, now, packet);
        for (t, b) in arrivals {
            s.channel.sequence += 1;
            let seq = s.channel.sequence;
            s.queues[1 - self.side].push(Event(t, seq, 1 - self.side, b));
        }
        cv.notify_all();
        // Like a serial write with flow control: return once the UART has taken the packet.
        let wait = Duration::from_secs_f64(((uart_done - now) / 1e6 / s.scale).max(0.0));
        drop(s);
        std::thread::sleep(wait);
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> std::io::Result<Option<Vec<u8>>> {
        let (lock, cv) = &*self.shared;
        let deadline = Instant::now() + timeout;
        let mut s = lock.lock().expect("sim lock");
        loop {
            let now = s.epoch.elapsed().as_secs_f64() * 1e6 * s.scale;
            let due = s.queues[self.side].peek().map(|e| e.0);
            if due.is_some_and(|t| t <= now) {
                return Ok(s.queues[self.side].pop().map(|e| e.3));
            }
            let real_now = Instant::now();
            if real_now >= deadline {
                return Ok(None);
            }
            let wait = due.map_or(deadline - real_now, |t| {
                Duration::from_secs_f64(((t - now) / 1e6 / s.scale).max(0.0))
                    .min(deadline - real_now)
            });
            s = cv
                .wait_timeout(s, wait.max(Duration::from_micros(50)))
                .expect("sim lock")
                .0;
        }
    }

    fn mtu(&self) -> usize {
        self.shared.0.lock().expect("sim lock").channel.cfg.mtu
    }

    fn packet_time(&self) -> Option<Duration> {
        let s = self.shared.0.lock().expect("sim lock");
        let cfg = s.channel.cfg;
        Some(Duration::from_secs_f64(
            cfg.packet_air_us(cfg.mtu) / 1e6 / s.scale,
        ))
    }

    fn describe(&self) -> String {
        let c = self.shared.0.lock().expect("sim lock").channel.cfg;
        format!("sim:?loss={}&seed={}&baud={}", c.loss, c.seed, c.baud)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(n: usize, seed: u64) -> Vec<u8> {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| r.gen()).collect()
    }

    /// On each firmware's model, against the bound for message bytes: each
    /// segment carries DATA_OVERHEAD bytes of header, and where the air is
    /// the limit (ZigBee, DigiMesh) the receiver's ACK, one per `ack_every`
    /// fragments, takes its packet time on the shared air. At least 96 % of
    /// that at no loss and 76 % at 10 % loss (issue 18's targets), and no
    /// retransmission at all without loss.
    #[test]
    fn goodput_targets_at_zero_and_ten_percent_loss() {
        let paced = |radio| SimConfig {
            radio,
            mtu: 84,
            ..SimConfig::default()
        };
        assert!((SimConfig::default().uart_bound_bps() - 84_550.0).abs() < 100.0);
        assert!((paced(Firmware::Zigbee).uart_bound_bps() - 75_900.0).abs() < 100.0);
        let msg = message(30_000, 1);
        for sim in [
            SimConfig::default(),
            paced(Firmware::Zigbee),
            paced(Firmware::DigiMesh),
        ] {
            let cfg = Config::for_mtu(sim.mtu);
            let mut bound = sim.bound_bps() * cfg.fragment_size() as f64 / cfg.mtu as f64;
            if sim.radio != Firmware::Ieee802154 {
                let data = sim.packet_air_us(sim.mtu) * cfg.ack_every as f64;
                bound *= data / (data + sim.packet_air_us(crate::arq::MIN_MTU));
            }
            let clean = transfer(sim, cfg, &msg);
            assert!(clean.delivered && clean.retransmissions == 0, "{clean:?}");
            assert!(
                clean.goodput_bps >= 0.96 * bound,
                "{} 0 %: {:.0} of {bound:.0}",
                sim.radio,
                clean.goodput_bps
            );
            let lossy = transfer(
                SimConfig {
                    loss: 0.1,
                    seed: 2,
                    ..sim
                },
                cfg,
                &msg,
            );
            assert!(lossy.delivered, "{lossy:?}");
            assert!(
                lossy.goodput_bps >= 0.76 * bound,
                "{} 10 %: {:.0} of {bound:.0}",
                sim.radio,
                lossy.goodput_bps
            );
        }
    }

    /// The calibrated models carry what Digi measured, less the ARQ's
    /// headers and ACKs: ZigBee 1 hop 35 kb/s, DigiMesh 27, and ZigBee at 4
    /// hops with security 5 kb/s.
    #[test]
    fn calibrated_models_carry_what_the_radios_carry() {
        let msg = message(20_000, 3);
        for (radio, hops, encrypted, digi) in [
            (Firmware::Zigbee, 1, false, 35_000.0),
            (Firmware::DigiMesh, 1, false, 27_000.0),
            (Firmware::Zigbee, 4, true, 5_000.0),
        ] {
            let sim = SimConfig {
                radio,
                hops,
                encrypted,
                mtu: 84,
                ..SimConfig::default()
            };
            assert!(
                (sim.bound_bps() - digi).abs() < 1.0,
                "{radio}: {}",
                sim.bound_bps()
            );
            let rep = transfer(sim, Config::for_mtu(84), &msg);
            let got = rep.goodput_bps;
            assert!(
                got <= digi && got >= 0.8 * digi,
                "{radio} {hops} hops: {got:.0} b/s against Digi's {digi:.0}"
            );
        }
    }

    /// At 0 % loss every retransmission is spurious: fewer than 1 % of
    /// the segments, from the first frame on, on every model from 6 hops
    /// with security (about 3 kb/s) to 802.15.4 at 1 Mbaud.
    #[test]
    fn no_spurious_retransmissions_from_the_first_frame() {
        let frame = message(4_400, 4);
        let mut models = vec![
            SimConfig::default(),
            SimConfig {
                baud: 1_000_000,
                ..SimConfig::default()
            },
        ];
        for radio in [Firmware::Zigbee, Firmware::DigiMesh] {
            for hops in 1..=6 {
                for encrypted in [false, true] {
                    models.push(SimConfig {
                        radio,
                        hops,
                        encrypted,
                        mtu: 84,
                        ..SimConfig::default()
                    });
                }
            }
        }
        for sim in models {
            let rep = transfer(sim, Config::for_mtu(sim.mtu), &frame);
            assert!(rep.delivered, "{:?}: {rep:?}", sim.path());
            assert!(
                rep.retransmissions as f64 <= 0.01 * rep.segments as f64,
                "{:?} at {} baud: {rep:?}",
                sim.path(),
                sim.baud
            );
        }
    }

    /// Randomized transfers over `sims` seeds, bit errors `unchecked` or
    /// not: every delivered message is exact, none is delivered twice,
    /// every failure is explicit. Returns how many were delivered.
    fn randomized(seeds: u64, unchecked: bool) -> usize {
        let mut ok = 0;
        for seed in 0..seeds {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            let sim = SimConfig {
                loss: r.gen_range(0.0..0.5),
                bit_error: r.gen_range(0.0..0.05),
                duplicate: r.gen_range(0.0..0.1),
                reorder: r.gen_range(0.0..0.1),
                unchecked,
                seed,
                ..SimConfig::default()
            };
            let arq = Config {
                deadline: 30_000_000,
                ..Config::for_mtu(r.gen_range(20..=100))
            };
            let msg = message(r.gen_range(0..3000), seed);
            let rep = transfer(sim, arq, &msg);
            assert!(!rep.corrupted, "seed {seed}");
            assert!(rep.deliveries <= 1, "seed {seed}: delivered twice");
            if rep.delivered {
                ok += 1;
            } else {
                assert!(rep.error.is_some(), "seed {seed}: silent failure");
            }
        }
        ok
    }

    /// Thousands of transfers over the radio as it is: damaged frames are
    /// dropped by the frame check, and nearly all messages get through.
    #[test]
    fn randomized_integrity() {
        let ok = randomized(1500, false);
        assert!(ok > 1400, "{ok} of 1500 delivered");
    }

    /// DATA segments have no CRC of their own: damage that slipped past the
    /// transport's check reaches the ARQ. It may cost the message (its
    /// CRC-32 fails), but never delivers a wrong or second copy and never
    /// lets the sender count as delivered what was not.
    #[test]
    fn damage_past_the_frame_check_is_never_delivered_nor_silent() {
        randomized(1500, true);
    }

    #[test]
    fn real_time_pair_carries_packets_both_ways() {
        let (mut a, mut b) = pair(SimConfig::default(), 50.0);
        a.send(b"hello").unwrap();
        assert_eq!(
            b.recv(Duration::from_secs(1)).unwrap(),
            Some(b"hello".to_vec())
        );
        b.send(b"back").unwrap();
        assert_eq!(
            a.recv(Duration::from_secs(1)).unwrap(),
            Some(b"back".to_vec())
        );
        assert_eq!(a.recv(Duration::from_millis(5)).unwrap(), None);
    }
}
