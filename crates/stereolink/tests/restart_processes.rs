//! Restarts in the middle of a stream, as a field system has them: `send`
//! and `receive` processes killed and started again over UDP and over a pty
//! pair joined by emulated radios. What counts is what the receiver shows
//! (its `frame N:` lines): every frame a sender reports sent after a
//! restart must be shown exactly once, and nothing is shown twice.

mod common;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::xbee::{Firmware, RadioLink};
use common::{free_port, strings, synth};
use stereolink_link::arq::Segment;

/// A running `stereolink` whose stdout lines are collected as they come.
struct Proc {
    child: Child,
    lines: Arc<Mutex<Vec<String>>>,
    reader: Option<std::thread::JoinHandle<()>>,
}

impl Proc {
    fn spawn(args: &[String]) -> Proc {
        let mut child = Command::new(env!("CARGO_BIN_EXE_stereolink"))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let out = child.stdout.take().unwrap();
        let lines = Arc::new(Mutex::new(Vec::new()));
        let sink = lines.clone();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                sink.lock().unwrap().push(line);
            }
        });
        Proc {
            child,
            lines,
            reader: Some(reader),
        }
    }

    /// Waits (at most 120 s) until a stdout line starts with `prefix`.
    fn wait_for(&self, prefix: &str) {
        let until = Instant::now() + Duration::from_secs(120);
        while Instant::now() < until {
            if self
                .lines
                .lock()
                .unwrap()
                .iter()
                .any(|l| l.starts_with(prefix))
            {
                return;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        panic!("no {prefix:?} line in {:?}", self.lines.lock().unwrap());
    }

    /// Kills the process (SIGKILL: no clean-up) and returns its stdout lines.
    fn kill(mut self) -> Vec<String> {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
        self.join()
    }

    /// Waits for the exit: whether it succeeded, stdout lines, stderr.
    fn finish(mut self) -> (bool, Vec<String>, String) {
        let mut err = String::new();
        std::io::Read::read_to_string(self.child.stderr.as_mut().unwrap(), &mut err).unwrap();
        let ok = self.child.wait().unwrap().success();
        (ok, self.join(), err)
    }

    fn join(&mut self) -> Vec<String> {
        self.reader.take().unwrap().join().unwrap();
        std::mem::take(&mut *self.lines.lock().unwrap())
    }
}

/// The ids of the `frame N:` lines, in order.
fn frame_ids(lines: &[String]) -> Vec<u32> {
    lines
        .iter()
        .filter_map(|l| l.strip_prefix("frame ")?.split(':').next()?.parse().ok())
        .collect()
}

/// A sender of the scene's pair, `repeat` times.
fn sender(link: &str, scene: &Path, repeat: u32) -> Proc {
    Proc::spawn(&sender_args(link, scene, repeat))
}

/// The arguments of [`sender`].
fn sender_args(link: &str, scene: &Path, repeat: u32) -> Vec<String> {
    let mut args = strings(&["send", "--link", link, "--max-disp", "23"]);
    args.extend(strings(&["--focal-px", "128", "--baseline-m", "0.03"]));
    args.extend(strings(&["--method", "kmeans", "--levels", "4"]));
    args.extend(strings(&[
        "--left",
        scene.join("left.png").to_str().unwrap(),
        "--right",
        scene.join("right.png").to_str().unwrap(),
        "--repeat",
        &repeat.to_string(),
    ]));
    args
}

/// A receiver that shows every frame as a PNG and stops after 4 s of silence.
fn receiver(link: &str, screens: &Path) -> Proc {
    Proc::spawn(&receiver_args(link, screens))
}

/// The arguments of [`receiver`].
fn receiver_args(link: &str, screens: &Path) -> Vec<String> {
    let display = format!("png:{}", screens.display());
    strings(&[
        "receive",
        "--link",
        link,
        "--max-disp",
        "24",
        "--timeout-s",
        "4",
        "--display",
        &display,
    ])
}

/// A sender's frames as it reports them sent: it must have succeeded.
fn sent_ids(p: Proc, what: &str) -> Vec<u32> {
    let (ok, lines, err) = p.finish();
    assert!(ok, "{what} failed: {lines:?} {err}");
    frame_ids(&lines)
}

fn udp_links() -> (String, String) {
    let (a, b) = (free_port(), free_port());
    (
        format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{a}"),
        format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{b}"),
    )
}

/// Three sender processes one after another, one pair each: the receiver
/// must show three frames (before sessions it showed only the first).
#[test]
fn sender_processes_one_after_another_over_udp() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let (rx_link, tx_link) = udp_links();
    let rx = receiver(&rx_link, &dir.path().join("screens"));
    std::thread::sleep(Duration::from_millis(200));
    for run in 1..=3 {
        assert_eq!(
            sent_ids(sender(&tx_link, &scene, 1), "sender"),
            [1],
            "run {run}"
        );
    }
    let (ok, lines, err) = rx.finish();
    assert!(ok, "{err}");
    assert_eq!(frame_ids(&lines), [1, 1, 1], "{lines:?}");
}

