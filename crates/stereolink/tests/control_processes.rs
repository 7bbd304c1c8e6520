//! Commands over the link to real stations (issue 22): this test process
//! is the peer on a real UDP link, as the gateway is, and sends Control
//! messages to a running `send` (levels, method, frame request; an axis
//! stop it must refuse) and to a running `receive` with a simulated axis
//! (an axis stop it must obey and hold). Malformed and forged Control
//! messages are refused with a clear line and change nothing.

mod common;

use std::net::UdpSocket;
use std::path::Path;
use std::process::Child;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::{free_port, spawn, synth};
use stereolink_codec::container::{self, Body};
use stereolink_codec::control::{Command, Control, Reply};
use stereolink_codec::{DepthReport, Limits, Message, ReportLevel};
use stereolink_link::arq::Config;
use stereolink_link::endpoint::{Endpoint, LinkError};
use stereolink_link::secure::{keyfile, Keys, SecureConfig};
use stereolink_link::spec::{self, LinkSpec};

/// How long the peer waits for the station to acknowledge a message.
const PATIENCE: Duration = Duration::from_secs(20);

/// A frame as the peer saw it: id, segmentation method, levels.
type FrameSeen = (u32, &'static str, u8);

/// What the peer took from the station so far.
#[derive(Default, Debug)]
struct Seen {
    frames: Vec<FrameSeen>,
    reports: Vec<u32>,
    replies: Vec<Reply>,
}

/// The test's end of a UDP link: the station's peer.
struct Peer {
    ep: Endpoint,
    seen: Seen,
}

impl Peer {
    /// Bound on `port`, talking to the station at `station`; a message
    /// not acknowledged within `deadline` fails.
    fn udp(port: u16, station: &str, keys: Option<Keys>, deadline: Duration) -> Peer {
        let spec: LinkSpec = format!("udp:127.0.0.1:{port}?peer={station}")
            .parse()
            .unwrap();
        let transport = spec::open(&spec).unwrap();
        let cfg = Config {
            deadline: deadline.as_micros() as u64,
            ..Config::for_mtu(transport.mtu())
        };
        let mut ep = Endpoint::with_config(transport, cfg).unwrap();
        if let Some(k) = keys {
            ep = ep.with_keys(k, SecureConfig::default());
        }
        Peer {
            ep,
            seen: Seen::default(),
        }
    }

    /// Sends one message and waits for the station's link to acknowledge it.
    #[track_caller]
    fn send(&mut self, msg: &[u8]) {
        self.ep.send_message(msg).expect("the station acknowledges");
    }

    /// Takes messages until `done` holds; panics after `limit`.
    #[track_caller]
    fn until(&mut self, limit: Duration, done: impl Fn(&Seen) -> bool) {
        let start = Instant::now();
        while !done(&self.seen) {
            assert!(start.elapsed() < limit, "waited {limit:?}: {:?}", self.seen);
            let msg = match self.ep.recv_message(Duration::from_millis(50)) {
                Ok(m) => m,
                Err(LinkError::Timeout) => continue,
                Err(e) => panic!("link: {e}"),
            };
            match container::parse(&msg, &Limits::default()).expect("a valid message") {
                (h, Body::StereoFrame(f)) => {
                    self.seen.frames.push((h.frame_id, f.kind.name(), f.levels))
                }
                (h, Body::DepthReport(_)) => self.seen.reports.push(h.frame_id),
                (_, Body::Control(c)) => match Control::decode(c) {
                    Ok(Control::Reply(r)) => self.seen.replies.push(r),
                    other => panic!("a station sent {other:?}"),
                },
            }
        }
        self.ep.dealt_with().unwrap();
    }

    /// Answers the station until it exits; returns its stdout and stderr.
    fn wait(&mut self, mut child: Child, what: &str) -> (String, String) {
        let start = Instant::now();
        while child.try_wait().unwrap().is_none() {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "{what} did not end"
            );
            self.ep.linger(Duration::from_millis(50)).unwrap();
        }
        let out = child.wait_with_output().unwrap();
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        );
        assert!(out.status.success(), "{what} failed: {stdout}{stderr}");
        (stdout, stderr)
    }
}

