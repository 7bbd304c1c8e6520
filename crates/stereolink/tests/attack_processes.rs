//! An attacker beside a paired sender and receiver (issue 19). `send` and
//! `receive` run as separate processes with keys; the "air" between them is
//! a hub in this test process, which delivers the receiver's packets to
//! every other port (as a radio broadcasts) and everything else to the
//! receiver. The attacker is this test process, which captures the real
//! session's datagrams off the air and re-injects them altered, plus two
//! attacking `send` processes on their own port: one without keys
//! (plaintext frames and reports) and one with a key the receiver was not
//! paired with. The air is UDP sockets, or pty pairs carrying SLIP frames
//! (`api=0`). Every attack must be refused and counted by cause, the axis
//! must only follow the paired sender's reports, and every legitimate frame
//! must be shown.

mod common;

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, UdpSocket};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::{finish, free_port, run_ok, spawn, strings, synth};
use serialport::{SerialPort, TTYPort};
use stereolink_link::arq::{Config, Segment, SessionId};
use stereolink_link::crc::crc32;
use stereolink_link::slip;

/// One attachment to the air.
trait Port: Send {
    /// A packet, if one arrived within a millisecond or so.
    fn recv(&mut self) -> Option<Vec<u8>>;
    fn send(&mut self, packet: &[u8]);
}

struct UdpPort {
    socket: UdpSocket,
    peer: SocketAddr,
}

impl Port for UdpPort {
    fn recv(&mut self) -> Option<Vec<u8>> {
        let mut buf = [0u8; 2048];
        let (n, _) = self.socket.recv_from(&mut buf).ok()?;
        Some(buf[..n].to_vec())
    }
    fn send(&mut self, packet: &[u8]) {
        let _ = self.socket.send_to(packet, self.peer);
    }
}

struct PtyPort {
    master: TTYPort,
    deframer: slip::Deframer,
    ready: Vec<Vec<u8>>,
}

impl Port for PtyPort {
    fn recv(&mut self) -> Option<Vec<u8>> {
        if self.ready.is_empty() {
            let mut buf = [0u8; 512];
            let n = self.master.read(&mut buf).unwrap_or(0);
            for &b in &buf[..n] {
                if let Some(Ok(p)) = self.deframer.push(b) {
                    self.ready.push(p);
                }
            }
        }
        (!self.ready.is_empty()).then(|| self.ready.remove(0))
    }
    fn send(&mut self, packet: &[u8]) {
        let _ = self.master.write_all(&slip::encode(packet));
    }
}

/// The air: port 0 is the receiver's, 1 the paired sender's, 2 the
/// attacking processes'. Keeps every packet from port 1.
struct Air {
    /// Link specs for the receiver, the sender and the attacker.
    links: [String; 3],
    inject: mpsc::Sender<Vec<u8>>,
    captured: Arc<Mutex<Vec<Vec<u8>>>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    _slaves: Vec<TTYPort>,
}