/// A sender killed after its second frame, while it works on the third,
/// and a new one sending three: the first's frames are shown at most once,
/// and each of the second's exactly once.
fn sender_restart(rx_link: &str, tx_link: &str) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let rx = receiver(rx_link, &dir.path().join("screens"));
    std::thread::sleep(Duration::from_millis(200));
    let first = sender(tx_link, &scene, 6);
    first.wait_for("frame 2:");
    std::thread::sleep(Duration::from_millis(30));
    let before = frame_ids(&first.kill());
    let after = sent_ids(sender(tx_link, &scene, 3), "restarted sender");
    assert_eq!(after, [1, 2, 3]);
    let (ok, lines, err) = rx.finish();
    assert!(ok, "{err}");
    let shown = frame_ids(&lines);
    // The second sender's frames start again at 1.
    let restart = shown
        .iter()
        .skip(1)
        .position(|&id| id == 1)
        .map(|i| i + 1)
        .unwrap_or_else(|| panic!("no frame of the restarted sender shown: {lines:?}"));
    let (old, new) = shown.split_at(restart);
    assert_eq!(new, after, "{lines:?}");
    assert!(old.starts_with(&before), "{before:?} sent, {old:?} shown");
    assert!(
        old.iter().enumerate().all(|(i, &id)| id == i as u32 + 1),
        "{old:?}"
    );
}

/// A receiver killed once it showed the second frame, and a new one
/// started on the same link: the one sender's six frames are shown once each
/// across the two.
fn receiver_restart(rx_link: &str, tx_link: &str) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let first = receiver(rx_link, &dir.path().join("screens-1"));
    std::thread::sleep(Duration::from_millis(200));
    let tx = sender(tx_link, &scene, 6);
    first.wait_for("frame 2:");
    let mut shown = frame_ids(&first.kill());
    let second = receiver(rx_link, &dir.path().join("screens-2"));
    let sent = sent_ids(tx, "sender");
    assert_eq!(sent, [1, 2, 3, 4, 5, 6]);
    let (ok, lines, err) = second.finish();
    assert!(ok, "{err}");
    shown.extend(frame_ids(&lines));
    assert_eq!(shown, sent, "{lines:?}");
}