/// A camera folder holding one synthetic pair, in `dir`.
fn camera_folder(dir: &Path) -> String {
    let scene = dir.join("scene");
    synth(&scene);
    let watch = dir.join("watch");
    std::fs::create_dir_all(&watch).unwrap();
    for view in ["left", "right"] {
        std::fs::copy(
            scene.join(format!("{view}.png")),
            watch.join(format!("{view}-1.png")),
        )
        .unwrap();
    }
    watch.to_str().unwrap().to_string()
}

/// `send` watching `watch`, on UDP port `port` with its peer on `peer`,
/// k-means with 3 levels, for `frames` frames; `keys` adds arguments.
fn spawn_sender(watch: &str, (port, peer): (u16, u16), frames: &str, keys: &[&str]) -> Child {
    let link = format!("udp:127.0.0.1:{port}?peer=127.0.0.1:{peer}");
    let mut args = vec!["send", "--link", &link, "--watch", watch];
    args.extend(["--poll-ms", "50", "--frames", frames, "--max-disp", "24"]);
    args.extend(["--method", "kmeans", "--levels", "3", "--deadline-s", "20"]);
    args.extend(keys);
    spawn(&args)
}

#[test]
fn a_running_sender_takes_levels_and_method_sends_a_frame_on_request_and_refuses_a_stop() {
    let dir = tempfile::tempdir().unwrap();
    let watch = camera_folder(dir.path());
    let (port, peer_port) = (free_port(), free_port());
    let mut peer = Peer::udp(peer_port, &format!("127.0.0.1:{port}"), None, PATIENCE);
    let child = spawn_sender(&watch, (port, peer_port), "2", &["--insecure"]);
    let wait = Duration::from_secs(60);
    peer.until(wait, |s| s.frames.len() == 1);
    assert_eq!(peer.seen.frames[0], (1, "kmeans", 3));

    // Malformed first: refused with a clear line, and the sender goes on.
    peer.send(&container::encode(
        &Message::Control(vec![9, 1, 0, 0, 0, 0]),
        0,
        0,
    ));
    peer.send(&container::encode(
        &Message::Control(vec![1, 3, 7, 0, 0, 0, 99]),
        0,
        0,
    ));
    peer.send(b"not a container message");
    for (id, c) in [
        (1, Command::SetLevels(5)),
        (2, Command::SetMethod("otsu".into())),
        (3, Command::AxisStop),
        (4, Command::FrameRequest),
    ] {
        peer.send(&c.message(id));
    }
    // No new pair in the folder: frame 2 is the one asked for, prepared
    // with the new settings.
    peer.until(wait, |s| s.frames.len() == 2 && s.replies.len() == 4);
    assert_eq!(peer.seen.frames[1], (2, "otsu", 5));
    let results: Vec<_> = peer
        .seen
        .replies
        .iter()
        .map(|r| (r.id, r.result.is_ok()))
        .collect();
    assert_eq!(results, [(1, true), (2, true), (3, false), (4, true)]);
    let stop = &peer.seen.replies[2].result;
    assert!(
        stop.as_ref().is_err_and(|e| e.contains("no axis")),
        "{stop:?}"
    );

    let (out, err) = peer.wait(child, "send");
    assert!(out.contains("frame 2:"), "{out}");
    for said in [
        "refused a message from the peer: control body: version 9 is not supported",
        "refused a message from the peer: control body: operation 3: levels",
        "refused a message from the peer: control message rejected: not a stereolink message",
        "command 1 (levels 5): done",
        "command 2 (method otsu): done",
        "command 3 (axis stop): refused: this station only sends images",
        "command 4 (frame request): done",
    ] {
        assert!(err.contains(said), "missing {said:?} in:\n{err}");
    }
}

/// The keys of `me` talking to `peer`, from the pairs in `dir`.
fn keys(dir: &Path, me: &str, peer: &str) -> Keys {
    let (private, _) = keyfile::paths(&dir.join(me));
    let (_, public) = keyfile::paths(&dir.join(peer));
    keyfile::read_keys(&private, &public).unwrap()
}