impl Air {
    fn start(mut ports: Vec<Box<dyn Port>>, links: [String; 3], slaves: Vec<TTYPort>) -> Air {
        let (inject, injected) = mpsc::channel::<Vec<u8>>();
        let captured = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (keep, halt) = (captured.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            while !halt.load(Ordering::Relaxed) {
                while let Ok(p) = injected.try_recv() {
                    ports[0].send(&p);
                }
                for i in 0..ports.len() {
                    while let Some(p) = ports[i].recv() {
                        if i == 0 {
                            ports.iter_mut().skip(1).for_each(|o| o.send(&p));
                        } else {
                            if i == 1 {
                                keep.lock().unwrap().push(p.clone());
                            }
                            ports[0].send(&p);
                        }
                    }
                }
            }
        });
        Air {
            links,
            inject,
            captured,
            stop,
            thread: Some(thread),
            _slaves: slaves,
        }
    }

    fn udp() -> Air {
        let hub: Vec<UdpSocket> = (0..3)
            .map(|_| UdpSocket::bind("127.0.0.1:0").unwrap())
            .collect();
        let ends: Vec<u16> = (0..3).map(|_| free_port()).collect();
        let links = std::array::from_fn(|i| {
            format!(
                "udp:127.0.0.1:{}?peer={}",
                ends[i],
                hub[i].local_addr().unwrap()
            )
        });
        let ports = hub
            .into_iter()
            .zip(&ends)
            .map(|(socket, &end)| {
                socket
                    .set_read_timeout(Some(Duration::from_millis(1)))
                    .unwrap();
                Box::new(UdpPort {
                    socket,
                    peer: format!("127.0.0.1:{end}").parse().unwrap(),
                }) as Box<dyn Port>
            })
            .collect();
        Air::start(ports, links, Vec::new())
    }

    fn pty() -> Air {
        let mut ports: Vec<Box<dyn Port>> = Vec::new();
        let mut slaves = Vec::new();
        let mut names = Vec::new();
        for _ in 0..3 {
            let (mut master, slave) = TTYPort::pair().unwrap();
            master.set_timeout(Duration::from_millis(1)).unwrap();
            names.push(slave.name().unwrap());
            slaves.push(slave);
            ports.push(Box::new(PtyPort {
                master,
                deframer: slip::Deframer::new(256),
                ready: Vec::new(),
            }));
        }
        let links = std::array::from_fn(|i| format!("serial:{}?baud=115200&api=0", names[i]));
        Air::start(ports, links, slaves)
    }

    /// The paired sender's messages as captured, by (session, msg id):
    /// the sealed payload, its CRC-32 stripped.
    fn messages(&self) -> BTreeMap<(SessionId, u8), Vec<u8>> {
        let mut frags: BTreeMap<(SessionId, u8), BTreeMap<u16, Vec<u8>>> = BTreeMap::new();
        for p in self.captured.lock().unwrap().iter() {
            if let Some(Segment::Data {
                session,
                msg_id,
                index,
                fragment,
                ..
            }) = Segment::parse(p)
            {
                frags
                    .entry((session, msg_id))
                    .or_default()
                    .insert(index, fragment.to_vec());
            }
        }
        frags
            .into_iter()
            .map(|(k, f)| {
                let mut m: Vec<u8> = f.into_values().flatten().collect();
                m.truncate(m.len() - 4);
                (k, m)
            })
            .collect()
    }

    /// Sends `payload` to the receiver as a well-formed ARQ message: the
    /// ARQ has no secret, so an attacker can always do this.
    fn inject(&self, session: SessionId, msg_id: u8, payload: &[u8]) {
        let mut body = payload.to_vec();
        body.extend_from_slice(&crc32(payload).to_le_bytes());
        let chunks: Vec<&[u8]> = body.chunks(Config::for_mtu(100).fragment_size()).collect();
        for (i, fragment) in chunks.iter().enumerate() {
            let seg = Segment::Data {
                session,
                msg_id,
                index: i as u16,
                last: i + 1 == chunks.len(),
                fragment,
            };
            self.inject.send(seg.emit()).unwrap();
        }
        std::thread::sleep(Duration::from_millis(30));
    }

    /// Re-sends every captured packet as it was.
    fn replay_verbatim(&self) {
        for p in self.captured.lock().unwrap().iter() {
            self.inject.send(p.clone()).unwrap();
            std::thread::sleep(Duration::from_micros(300));
        }
    }
}