/// A receiver restarted in a `--temporal` stream lacks the reference of
/// the next predicted frame: it shows no frame it cannot rebuild, asks the
/// sender for a key frame, and shows the key frame that comes.
#[test]
fn a_restarted_receiver_asks_for_a_key_frame_over_udp() {
    let (rx_link, tx_link) = udp_links();
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let first = receiver(&rx_link, &dir.path().join("screens-1"));
    std::thread::sleep(Duration::from_millis(200));
    let mut args = sender_args(&tx_link, &scene, 10);
    args.extend(strings(&["--temporal", "--json"]));
    let tx = Proc::spawn(&args);
    first.wait_for("frame 2:");
    first.kill();
    let mut args = strings(&["--json"]);
    args.extend(receiver_args(&rx_link, &dir.path().join("screens-2")));
    let second = Proc::spawn(&args);
    let (ok, lines, err) = tx.finish();
    assert!(ok, "sender failed: {lines:?} {err}");
    let sent: serde_json::Value = serde_json::from_str(&lines.join("\n")).unwrap();
    let (ok, lines, err) = second.finish();
    assert!(ok, "{err}");
    let got: serde_json::Value = serde_json::from_str(&lines.join("\n")).unwrap();
    assert!(
        got["summary"]["key_requests"].as_u64().unwrap() >= 1,
        "{got}"
    );
    let events = got["events"].as_array().unwrap();
    let answered = events
        .iter()
        .position(|e| e["Answered"]["result"].get("Ok").is_some())
        .unwrap_or_else(|| panic!("no answer to a key frame request: {got}"));
    // Every frame shown after the answer: the key frame and those
    // predicted from it.
    let shown_after = events[answered..]
        .iter()
        .filter(|e| e.get("Frame").is_some())
        .count();
    assert!(shown_after >= 1, "{got}");
    // The sender sent a key frame after the first.
    let keys = sent["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["frame_kind"] == "key")
        .count();
    assert!(keys >= 2, "{sent}");
    // Nothing was shown that the board could not rebuild: the frames it
    // refused are the predicted ones before the key frame.
    for e in &events[..answered] {
        assert!(e.get("Frame").is_none(), "{got}");
    }
}

/// What [`Relay`] does with the datagrams.
const FORWARD_FIRST_8: u8 = 0;
const CUT: u8 = 1;
const FORWARD_ALL: u8 = 2;

/// A UDP relay between a sender (port `a`) and a receiver (port `b`) that
/// leaves the receiver with part of message `msg_id` acknowledged: it
/// forwards only that message's fragments 0–7, and once the receiver's ACK
/// of those 8 has gone back it cuts the link until told to forward all.
struct Relay {
    port: u16,
    mode: Arc<AtomicU8>,
}

impl Relay {
    fn start(a: u16, b: u16, msg_id: u8) -> Relay {
        let mode = Arc::new(AtomicU8::new(FORWARD_FIRST_8));
        let m = mode.clone();
        let port = common::udp_relay(a, b, move |_, datagram| {
            Some(match (m.load(Ordering::SeqCst), Segment::parse(datagram)) {
                (FORWARD_ALL, _) => true,
                (CUT, _) => false,
                (
                    _,
                    Some(Segment::Data {
                        msg_id: id, index, ..
                    }),
                ) => id != msg_id || index < 8,
                (
                    _,
                    Some(Segment::Ack {
                        msg_id: id, next, ..
                    }),
                ) if id == msg_id && next >= 8 => {
                    m.store(CUT, Ordering::SeqCst);
                    true
                }
                _ => true,
            })
        });
        Relay { port, mode }
    }

    /// Waits (at most 60 s) until the relay has cut the link.
    fn wait_for_cut(&self) {
        let until = Instant::now() + Duration::from_secs(60);
        while self.mode.load(Ordering::SeqCst) != CUT {
            assert!(
                Instant::now() < until,
                "the receiver never acknowledged 8 fragments"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

/// The receiver killed in the middle of frame 3 (message 6: frames take the
/// bulk lane's even message ids, reports the urgent lane's odd ones), after it
/// acknowledged 8 of its fragments, and a new one started: the sender must
/// send the new one the whole message (the old one's ACKs mean nothing to
/// it), and every frame is shown once across the two.
#[test]
fn receiver_restart_mid_message_over_udp() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    synth(&scene);
    let (a, b) = (free_port(), free_port());
    let relay = Relay::start(a, b, 6);
    let rx_link = format!("udp:127.0.0.1:{b}?peer=127.0.0.1:{}", relay.port);
    let first = receiver(&rx_link, &dir.path().join("screens-1"));
    std::thread::sleep(Duration::from_millis(200));
    let tx = sender(
        &format!("udp:127.0.0.1:{a}?peer=127.0.0.1:{}", relay.port),
        &scene,
        6,
    );
    relay.wait_for_cut();
    let mut shown = frame_ids(&first.kill());
    assert_eq!(
        shown,
        [1, 2],
        "frame 3 was not complete at the old receiver"
    );
    let second = receiver(&rx_link, &dir.path().join("screens-2"));
    relay.mode.store(FORWARD_ALL, Ordering::SeqCst);
    let sent = sent_ids(tx, "sender");
    assert_eq!(sent, [1, 2, 3, 4, 5, 6]);
    let (ok, lines, err) = second.finish();
    assert!(ok, "{err}");
    shown.extend(frame_ids(&lines));
    assert_eq!(shown, sent, "{lines:?}");
}

#[test]
fn sender_restart_over_udp() {
    let (rx, tx) = udp_links();
    sender_restart(&rx, &tx);
}

/// The receiver's and the sender's links over two emulated 802.15.4
/// radios; the radios run while the returned `RadioLink` lives.
fn pty_links() -> (RadioLink, String, String) {
    let radio = RadioLink::new(Firmware::Ieee802154, None);
    let link = |dev: &str| format!("serial:{dev}?baud=115200&api=2");
    let (rx, tx) = (link(&radio.b), link(&radio.a));
    (radio, rx, tx)
}

#[test]
fn sender_restart_over_a_pty_pair() {
    let (_radio, rx, tx) = pty_links();
    sender_restart(&rx, &tx);
}

#[test]
fn receiver_restart_over_udp() {
    let (rx, tx) = udp_links();
    receiver_restart(&rx, &tx);
}

#[test]
fn receiver_restart_over_a_pty_pair() {
    let (_radio, rx, tx) = pty_links();
    receiver_restart(&rx, &tx);
}