/// The air between a station and the peers that talk to it: what the
/// station sends reaches every peer (a radio broadcasts), and what any peer
/// sends reaches the station from one and the same address (on the air, a
/// source address proves nothing): only the secure layer tells them apart.
struct Air {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Air {
    /// Links the station on UDP port `station` with `peers` peers; returns
    /// the air, the station's peer address and each peer's.
    fn start(station: u16, peers: &[u16]) -> (Air, String, Vec<String>) {
        let bind = || {
            let s = UdpSocket::bind("127.0.0.1:0").unwrap();
            s.set_read_timeout(Some(Duration::from_millis(1))).unwrap();
            s
        };
        let toward_station = bind();
        let toward_peers: Vec<UdpSocket> = peers.iter().map(|_| bind()).collect();
        let addr = |s: &UdpSocket| s.local_addr().unwrap().to_string();
        let (station_side, peer_sides) = (
            addr(&toward_station),
            toward_peers.iter().map(addr).collect(),
        );
        let stop = Arc::new(AtomicBool::new(false));
        let (halt, peers) = (stop.clone(), peers.to_vec());
        let thread = std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            while !halt.load(Ordering::Relaxed) {
                while let Ok(n) = toward_station.recv(&mut buf) {
                    for (s, &p) in toward_peers.iter().zip(&peers) {
                        let _ = s.send_to(&buf[..n], ("127.0.0.1", p));
                    }
                }
                for s in &toward_peers {
                    while let Ok(n) = s.recv(&mut buf) {
                        let _ = toward_station.send_to(&buf[..n], ("127.0.0.1", station));
                    }
                }
            }
        });
        let air = Air {
            stop,
            thread: Some(thread),
        };
        (air, station_side, peer_sides)
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

#[test]
fn a_sealed_sender_obeys_only_its_paired_peer() {
    let dir = tempfile::tempdir().unwrap();
    let watch = camera_folder(dir.path());
    for name in ["sender", "gateway", "intruder"] {
        keyfile::generate(&dir.path().join(name)).unwrap();
    }
    let (port, gateway_port, intruder_port) = (free_port(), free_port(), free_port());
    let (_air, station_side, peer_sides) = Air::start(port, &[gateway_port, intruder_port]);
    let keys_of = |me: &str| Some(keys(dir.path(), me, "sender"));
    let mut gateway = Peer::udp(gateway_port, &peer_sides[0], keys_of("gateway"), PATIENCE);
    let (key, _) = keyfile::paths(&dir.path().join("sender"));
    let (_, peer_key) = keyfile::paths(&dir.path().join("gateway"));
    let link = format!("udp:127.0.0.1:{port}?peer={station_side}");
    let mut args = vec!["send", "--link", &link, "--watch", &watch];
    args.extend(["--poll-ms", "50", "--frames", "2", "--max-disp", "24"]);
    args.extend(["--method", "kmeans", "--levels", "3", "--deadline-s", "20"]);
    args.extend(["--key", key.to_str().unwrap()]);
    args.extend(["--peer-key", peer_key.to_str().unwrap()]);
    let child = spawn(&args);
    let wait = Duration::from_secs(60);
    gateway.until(wait, |s| s.frames.len() == 1);

    // An intruder on the same air with its own key (its handshake is
    // refused), then with none (its plaintext command is refused): the
    // sender must not obey either. Whether the ARQ acknowledged the
    // segments says nothing; what the sender does is checked below.
    for intruder_keys in [keys_of("intruder"), None] {
        let secs = Duration::from_secs(1);
        let mut intruder = Peer::udp(intruder_port, &peer_sides[1], intruder_keys, secs);
        let _ = intruder.ep.send_message(&Command::SetLevels(9).message(1));
        let _ = intruder.ep.linger(Duration::from_millis(200));
    }
    gateway.send(&Command::FrameRequest.message(7));
    gateway.until(wait, |s| s.frames.len() == 2 && !s.replies.is_empty());
    assert_eq!(
        gateway.seen.frames[1],
        (2, "kmeans", 3),
        "levels must not change"
    );
    let done = Reply {
        id: 7,
        result: Ok(()),
    };
    assert_eq!(gateway.seen.replies, [done]);
    let (_, err) = gateway.wait(child, "send");
    assert!(!err.contains("levels 9"), "{err}");
    assert!(!err.contains("command 1"), "{err}");
    assert!(err.contains("command 7 (frame request): done"), "{err}");
}

/// A depth report of `distance_m` for frame `frame_id`.
fn report(frame_id: u32, distance_m: f32) -> Vec<u8> {
    let r = DepthReport {
        target_distance_m: distance_m,
        target_region: [0, 0, 10, 10],
        levels: vec![ReportLevel {
            disparity: 10.0,
            distance_m,
            share: 1.0,
        }],
        histogram: vec![0; 25],
    };
    container::encode(&Message::DepthReport(r), frame_id, 0)
}

#[test]
fn receive_stops_its_axis_on_an_axis_stop_and_holds_it() {
    let (port, peer_port) = (free_port(), free_port());
    let mut peer = Peer::udp(peer_port, &format!("127.0.0.1:{port}"), None, PATIENCE);
    let child = common::spawn_udp_receiver(peer_port, port, &["--timeout-s", "2", "--json"]);
    // Sent to 800 mm at 50 mm/s: 16 s of travel, unless stopped.
    peer.send(&report(1, 0.8));
    std::thread::sleep(Duration::from_millis(300));
    peer.send(&Command::AxisStop.message(1));
    peer.send(&Command::SetLevels(4).message(2));
    peer.send(&container::encode(
        &Message::Control(vec![1, 1, 0, 0, 0, 0, 0]),
        0,
        0,
    ));
    peer.send(&report(2, 0.9));
    let (out, _) = peer.wait(child, "receive");
    let got = common::json_text(&out);
    let events = got["events"].as_array().unwrap();
    let report = |id: u64| {
        events
            .iter()
            .find(|e| e["Report"]["frame_id"] == id)
            .map(|e| &e["Report"])
            .unwrap_or_else(|| panic!("no report {id}: {got}"))
    };
    let command = |id: u64| {
        events
            .iter()
            .find(|e| e["Command"]["id"] == id)
            .map(|e| &e["Command"])
            .unwrap_or_else(|| panic!("no command {id}: {got}"))
    };
    let to = report(1)["commanded_mm"].as_f64().unwrap();
    assert!((to - 800.0).abs() < 1e-3, "{got}");
    assert_eq!(command(1)["command"], "axis stop");
    assert!(command(1)["result"].get("Ok").is_some(), "{got}");
    // Held: the later report does not move the axis.
    assert_eq!(report(2)["held"], true, "{got}");
    assert!(report(2)["commanded_mm"].is_null(), "{got}");
    let refused = command(2)["result"]["Err"].as_str().unwrap_or_default();
    assert!(
        refused.contains("the board takes only an axis stop"),
        "{got}"
    );
    assert!(
        events.iter().any(|e| e["Rejected"]
            .as_str()
            .is_some_and(|r| r.contains("control body: operation 1: takes no argument"))),
        "{got}"
    );
    // Stopped early (0.3 s at 50 mm/s, about 15 mm) and held there to the end.
    let settled = got["summary"]["axis_mm"].as_f64().unwrap();
    assert!(settled < 100.0, "settled at {settled} mm: {got}");
}

/// A link that goes quiet mid-move: the watchdog stops the axis within its
/// period (0.5 s by default, at 50 mm/s: well short of the target), and the
/// receiver still ends with its summary, which counts the report.
#[test]
fn a_quiet_link_stops_the_axis_and_the_summary_is_still_printed() {
    let (port, peer_port) = (free_port(), free_port());
    let mut peer = Peer::udp(peer_port, &format!("127.0.0.1:{port}"), None, PATIENCE);
    let child = common::spawn_udp_receiver(peer_port, port, &["--timeout-s", "2", "--json"]);
    // Sent to 800 mm at 50 mm/s: 16 s of travel, unless stopped.
    peer.send(&report(1, 0.8));
    let (out, err) = peer.wait(child, "receive");
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    let summary = &json["summary"];
    assert_eq!(summary["reports"], 1, "{summary}");
    assert_eq!(summary["ended"], "quiet", "{summary}");
    assert_eq!(summary["frames"], 0, "{summary}");
    let axis = summary["axis_mm"].as_f64().unwrap();
    assert!(
        axis < 40.0,
        "the watchdog let the axis reach {axis} mm:\n{err}"
    );
    assert_eq!(err.matches("watchdog: ").count(), 1, "{err}");
}