impl Drop for Air {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

struct Keys {
    sender: (String, String),
    robot: (String, String),
    mallory: (String, String),
}

fn keygen(dir: &Path) -> Keys {
    let pair = |name: &str| {
        let base = dir.join(name);
        run_ok(&["keygen", "-o", base.to_str().unwrap()]);
        (
            format!("{}.key", base.display()),
            format!("{}.pub", base.display()),
        )
    };
    Keys {
        sender: pair("sender"),
        robot: pair("robot"),
        mallory: pair("mallory"),
    }
}

fn send_args(
    link: &str,
    scene: &Path,
    repeat: u32,
    focal: &str,
    keys: Option<(&str, &str)>,
) -> Vec<String> {
    let mut args = strings(&[
        "send",
        "--link",
        link,
        "--max-disp",
        "23",
        "--deadline-s",
        "5",
    ]);
    args.extend(strings(&["--focal-px", focal, "--baseline-m", "0.03"]));
    args.extend(strings(&["--method", "kmeans", "--levels", "4"]));
    args.extend(strings(&[
        "--left",
        scene.join("left.png").to_str().unwrap(),
        "--right",
        scene.join("right.png").to_str().unwrap(),
        "--repeat",
        &repeat.to_string(),
    ]));
    if let Some((key, peer)) = keys {
        args.extend(strings(&["--key", key, "--peer-key", peer]));
    }
    args
}

/// A receiver that stops after `frames` reports (0: after 8 s without a
/// message for it; refused ones do not count).
fn receive_args(link: &str, keys: &Keys, frames: u32) -> Vec<String> {
    strings(&[
        "receive",
        "--frames",
        &frames.to_string(),
        "--link",
        link,
        "--robot",
        "sim",
        "--max-disp",
        "24",
        "--timeout-s",
        "8",
        "--key",
        &keys.robot.0,
        "--peer-key",
        &keys.sender.1,
    ])
}

/// The distances of the lines starting with `prefix` ("frame", "report").
fn distances(out: &str, prefix: &str) -> Vec<String> {
    out.lines()
        .filter(|l| l.starts_with(prefix))
        .map(|l| {
            l.split("distance ")
                .nth(1)
                .unwrap()
                .split(' ')
                .next()
                .unwrap()
                .to_string()
        })
        .collect()
}

/// The receiver's "link: rejected: …" counts, in the order bad tag,
/// replay, unknown session, handshake.
fn rejected(out: &str) -> [u64; 4] {
    let line = out
        .lines()
        .find(|l| l.starts_with("link: rejected:"))
        .unwrap_or_else(|| panic!("{out}"));
    let n: Vec<u64> = line
        .split([':', ','])
        .filter_map(|p| p.split_whitespace().next()?.parse().ok())
        .collect();
    n.try_into().unwrap()
}

fn attacks(air: Air) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let keys = keygen(dir.path());
    let paired = Some((keys.sender.0.as_str(), keys.robot.1.as_str()));
    let [rx_link, tx_link, evil_link] = air.links.clone();

    let rx = spawn(&receive_args(&rx_link, &keys, 0));
    let first = finish(
        spawn(&send_args(&tx_link, &scene, 2, "128", paired)),
        "paired sender",
    );
    let legit = distances(&first, "frame");
    assert_eq!(legit.len(), 2, "{first}");

    // Attacking processes: no keys (plaintext), and an unpaired key.
    let plain = finish(
        spawn(&send_args(&evil_link, &scene, 1, "200", None)),
        "plaintext attacker",
    );
    let forged = distances(&plain, "frame");
    assert_ne!(
        forged,
        legit[..1],
        "the attacker's reports must differ to be told apart"
    );
    let mallory = spawn(&send_args(
        &evil_link,
        &scene,
        1,
        "200",
        Some((&keys.mallory.0, &keys.robot.1)),
    ))
    .wait_with_output()
    .unwrap();
    assert!(
        !mallory.status.success(),
        "an unpaired sender must not report a frame sent"
    );
    assert!(String::from_utf8_lossy(&mallory.stderr).contains("no secure session"));

    // Captured traffic, altered and re-injected.
    let msgs = air.messages();
    let (&(session, _), init) = msgs.iter().next().unwrap();
    assert_eq!(init.len(), 60, "the first message is the handshake INIT");
    let sealed: Vec<&Vec<u8>> = msgs.values().skip(1).collect();
    assert_eq!(sealed.len(), 4, "two frames and two reports");
    let report = sealed[3];
    let mut id = 100u8;
    let mut next = || {
        id += 1;
        id
    };
    // Expected refusals by cause: bad tag, replay, unknown session, handshake.
    // A changed copy of an accepted message is refused as a replay before
    // its tag is even checked; a new counter needs a valid tag.
    let mut expected = [0u64; 4];
    air.inject(session, next(), init); // the INIT again
    expected[3] += 1;
    for m in sealed.iter().rev() {
        air.inject(session, next(), m); // replayed, in reverse order
        expected[1] += 1;
    }
    for cut in [report.len() - 1, report.len() / 2, 30] {
        air.inject(session, next(), &report[..cut]);
        expected[1] += 1;
    }
    air.inject(session, next(), &report[..9]); // too short for a tag
    expected[0] += 1;
    for bit in [70, report.len() * 4, report.len() * 8 - 1] {
        let mut bad = report.clone();
        bad[bit / 8] ^= 1 << (bit % 8);
        air.inject(session, next(), &bad);
        expected[1] += 1;
    }
    let mut bad = report.clone();
    bad[7] ^= 0x40; // the counter: an unseen one, so the tag is checked
    air.inject(session, next(), &bad);
    expected[0] += 1;
    let mut fake = 5000u64.to_le_bytes().to_vec();
    fake.extend((0..200u32).map(|i| (i * 37) as u8));
    air.inject(session, next(), &fake); // forged ciphertext
    expected[0] += 1;

    // The paired sender restarts: a new handshake, a new session.
    let second = finish(
        spawn(&send_args(&tx_link, &scene, 1, "128", paired)),
        "restarted sender",
    );
    assert_eq!(distances(&second, "frame"), legit[..1]);
    // The first life's messages after the rekey.
    air.inject(session, next(), report);
    expected[2] += 1;
    let out = finish(rx, "receiver");

    let reports = distances(&out, "report");
    assert_eq!(
        reports,
        [&legit[..], &legit[..1]].concat(),
        "only the paired sender's reports: {out}"
    );
    assert_eq!(
        out.lines().filter(|l| l.starts_with("frame ")).count(),
        3,
        "{out}"
    );
    // The plaintext attacker's frame and report come from a session with no
    // keys; the unpaired sender's INITs (one per retry) fail.
    let counts = rejected(&out);
    assert_eq!(
        counts[..3],
        [expected[0], expected[1], expected[2] + 2],
        "{out}"
    );
    assert!(counts[3] > expected[3], "{out}");

    // The receiver restarts and the attacker replays everything captured.
    let rx = spawn(&receive_args(&rx_link, &keys, 1));
    std::thread::sleep(Duration::from_millis(300));
    air.replay_verbatim();
    let third = finish(
        spawn(&send_args(&tx_link, &scene, 1, "128", paired)),
        "third sender",
    );
    assert_eq!(distances(&third, "frame"), legit[..1]);
    let out = finish(rx, "restarted receiver");
    assert_eq!(distances(&out, "report"), legit[..1], "{out}");
    // The replayed INITs are answered (this life never saw them), but the
    // keys of those handshakes are new, so each of the six replayed sealed
    // messages fails its tag.
    let counts = rejected(&out);
    assert!(
        counts.iter().sum::<u64>() >= 6,
        "old sessions refused: {counts:?}"
    );
}

#[test]
fn attacks_over_udp_are_refused() {
    attacks(Air::udp());
}

#[test]
fn attacks_over_a_pty_pair_are_refused() {
    attacks(Air::pty());
}

#[test]
fn a_robot_without_keys_needs_insecure_and_is_warned_about_each_start() {
    let link = format!(
        "udp:127.0.0.1:{}?peer=127.0.0.1:{}",
        free_port(),
        free_port()
    );
    let args = [
        "receive",
        "--link",
        &link,
        "--robot",
        "sim",
        "--timeout-s",
        "1",
    ];
    let refused = spawn(&args).wait_with_output().unwrap();
    assert!(!refused.status.success());
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        err.contains("refusing to drive the axis") && err.contains("--insecure"),
        "{err}"
    );
    let insecure = spawn(&[&args[..], &["--insecure"]].concat())
        .wait_with_output()
        .unwrap();
    assert!(insecure.status.success());
    let err = String::from_utf8_lossy(&insecure.stderr);
    assert!(
        err.contains("anyone in radio range can send frames and reports and move the axis"),
        "{err}"
    );
}
